"""``render --from-cache DIR``: a run's frames (and video) drawn again from its simulation cache
(``output/cache.py``), without simulating: the scene rebuilt from the cached document, the
garment's rest mesh and the body from it, every cached frame's positions drawn at its time.
For an f32 scene the PNG files are byte for byte those of the run that wrote the cache."""

import contextlib
from pathlib import Path

import numpy as np
import taichi as ti

from taichi_cloth.cloth.garment import build_garment
from taichi_cloth.output.cache import read_cache, read_frame
from taichi_cloth.output.exports import mesh_series
from taichi_cloth.output.files import write_png
from taichi_cloth.output.folder import OwnedFolder
from taichi_cloth.output.progress import Progress
from taichi_cloth.output.run import FRAME_DIR, check_writable, safe_name
from taichi_cloth.output.video import video_writer
from taichi_cloth.physics.rig import BodyRig
from taichi_cloth.runtime import start_taichi


def cached_run(source: Path):
    """(scene, frames, garment, body or None) of the run cached under ``source``: its scene, the
    garment's rest mesh and the body rebuilt from the cached document."""
    scene, frames = read_cache(source)
    start_taichi("cpu")
    body = BodyRig(scene).body if scene.body is not None else None
    waist = body.waist_height if scene.body is not None else None
    return scene, frames, build_garment(scene.cloth, scene.material, waist, scene.path), body


def position_field(scene, garment) -> ti.Field:
    """A field for the cached positions, in the run's precision (what the run drew)."""
    return ti.Vector.field(3, ti.f64 if scene.simulation.precision == "f64" else ti.f32,
                           garment.particle_count)


def draw_cached_frame(source: Path, frame: int, size: tuple[int, int]):
    """One cached frame of the run under ``source`` drawn at ``size`` (width, height) [pixels]:
    an (H, W, 3) uint8 image (a sweep's thumbnail)."""
    from taichi_cloth.render.renderer import Renderer
    scene, _, garment, body = cached_run(source)
    field = position_field(scene, garment)
    with Renderer(scene, garment, body, *size) as renderer:
        t, positions = read_frame(source, frame, garment.particle_count)
        field.from_numpy(positions)
        return renderer.draw(field, t)


def render_from_cache(source: Path, out: Path | None, size: tuple, video: str | None,
                      quiet: bool, meshes=(), body_meshes: bool = False) -> int:
    """Draw every frame cached under ``source`` into ``out`` (default: ``source``) at ``size``
    (width, height: None takes the scene's), with a video when ``video`` is "mp4" or "gif"
    (default: the scene's ``output.video``), and the ``meshes`` formats (and the body's with
    ``body_meshes``) exported from the cached frames: the files the run itself would write. The
    folder keeps what the run wrote there (its cache, stats); frames are replaced."""
    from taichi_cloth.render.renderer import Renderer
    source = Path(source)
    scene, frames, garment, body = cached_run(source)
    directory = source if out is None else Path(out)
    check_writable(directory, "--out")
    size = (size[0] or scene.render.width, size[1] or scene.render.height)
    video = scene.output.video if video is None else video
    field = position_field(scene, garment)
    with OwnedFolder(directory) as folder:
        with contextlib.ExitStack() as stack:
            renderer = stack.enter_context(Renderer(scene, garment, body, *size))
            append_video = stack.enter_context(video_writer(
                directory / f"{safe_name(scene.name)}.{video}", video, scene.scene.fps)) \
                if video else None
            series = mesh_series(scene, garment, body, directory, meshes, body_meshes)
            progress = stack.enter_context(Progress(scene.name, len(frames), quiet))
            for frame in frames:
                t, positions = read_frame(source, frame, garment.particle_count)
                field.from_numpy(positions)
                image = renderer.draw(field, t)
                write_png(directory / FRAME_DIR / f"frame_{frame:05d}.png", image)
                if append_video is not None:
                    append_video(image)
                for mesh, points in series:  # as the run does: its positions in float64
                    mesh.append(frame, t, points(t, positions.astype(np.float64)))
                progress.update(t)
            for mesh, _ in series:
                mesh.finish()
        folder.finish(resumed=True)
    if not quiet:
        print(f"{scene.name}: {len(frames)} frames drawn from the cache in {source} → "
              f"{directory}")
    return 0
