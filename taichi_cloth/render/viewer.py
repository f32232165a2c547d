"""The interactive viewer (``view``): a GGUI window that plays a scene's frames, from a live
simulation or from a run's cache (``output/view.py`` makes those sources).

Keys: space play/pause; n one frame; r restart; b the body on/off; w the cloth's triangle
edges on/off; the arrow keys orbit the camera, as does dragging with the left mouse button; +
and - zoom; q or Esc quit. An overlay shows the scene, the integrator, dt, the frame and time,
max strain and penetration.

``ViewerControls`` is the keyboard and mouse logic alone (no window), so that it can be tested
by feeding it keys; ``run_viewer`` is the window loop. With ``frames`` the loop plays that many
frames and stops, and ``screenshot`` saves the last picture (also when the user quits with q or
Esc): the viewer run by a script (and by the tests, under a virtual X display).
"""

import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import taichi as ti

ORBIT_STEP = math.radians(5.0)  # rad per arrow key press
DRAG_SCALE = math.pi  # rad per window width dragged
ZOOM_STEP = 1.1  # distance factor per + or - press
PITCH_LIMIT = math.radians(85.0)
HELP = ("space play/pause, n step, r restart", "b body, w wireframe, q quit",
        "arrows or drag: orbit, +/-: zoom")


@dataclass
class ViewerControls:
    """Play state, toggles and the orbit camera about ``lookat`` (yaw about +y, pitch above the
    horizon, distance [m]), changed by ``press(key)`` and ``drag(dx, dy)``."""

    lookat: np.ndarray
    yaw: float
    pitch: float
    distance: float
    playing: bool = True
    show_body: bool = True
    wireframe: bool = False
    quit: bool = False
    step_requested: bool = False
    restart_requested: bool = False
    zoom_limits: tuple = field(default=(0.05, 100.0))

    @classmethod
    def looking(cls, position, lookat) -> "ViewerControls":
        """Controls whose camera starts at ``position`` looking at ``lookat`` [m]."""
        offset = np.asarray(position, float) - np.asarray(lookat, float)
        distance = float(np.linalg.norm(offset))
        return cls(np.asarray(lookat, float), math.atan2(offset[0], offset[2]),
                   math.asin(offset[1] / distance), distance)

    def camera_position(self) -> np.ndarray:
        """Where the camera is [m]."""
        return self.lookat + self.distance * np.array([
            math.cos(self.pitch) * math.sin(self.yaw), math.sin(self.pitch),
            math.cos(self.pitch) * math.cos(self.yaw)])

    def orbit(self, yaw: float, pitch: float) -> None:
        self.yaw += yaw
        self.pitch = min(max(self.pitch + pitch, -PITCH_LIMIT), PITCH_LIMIT)

    def drag(self, dx: float, dy: float) -> None:
        """The cursor moved (dx, dy) window widths/heights with the left button held."""
        self.orbit(-dx * DRAG_SCALE, -dy * DRAG_SCALE)

    def press(self, key: str) -> None:
        """One key press (GGUI's names: a letter, ' ', 'Left', 'Escape', ...)."""
        arrows = {ti.ui.LEFT: (-ORBIT_STEP, 0.0), ti.ui.RIGHT: (ORBIT_STEP, 0.0),
                  ti.ui.UP: (0.0, ORBIT_STEP), ti.ui.DOWN: (0.0, -ORBIT_STEP)}
        if key in arrows:
            self.orbit(*arrows[key])
        elif key == ti.ui.SPACE:
            self.playing = not self.playing
        elif key == "n":
            self.playing, self.step_requested = False, True
        elif key == "r":
            self.restart_requested = True
        elif key == "b":
            self.show_body = not self.show_body
        elif key == "w":
            self.wireframe = not self.wireframe
        elif key in ("=", "+", "-"):
            factor = 1 / ZOOM_STEP if key in ("=", "+") else ZOOM_STEP
            self.distance = min(max(self.distance * factor, self.zoom_limits[0]),
                                self.zoom_limits[1])
        elif key in ("q", ti.ui.ESCAPE):
            self.quit = True


def run_viewer(renderer, source, frames: int | None = None,
               screenshot: Path | None = None) -> tuple[int, bool]:
    """Show ``source`` (``output/view.py``: its ``positions`` field, time ``t``, ``advance()``,
    ``restart()`` and overlay ``lines()``) in ``renderer``'s visible window until the user quits
    (q or Esc, or closing the window) or, with ``frames``, until that many frames were shown.
    ``screenshot``: the last picture is saved there when the viewer stops by ``frames`` or by
    q/Esc (a window closed by its title bar has no picture left to save). Returns the frames
    shown and whether the screenshot was saved."""
    window = renderer.window
    config = renderer.config
    controls = ViewerControls.looking(config.camera_position, config.camera_lookat)
    cursor = None
    shown = 0
    while window.running:
        for event in window.get_events(ti.ui.PRESS):
            controls.press(event.key)
        position = window.get_cursor_pos()
        if window.is_pressed(ti.ui.LMB) and cursor is not None:
            controls.drag(position[0] - cursor[0], position[1] - cursor[1])
        cursor = position
        if controls.restart_requested:
            source.restart()
            controls.restart_requested = False
        if (controls.playing or controls.step_requested) and not controls.quit:
            if not source.advance():
                controls.playing = False
            controls.step_requested = False
        renderer.camera.position(*controls.camera_position())
        renderer.camera.lookat(*controls.lookat)
        renderer.compose(source.positions, source.t, controls.show_body, controls.wireframe)
        overlay(window.get_gui(), source.lines(controls.playing))
        if controls.quit or (frames is not None and shown + 1 >= frames):
            shown += not controls.quit  # q/Esc re-draws the picture already shown
            if screenshot is not None:  # saved before show(), which hands the picture over
                Path(screenshot).parent.mkdir(parents=True, exist_ok=True)
                window.save_image(str(screenshot))
            return shown, screenshot is not None
        shown += 1
        window.show()
    return shown, False


def overlay(gui, lines: list[str]) -> None:
    """The info panel in the window's top left corner, the keys below it."""
    with gui.sub_window("taichi_cloth", 0.01, 0.01, 0.5, 0.06 + 0.04 * (len(lines) + len(HELP))):
        for line in (*lines, *HELP):
            gui.text(line)
