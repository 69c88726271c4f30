"""The live viewer: key handling, and a real window when a display exists."""
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from taichi_hsdem.render.viewer import LiveViewer, display_available

ROOT = Path(__file__).resolve().parents[1]


class _Sim:
    t = 1.25


def test_keys_pause_step_screenshot_close(tmp_path):
    import imageio.v3 as iio
    import taichi as ti
    v = LiveViewer(tmp_path)
    frame = np.zeros((4, 6, 3), np.uint8)
    frame[1, 2] = (255, 0, 0)
    assert v.handle_key(ti.GUI.SPACE, _Sim, frame) is False and v.paused   # pause
    assert v.handle_key("n", _Sim, frame) is True                          # one step
    assert v.handle_key("s", _Sim, frame) is False                         # still paused
    (shot,) = v.screenshots
    assert shot.name == "screenshot_1.25.png" and (iio.imread(shot) == frame).all()
    assert v.handle_key(ti.GUI.SPACE, _Sim, frame) is True and not v.paused
    assert v.handle_key(ti.GUI.ESCAPE, _Sim, frame) is True and v.closed


def test_no_display_is_reported(monkeypatch):
    monkeypatch.delenv("DISPLAY", raising=False)
    monkeypatch.delenv("WAYLAND_DISPLAY", raising=False)
    ok, why = display_available()
    assert not ok and "DISPLAY" in why


@pytest.mark.skipif(shutil.which("xvfb-run") is None, reason="needs xvfb-run (Debian xvfb)")
def test_view_runs_in_a_real_window(tmp_path):
    # Under Xvfb the run opens the window, shows every frame and finishes normally.
    proc = subprocess.run(
        ["xvfb-run", "-a", sys.executable, "-m", "taichi_hsdem",
         str(ROOT / "scenes" / "hourglass24.toml"), "--view", "--out", str(tmp_path / "o"),
         "--set", "run.t_end=0.3", "--set", "output.frames=4", "--quiet"],
        cwd=tmp_path, capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr
    import json
    video = json.loads((tmp_path / "o" / "summary.json").read_text())["video"]
    assert video["frames"] == 4 and video["file"] is None     # viewed, not recorded
    assert not (tmp_path / "o" / "video.mp4").exists()


def test_display_set_but_no_x_server_is_reported(monkeypatch, tmp_path, capsys):
    # a display number no X server listens on: refused up front, the run goes on
    monkeypatch.setenv("DISPLAY", ":987")
    ok, why = display_available()
    assert not ok and "no X server answers on DISPLAY=:987" in why
    from taichi_hsdem.cli import main
    hourglass = str(Path(__file__).resolve().parents[1] / "scenes" / "hourglass24.toml")
    assert main([hourglass, "--view", "--out", str(tmp_path / "o"), "--set",
                 "run.t_end=0.1"]) == 0
    err = capsys.readouterr().err
    assert "--view skipped: no X server" in err and "Traceback" not in err
    assert main([hourglass, "--view", "--quiet", "--out", str(tmp_path / "q"), "--set",
                 "run.t_end=0.1"]) == 0
    assert "--view" not in capsys.readouterr().err          # --quiet: errors only
