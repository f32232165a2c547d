"""The integrators side by side at one step, like the seed paper's Figs. 6–8: a labelled video
(``side_by_side.mp4``, one tile per integrator, frame by frame) and a contact sheet
(``contact_sheet.png``, a row per integrator, a few frames across).

The runs are already simulated (``compare.Run`` keeps every frame's positions); one headless
``Renderer`` draws each run's cloth from a scratch position field. A run that blew up shows the
state the guard rejected (when finite: what blowing up looks like), then keeps showing its last
state, dimmed, at that frame's time, labelled with when it blew up.
Labels are drawn with matplotlib over the tiled frame, so no font library is needed.
"""

from pathlib import Path

import numpy as np
import taichi as ti
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure

from taichi_cloth.studies.compare_plots import INTEGRATOR_TITLES, milliseconds, save
from taichi_cloth.errors import InputError
from taichi_cloth.output.video import video_writer
from taichi_cloth.output.progress import Progress

TILE_WIDTH = 480  # pixels per integrator in the video
LABEL_HEIGHT = 44  # pixels of label strip above the tiles
TILE_GAP = 6  # white pixels between tiles
SHEET_COLUMNS = 5  # frames per integrator on the contact sheet
DIMMED = 0.45  # a blown-up run's last frame: this much of it, the rest white


def tile_label(run, failed: bool, t: float) -> tuple[str, str, str]:
    """(title line, status line, status colour) of ``run``'s tile at frame time ``t`` [s];
    ``failed``: the run blew up in this frame or before."""
    title = f"{INTEGRATOR_TITLES[run.integrator]} · dt = {milliseconds(run.time_step.dt)}"
    if failed:
        return title, f"blew up at t = {run.blowup_time:.2f} s", "tab:red"
    return title, f"t = {t:.2f} s", "black"


def side_by_side(tiles: list[np.ndarray]) -> np.ndarray:
    """Tiles of one height in a row, ``TILE_GAP`` white pixels apart."""
    gap = np.full((tiles[0].shape[0], TILE_GAP, 3), 255, np.uint8)
    return np.concatenate([part for tile in tiles for part in (tile, gap)][:-1], axis=1)


def labelled(image: np.ndarray, labels: list[tuple[str, str, str]]) -> np.ndarray:
    """``image`` (tiles side by side) under a white strip with each tile's two label lines (only
    the strip goes through matplotlib: drawing the whole frame there took ~6× as long)."""
    width = image.shape[1]
    figure = Figure(figsize=(width / 100, LABEL_HEIGHT / 100), dpi=100, facecolor="white")
    canvas = FigureCanvasAgg(figure)
    tile = (width + TILE_GAP) / len(labels)
    for k, (title, status, color) in enumerate(labels):
        x = (k * tile + 8) / width
        figure.text(x, 1.0 - 0.32, title, fontsize=11, weight="bold", va="center")
        figure.text(x, 1.0 - 0.75, status, fontsize=10, color=color, va="center")
    canvas.draw()
    strip = np.asarray(canvas.buffer_rgba())[..., :3]
    return np.concatenate([strip, image])


def write_contact_sheet(target: Path, runs: list, sheet: dict, times: list) -> None:
    """sheet: (run index, frame) → (image, label); a row per run, ``SHEET_COLUMNS`` frames."""
    frames = sorted({frame for _, frame in sheet})
    image_height, image_width = next(iter(sheet.values()))[0].shape[:2]
    aspect = image_height / image_width
    figure = Figure(figsize=(2.4 * len(frames) + 0.4, (2.4 * aspect + 0.3) * len(runs) + 0.5))
    panels = np.atleast_2d(figure.subplots(len(runs), len(frames)))
    for (index, frame), (image, (title, status, color)) in sheet.items():
        axes = panels[index, frames.index(frame)]
        axes.imshow(image)
        axes.set_xticks([])
        axes.set_yticks([])
        axes.set_title(status, fontsize=8, color=color)
        if frame == frames[0]:
            axes.set_ylabel(title.replace(" · ", "\n"), fontsize=8)
    figure.suptitle(f"Integrators side by side at dt = {milliseconds(runs[0].time_step.dt)} "
                    f"(frames at t = {', '.join(f'{times[f]:.2f}' for f in frames)} s)",
                    fontsize=10)
    save(figure, target)


def write_video_and_sheet(directory: Path, simulation, runs: list, quiet: bool) -> None:
    """``side_by_side.mp4`` and ``contact_sheet.png`` of ``runs`` (one per integrator, the same
    step) of ``simulation``'s scene. No Vulkan driver: ``InputError`` naming ``--no-video``."""
    from taichi_cloth.render.renderer import Renderer
    scene = simulation.scene
    width = TILE_WIDTH
    height = round(width * scene.render.height / scene.render.width / 2) * 2
    frame_count = scene.frame_count + 1  # frame 0 (the start) to the last
    times = [simulation.frame_time(k) for k in range(frame_count)]
    sheet_frames = set(np.linspace(0, frame_count - 1, min(SHEET_COLUMNS, frame_count))
                       .round().astype(int).tolist())
    positions = ti.Vector.field(3, ti.f32, simulation.model.particle_count)
    body = simulation.body_rig.body if simulation.body_rig is not None else None
    sheet = {}
    try:
        renderer = Renderer(scene, simulation.garment, body, width, height)
    except InputError as error:
        raise InputError(f"{error}; or pass --no-video") from None
    with renderer, Progress("side by side", frame_count, quiet) as progress, \
            video_writer(directory / "side_by_side.mp4", "mp4", scene.scene.fps) as append:
        for frame in range(frame_count):
            tiles, labels = [], []
            for index, run in enumerate(runs):
                states = run.positions + ([run.blowup_positions]
                                          if run.blowup_positions is not None else [])
                shown = min(frame, len(states) - 1)
                if shown < 0:
                    tile = np.full((height, width, 3), 255, np.uint8)
                else:
                    positions.from_numpy(states[shown].astype(np.float32))
                    tile = renderer.draw(positions, times[shown])
                label = tile_label(run, frame >= len(run.positions), times[frame])
                if shown < frame:
                    tile = (DIMMED * tile + (1 - DIMMED) * 255).astype(np.uint8)
                if frame in sheet_frames:
                    sheet[index, frame] = (tile, label)
                tiles.append(tile)
                labels.append(label)
            append(labelled(side_by_side(tiles), labels))
            progress.update(times[frame])
    write_contact_sheet(directory / "contact_sheet.png", runs, sheet, times)
