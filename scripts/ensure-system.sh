#!/bin/sh
# What the project needs from the system beside its venv. Headless rendering (Taichi GGUI) needs
# the Vulkan loader and a driver; the interactive viewer's test needs a virtual display
# (xvfb-run). Where one is missing and we run as root with apt-get (a fresh Debian machine, CI),
# install Debian's packages for it (Mesa's lavapipe renders on the CPU); otherwise say what to
# install and carry on, since simulation and the tests that do not render work without them.
set -eu

has_vulkan() {
    { { ldconfig -p 2>/dev/null || /sbin/ldconfig -p 2>/dev/null; } | grep -q 'libvulkan\.so\.1' \
        || ls /usr/lib/*/libvulkan.so.1 /usr/lib/libvulkan.so.1 >/dev/null 2>&1; } || return 1
    for folder in /usr/share/vulkan/icd.d /etc/vulkan/icd.d /usr/local/share/vulkan/icd.d; do
        ls "$folder"/*.json >/dev/null 2>&1 && return 0
    done
    return 1
}

has_xvfb() {
    command -v xvfb-run >/dev/null 2>&1
}

# ensure WHAT CHECK PACKAGES: install PACKAGES when CHECK fails (as root with apt-get)
ensure() {
    what=$1 check=$2 packages=$3
    if $check; then
        return 0
    fi
    if [ "$(id -u)" = 0 ] && command -v apt-get >/dev/null 2>&1; then
        echo "ensure-system: no $what found; installing $packages"
        export DEBIAN_FRONTEND=noninteractive
        apt-get update -qq
        apt-get install -y -qq --no-install-recommends $packages >/dev/null
        $check && return 0
        echo "ensure-system: installed $packages but still found no $what" >&2
        return 1
    fi
    echo "ensure-system: no $what found; it needs Debian's $packages" \
         "(run 'make setup' as root, or 'sudo apt-get install $packages')" >&2
}

ensure "Vulkan driver (headless rendering)" has_vulkan "libvulkan1 mesa-vulkan-drivers"
ensure "xvfb-run (the viewer's test)" has_xvfb "xvfb xauth"
