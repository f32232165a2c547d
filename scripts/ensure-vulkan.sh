#!/bin/sh
# Headless rendering (Taichi GGUI) needs the Vulkan loader and a driver. Where there is none and
# we run as root with apt-get (a fresh Debian machine, CI), install Debian's loader and Mesa's
# drivers, whose lavapipe renders on the CPU; otherwise say what to install and carry on, since
# simulation and the tests that do not render work without it.
set -eu
PACKAGES="libvulkan1 mesa-vulkan-drivers"

has_loader() {
    { ldconfig -p 2>/dev/null || /sbin/ldconfig -p 2>/dev/null; } | grep -q 'libvulkan\.so\.1' \
        || ls /usr/lib/*/libvulkan.so.1 /usr/lib/libvulkan.so.1 >/dev/null 2>&1
}

has_driver() {
    for folder in /usr/share/vulkan/icd.d /etc/vulkan/icd.d /usr/local/share/vulkan/icd.d; do
        ls "$folder"/*.json >/dev/null 2>&1 && return 0
    done
    return 1
}

if has_loader && has_driver; then
    exit 0
fi
if [ "$(id -u)" = 0 ] && command -v apt-get >/dev/null 2>&1; then
    echo "ensure-vulkan: no Vulkan driver found; installing $PACKAGES"
    export DEBIAN_FRONTEND=noninteractive
    apt-get update -qq
    apt-get install -y -qq --no-install-recommends $PACKAGES >/dev/null
    if has_loader && has_driver; then
        exit 0
    fi
    echo "ensure-vulkan: installed $PACKAGES but still found no Vulkan driver" >&2
    exit 1
fi
echo "ensure-vulkan: no Vulkan driver found; rendering needs Debian's $PACKAGES" \
     "(run 'make setup' as root, or 'sudo apt-get install $PACKAGES')" >&2
