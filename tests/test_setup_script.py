"""tools/setup.sh with apt-get, dpkg, sudo and the interpreter replaced by
recording stubs: it says each step on stderr before it starts (the installs are
silent for a minute or two), prints nothing else, and installs what it did."""

import os
import subprocess
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
PACKAGES = "mesa-vulkan-drivers libvulkan1 xvfb xauth"


def run_setup(tmp_path, installed):
    """Run setup.sh inside an active virtual environment (so no .venv is made)
    with stubs that log their arguments; ``installed``: dpkg finds the system
    packages."""
    bin_dir, log = tmp_path / "bin", tmp_path / "calls.log"
    bin_dir.mkdir()
    stubs = {"dpkg": f"exit {0 if installed else 1}",
             "apt-get": f'echo "apt-get $*" >> {log}',
             "sudo": 'exec "$@"',
             "python": f'echo "python $*" >> {log}'}
    for name, body in stubs.items():
        path = bin_dir / name
        path.write_text(f"#!/bin/bash\n{body}\n")
        path.chmod(0o755)
    env = dict(os.environ, PATH=f"{bin_dir}{os.pathsep}{os.environ['PATH']}",
               PYTHON=str(bin_dir / "python"), VIRTUAL_ENV=str(tmp_path / "venv"))
    proc = subprocess.run(["bash", str(REPO / "tools" / "setup.sh")], env=env,
                          capture_output=True, text=True, timeout=60)
    calls = log.read_text().splitlines() if log.exists() else []
    return proc, calls


PIP = "python -m pip install -q --disable-pip-version-check -e .[test,plot,vtk]"
PIP_LINE = "setup: installing the Python package and its test, plot and vtk extras with pip ..."


def test_fresh_machine_says_each_step_on_stderr(tmp_path):
    proc, calls = run_setup(tmp_path, installed=False)
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout == ""
    assert proc.stderr.splitlines() == [
        f"setup: installing system packages ({PACKAGES}) with apt-get ...", PIP_LINE,
        "setup: done"]
    assert calls == ["apt-get update -qq", f"apt-get install -y -qq {PACKAGES}", PIP]


def test_installed_system_packages_are_not_reinstalled_or_announced(tmp_path):
    proc, calls = run_setup(tmp_path, installed=True)
    assert proc.returncode == 0, proc.stderr
    assert proc.stdout == ""
    assert proc.stderr.splitlines() == [PIP_LINE, "setup: done"]
    assert calls == [PIP]
