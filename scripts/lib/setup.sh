# Set-up shared by the project's scripts. Everything a fresh machine lacks is installed here,
# idempotently: a second run installs nothing.

# Debian packages the tests use:
# - iproute2: `ip link add ... type vcan` for the SocketCAN test, where the kernel allows it.
# - fonts-dejavu-core: DejaVu Sans, the TTF that eval's plots register at run time (plotters'
#   ab_glyph backend loads no system fonts, and the repository ships no font file).
# - xvfb, xauth, x11-apps (xwd), Mesa's software GL (libgl1-mesa-dri, libegl1) and the X client
#   libraries winit loads at run time: the ground station's real-window test runs the eframe app
#   under Xvfb on llvmpipe and grabs the window.
# - libusb-1.0-0: the open3d wheel (the submap matcher's reference) links libusb-1.0 and fails to
#   import without it.
SYSTEM_PACKAGES=(iproute2 fonts-dejavu-core xvfb xauth x11-apps libgl1-mesa-dri libegl1 libxkbcommon-x11-0
    libxcursor1 libxrandr2 libxi6 libusb-1.0-0)

ensure_system_packages() {
    local missing=()
    for pkg in "${SYSTEM_PACKAGES[@]}"; do
        dpkg-query -W -f='${Status}' "$pkg" 2>/dev/null | grep -q "install ok installed" || missing+=("$pkg")
    done
    if ((${#missing[@]} > 0)); then
        echo "setup: installing ${missing[*]}"
        local sudo=""
        [[ $(id -u) -ne 0 ]] && sudo="sudo"
        $sudo apt-get update -qq
        DEBIAN_FRONTEND=noninteractive $sudo apt-get install -y -qq --no-install-recommends "${missing[@]}" >/dev/null
    fi
}

# The project's Python venv: `.venv` at the project root (gitignored) with the exact pins of
# scripts/requirements.txt. Used by the OpenCV comparison (fpga_model/scripts/opencv_sgbm.py,
# run by fpga_model's tests/middlebury.rs and benches/vs_opencv.rs) and by the GTSAM reference
# of the pose-graph optimizer (onboard/graph/scripts/gtsam_reference.py). A stamp holding the
# requirements' hash makes a second run install nothing, and a change of pins reinstall.
PYTHON_REQUIREMENTS=scripts/requirements.txt

ensure_python_venv() {
    local venv=.venv
    local stamp="$venv/.requirements.sha256"
    local want
    want=$(sha256sum "$PYTHON_REQUIREMENTS" | cut -d' ' -f1)
    if [[ -x "$venv/bin/python" && -f "$stamp" && "$(cat "$stamp")" == "$want" ]]; then
        return 0
    fi
    echo "setup: creating the Python venv $venv from $PYTHON_REQUIREMENTS"
    if [[ ! -x "$venv/bin/python" ]]; then
        python3 -m venv "$venv"
    fi
    "$venv/bin/python" -m pip install --quiet --disable-pip-version-check -r "$PYTHON_REQUIREMENTS"
    # Fail here, not deep inside a test, if the wheels do not import on this machine.
    "$venv/bin/python" -c "import cv2, numpy, gtsam, evo, open3d, can, canopen"
    echo "$want" >"$stamp"
}

# The tests read their data from the repository's `data/` (each set's origin, licence and file
# checksums in its SOURCE.md); nothing outside the checkout is read. Checked before every run, so
# a damaged or partial checkout (a Git LFS pointer, a truncated file) fails here with the file's
# name instead of deep inside a test.
verify_test_data() {
    scripts/data-checksums --check
}

# hal's SocketCAN tests (`#[ignore = "needs vcan"]` in hal/tests/can_link.rs) need a vcan
# interface, and creating one takes a kernel with vcan and root. Where both are at hand this makes
# `vcan0` (mtu 72 so it carries FD frames; classic sockets work on it too) and returns 0; it is
# fine if it exists already. Otherwise it returns 1 with the reason in VCAN_UNAVAILABLE, so that
# scripts/test reports those tests as not run rather than letting them pass unseen.
VCAN_INTERFACE=vcan0

ensure_vcan() {
    VCAN_UNAVAILABLE=""
    local sudo=() err modprobe_note=""
    if [[ $(id -u) -ne 0 ]]; then
        # -n: a password prompt would hang an unattended run.
        if ! sudo -n true 2>/dev/null; then
            VCAN_UNAVAILABLE="not root and no password-less sudo"
            return 1
        fi
        sudo=(sudo -n)
    fi
    if [[ ! -e /sys/class/net/$VCAN_INTERFACE ]]; then
        # modprobe is missing from slim images and not needed where vcan is built in or already
        # loaded; its failure only matters if the interface then cannot be made.
        if ! command -v modprobe >/dev/null; then
            modprobe_note="no modprobe"
        elif ! err=$("${sudo[@]}" modprobe vcan 2>&1); then
            modprobe_note="modprobe vcan: ${err//$'\n'/ }"
        fi
        if ! err=$("${sudo[@]}" ip link add dev "$VCAN_INTERFACE" type vcan 2>&1); then
            VCAN_UNAVAILABLE="ip link add dev $VCAN_INTERFACE type vcan: ${err//$'\n'/ }${modprobe_note:+; $modprobe_note}"
            return 1
        fi
    fi
    # vcan refuses an mtu change while up.
    if [[ $(cat "/sys/class/net/$VCAN_INTERFACE/mtu") != 72 ]] &&
        ! err=$("${sudo[@]}" ip link set dev "$VCAN_INTERFACE" down 2>&1 &&
            "${sudo[@]}" ip link set dev "$VCAN_INTERFACE" mtu 72 2>&1); then
        VCAN_UNAVAILABLE="cannot give $VCAN_INTERFACE mtu 72 for CAN FD: ${err//$'\n'/ }"
        return 1
    fi
    if ! err=$("${sudo[@]}" ip link set dev "$VCAN_INTERFACE" up 2>&1); then
        VCAN_UNAVAILABLE="ip link set dev $VCAN_INTERFACE up: ${err//$'\n'/ }"
        return 1
    fi
}
