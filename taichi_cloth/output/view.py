"""``view``: the interactive viewer (``render/viewer.py``) on a live simulation of a scene, or on
a run's simulation cache (``view --from-cache DIR``, no simulation).

A source gives the viewer the cloth's ``positions`` (a field) and time ``t`` [s] of its current
frame, ``advance()`` to the next (False at the end), ``restart()`` to frame 0, and the overlay's
``lines()``: the scene, integrator and step, frame and time, strain and penetration.
"""

import json
import os
from pathlib import Path

import numpy as np

from taichi_cloth.errors import InputError
from taichi_cloth.output.cache import read_frame
from taichi_cloth.output.replay import cached_run, position_field
from taichi_cloth.output.progress import announce


def status_lines(name: str, integrator: str, dt: float, substeps: int, frame: int,
                 frame_count: int, t: float, metrics: dict | None, playing: bool) -> list[str]:
    """The overlay: what runs, where it is, and how the cloth is doing."""
    lines = [name, f"{integrator}, dt = {dt * 1e3:.3g} ms × {substeps} a frame",
             f"frame {frame}/{frame_count}, t = {t:.2f} s ({'playing' if playing else 'paused'})"]
    if metrics is not None:
        lines.append(f"strain {metrics['max_strain'] * 100:.2f} %, penetration "
                     f"{metrics['max_penetration'] * 1e3:.1f} mm")
    return lines


class LiveSource:
    """The scene simulated as the viewer plays it: settled first (as ``simulate`` does), then
    one guarded frame per ``advance``, up to the scene's frame count."""

    def __init__(self, scene, quiet: bool):
        from taichi_cloth.physics.metrics import RunRecord
        from taichi_cloth.physics.settling import settle
        from taichi_cloth.physics.simulation import Simulation
        announce(scene.name, "building the cloth, the body and the effects", quiet)
        self.simulation = Simulation.from_scene(scene)
        self.record = RunRecord()
        if scene.simulation.settle > 0:
            announce(scene.name, "settling on the still body before frame 0", quiet)
        settle(self.simulation, self.record)
        self.start = self.simulation.snapshot()
        self.frame_count = scene.frame_count
        self.restart()

    @property
    def garment(self):
        return self.simulation.garment

    @property
    def body(self):
        rig = self.simulation.body_rig
        return rig.body if rig is not None else None

    @property
    def positions(self):
        return self.simulation.state_in.x

    @property
    def t(self) -> float:
        return self.simulation.frame_time(self.frame)

    def restart(self) -> None:
        self.simulation.restore(self.start)
        self.frame = 0
        self.metrics = self.simulation.measure(0, *self.simulation.host_state())

    def advance(self) -> bool:
        if self.frame >= self.frame_count:
            return False
        self.frame += 1
        self.metrics = self.simulation.guarded_frame(self.frame, self.record)
        self.simulation.integrator.take_iterations()
        return True

    def lines(self, playing: bool) -> list[str]:
        step = self.simulation.time_step
        return status_lines(self.simulation.scene.name, self.simulation.scene.simulation.integrator,
                            step.dt, step.substeps_per_frame, self.frame, self.frame_count, self.t,
                            {"max_strain": self.metrics.max_strain,
                             "max_penetration": self.metrics.max_penetration}, playing)


class CacheSource:
    """A cached run's frames, with each frame's metrics from its stats.json when it has one."""

    def __init__(self, directory: Path):
        self.directory = Path(directory)
        self.scene, self.frames, self.garment, self.body = cached_run(self.directory)
        self.positions = position_field(self.scene, self.garment)
        try:
            stats = json.loads((self.directory / "stats.json").read_text(encoding="utf-8"))
        except (OSError, ValueError):
            stats = {}
        self.stats = stats
        self.per_frame = {entry["frame"]: entry for entry in stats.get("per_frame", [])}
        self.restart()

    def restart(self) -> None:
        self.index = 0
        self._load()

    def _load(self) -> None:
        self.t, positions = read_frame(self.directory, self.frames[self.index],
                                       self.garment.particle_count)
        self.positions.from_numpy(positions)

    def advance(self) -> bool:
        if self.index + 1 >= len(self.frames):
            return False
        self.index += 1
        self._load()
        return True

    def lines(self, playing: bool) -> list[str]:
        frame = self.frames[self.index]
        return status_lines(f"{self.scene.name} (cache: {self.directory})",
                            self.stats.get("integrator", self.scene.simulation.integrator),
                            self.stats.get("dt", np.nan), self.stats.get("substeps_per_frame", 0),
                            frame, self.frames[-1], self.t, self.per_frame.get(frame), playing)


def check_display() -> None:
    """A window needs a display: say how to get one when there is none."""
    if not (os.environ.get("DISPLAY") or os.environ.get("WAYLAND_DISPLAY")):
        raise InputError("view: no display to open a window on (DISPLAY is not set); on a "
                         "machine without one, run it under a virtual display: xvfb-run -a "
                         "python -m taichi_cloth view ...")


def view(scene, from_cache: str | None, size: tuple, frames: int | None,
         screenshot: str | None, quiet: bool) -> int:
    """The ``view`` command: ``scene`` (a loaded Scene; None with ``from_cache``) in a window of
    ``size`` (width, height; None: the scene's), until the user quits, or for ``frames`` frames
    saving ``screenshot``."""
    from taichi_cloth.render.renderer import Renderer
    from taichi_cloth.render.viewer import run_viewer
    from taichi_cloth.runtime import start_taichi
    check_display()
    if frames is not None and frames < 1:
        raise InputError(f"--frames {frames}: must be at least 1")
    if from_cache is not None:
        source = CacheSource(Path(from_cache))
        scene = source.scene
    else:
        start_taichi(scene.simulation.arch)
        source = LiveSource(scene, quiet)
    width, height = size[0] or scene.render.width, size[1] or scene.render.height
    with Renderer(scene, source.garment, source.body, width, height, visible=True) as renderer:
        shown, saved = run_viewer(renderer, source, frames,
                                  Path(screenshot) if screenshot else None)
    if not quiet and screenshot:
        print(f"{scene.name}: {shown} frames shown, " + (
            f"the last saved to {screenshot}" if saved else
            f"not saved to {screenshot} (the window was closed; stop with q or Esc, or give "
            f"--frames, to save it)"))
    return 0
