# Set-up shared by the project's scripts. Everything a fresh machine lacks is installed here,
# idempotently: a second run installs nothing.

# Debian packages the tests use:
# - iproute2: `ip link add ... type vcan` for the SocketCAN test, where the kernel allows it.
# - fonts-dejavu-core: DejaVu Sans, the TTF that eval's plots register at run time (plotters'
#   ab_glyph backend loads no system fonts, and the repository ships no font file).
# - xvfb, xauth, x11-apps (xwd), Mesa's software GL (libgl1-mesa-dri, libegl1) and the X client
#   libraries winit loads at run time: the ground station's real-window test runs the eframe app
#   under Xvfb on llvmpipe and grabs the window.
SYSTEM_PACKAGES=(iproute2 fonts-dejavu-core xvfb xauth x11-apps libgl1-mesa-dri libegl1 libxkbcommon-x11-0
    libxcursor1 libxrandr2 libxi6)

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
    "$venv/bin/python" -c "import cv2, numpy, gtsam, evo"
    echo "$want" >"$stamp"
}

# The tests read their data from the repository's `data/` (each set's origin, licence and file
# checksums in its SOURCE.md); nothing outside the checkout is read. Checked before every run, so
# a damaged or partial checkout (a Git LFS pointer, a truncated file) fails here with the file's
# name instead of deep inside a test.
verify_test_data() {
    scripts/data-checksums --check
}
