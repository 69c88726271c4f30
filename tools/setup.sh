#!/usr/bin/env bash
# Set up a fresh Debian machine for taichi_hsdem: the software Vulkan driver that
# off-screen video rendering needs (and Xvfb, for testing the live viewer), then
# the package with its test extras.
# Safe to run again.
set -euo pipefail
cd "$(dirname "$0")/.."
if ! dpkg -s mesa-vulkan-drivers libvulkan1 xvfb xauth >/dev/null 2>&1; then
    SUDO=""
    if [ "$(id -u)" -ne 0 ]; then SUDO="sudo"; fi
    $SUDO apt-get update -qq
    DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq mesa-vulkan-drivers libvulkan1 xvfb xauth >/dev/null
fi
python -m pip install -q --disable-pip-version-check -e ".[test,plot]"
