# Set-up shared by the project's scripts. Everything a fresh machine lacks is installed here,
# idempotently: a second run installs nothing.

# Debian packages the tests use:
# - iproute2: `ip link add ... type vcan` for the SocketCAN test, where the kernel allows it.
SYSTEM_PACKAGES=(iproute2)

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
