"""The interactive viewer: its key and mouse logic fed directly, and the window itself driven for
a few frames under a virtual X display (xvfb-run with the software Vulkan driver), live and from
a cache, saving a screenshot. Without xvfb-run the window tests skip, except in CI (CI=true),
whose `make setup` installs it (scripts/ensure-system.sh)."""

import math
import os
import shutil
import subprocess
import sys
from pathlib import Path

import imageio.v3 as iio
import numpy as np
import pytest

from taichi_cloth.render.viewer import PITCH_LIMIT, ViewerControls

REPO = Path(__file__).resolve().parent.parent
SMALL = ["--set", "cloth.resolution=[6,6]", "--set", "scene.duration=0.2"]


def controls() -> ViewerControls:
    return ViewerControls.looking([0.0, 1.1, 2.6], [0.0, 1.0, 0.0])


def test_the_controls_start_at_the_scene_camera_and_orbit_about_its_target():
    state = controls()
    assert np.allclose(state.camera_position(), [0.0, 1.1, 2.6])
    distance = state.distance
    for key in ("Left", "Left", "Up", "Right", "Down", "Down"):
        state.press(key)
        assert math.isclose(np.linalg.norm(state.camera_position() - state.lookat), distance)
    assert math.isclose(state.yaw, -math.radians(5.0), abs_tol=1e-12)
    for _ in range(40):
        state.press("Up")
    assert state.pitch == PITCH_LIMIT  # never over the top
    state.drag(0.25, 0.0)  # a quarter of the window's width: a quarter turn
    assert math.isclose(state.yaw, -math.radians(5.0) - math.pi / 4, abs_tol=1e-12)


def test_keys_play_step_restart_toggle_zoom_and_quit():
    state = controls()
    assert state.playing and state.show_body and not state.wireframe
    state.press(" ")
    assert not state.playing
    state.press(" ")
    state.press("n")  # a step pauses
    assert state.step_requested and not state.playing
    state.press("r")
    assert state.restart_requested
    state.press("b")
    state.press("w")
    assert not state.show_body and state.wireframe
    distance = state.distance
    state.press("=")
    assert math.isclose(state.distance, distance / 1.1)
    state.press("-")
    state.press("-")
    assert math.isclose(state.distance, distance * 1.1)
    for _ in range(200):
        state.press("-")
    assert state.distance == state.zoom_limits[1]
    state.press("x")  # an unbound key changes nothing
    assert not state.quit
    state.press("Escape")
    assert state.quit


def run_view(arguments: list[str], folder: Path, display: bool = True):
    """``view`` run in ``folder`` (under xvfb-run when ``display``, else with no display)."""
    command = [sys.executable, "-m", "taichi_cloth", "view", *arguments]
    if display:
        command = ["xvfb-run", "-a", *command]
    environment = {key: value for key, value in os.environ.items()
                   if display or key not in ("DISPLAY", "WAYLAND_DISPLAY")}
    environment["PYTHONPATH"] = str(REPO)
    return subprocess.run(command, cwd=folder, capture_output=True, text=True, timeout=300,
                          env=environment)


needs_xvfb = pytest.mark.skipif(shutil.which("xvfb-run") is None and not os.environ.get("CI"),
                                reason="no xvfb-run (Debian's xvfb; make setup installs it as "
                                       "root)")


@needs_xvfb
def test_the_window_plays_a_live_scene_and_a_cache_and_saves_a_screenshot(tmp_path):
    live = run_view(["sheet", *SMALL, "--frames", "4", "--width", "160", "--height", "120",
                     "--screenshot", str(tmp_path / "live.png")], tmp_path)
    assert live.returncode == 0, live.stderr
    image = iio.imread(tmp_path / "live.png")
    assert image.shape[:2] == (120, 160)
    assert np.ptp(image[..., :3].reshape(-1, 3), axis=0).max() > 100  # a picture, not a blank
    subprocess.run([sys.executable, "-m", "taichi_cloth", "simulate", "sheet", *SMALL, "--quiet",
                    "--out", str(tmp_path / "run")], cwd=REPO, check=True)
    cached = run_view(["--from-cache", str(tmp_path / "run"), "--frames", "3",
                       "--screenshot", str(tmp_path / "cached.png")], tmp_path)
    assert cached.returncode == 0, cached.stderr
    assert iio.imread(tmp_path / "cached.png").shape[:2] == (480, 640)  # the scene's size
    assert not (tmp_path / "imgui.ini").exists()  # GGUI's file is not left where it ran


def test_no_display_or_bad_arguments_are_one_line_and_exit_2(tmp_path):
    for arguments in (["sheet"], ["sheet", "--from-cache", str(tmp_path)], [],
                      ["sheet", "--width", "4"]):
        result = run_view(arguments, tmp_path, display=False)
        assert result.returncode == 2
        assert len(result.stderr.strip().splitlines()) == 1, result.stderr
    assert "xvfb-run" in run_view(["sheet"], tmp_path, display=False).stderr
