#!/usr/bin/env bash
# Set up a fresh Debian machine for taichi_hsdem: the software Vulkan driver that
# off-screen video rendering needs (and Xvfb, for testing the live viewer), then
# the package with its test, plot and ParaView extras.
#
# Where it installs: into the active virtual environment if one is active; else
# into the interpreter ($PYTHON, default python3) when it accepts installs; else
# (a Debian python3 refuses them: PEP 668, "externally-managed-environment") into a
# virtual environment .venv here, which `. tools/env.sh` activates. Safe to run again.
# It says what it is doing in one line per step on stderr (the installs take a
# minute or two), and nothing else unless something fails.
set -euo pipefail
cd "$(dirname "$0")/.."

say() { echo "setup: $*" >&2; }

PY="${PYTHON:-python3}"
command -v "$PY" >/dev/null 2>&1 || PY=python
SUDO=""
if [ "$(id -u)" -ne 0 ]; then SUDO="sudo"; fi

packages=(mesa-vulkan-drivers libvulkan1 xvfb xauth)
venv=""
if [ -z "${VIRTUAL_ENV:-}" ]; then
    managed=$("$PY" -c 'import os, sysconfig
print(os.path.exists(os.path.join(sysconfig.get_path("stdlib"), "EXTERNALLY-MANAGED")))')
    if [ "$managed" = "True" ] || ! "$PY" -m pip --version >/dev/null 2>&1; then
        venv=.venv
        # Debian's python3 makes virtual environments only with python3-venv
        "$PY" -c "import ensurepip, venv" >/dev/null 2>&1 || packages+=(python3-venv)
    fi
fi
if ! dpkg -s "${packages[@]}" >/dev/null 2>&1; then
    say "installing system packages (${packages[*]}) with apt-get ..."
    $SUDO apt-get update -qq
    DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq "${packages[@]}" >/dev/null
fi
if [ -n "$venv" ]; then
    if [ ! -x "$venv/bin/python" ]; then
        say "making a virtual environment in $venv ..."
        "$PY" -m venv "$venv"
    fi
    PY="$venv/bin/python"
fi
say "installing the Python package and its test, plot and vtk extras with pip ..."
"$PY" -m pip install -q --disable-pip-version-check -e ".[test,plot,vtk]"
say "done"
if [ -n "$venv" ]; then
    echo "taichi_hsdem is installed in $venv: activate it with  . tools/env.sh  (or . $venv/bin/activate)"
fi
