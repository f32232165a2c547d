"""A scene's run with its outputs: frames (PNG, video), meshes, ``stats.json``, and after a stop
a checkpoint. ``run_scene`` drives ``Simulation.run`` and writes each frame's files as it comes;
files are written whole or not at all (``output.files.atomic_path``)."""

import contextlib
import json
import os
import re
import shlex
import sys
import tempfile
import textwrap
import time
from pathlib import Path

import numpy as np

from taichi_cloth.output.checkpoint import (Checkpoint, load_checkpoint, outputs_fingerprint,
                                            remove_checkpoint, save_checkpoint, scene_fingerprint)
from taichi_cloth.errors import InputError, UnstableError
from taichi_cloth.output.files import read_png, write_json, write_png
from taichi_cloth.output.budget import RunLimits, check_memory, check_time
from taichi_cloth.output.cache import CacheWriter
from taichi_cloth.output.folder import OwnedFolder
from taichi_cloth.output.exports import mesh_series
from taichi_cloth.output.video import video_writer
from taichi_cloth.output.progress import Progress, announce
from taichi_cloth.config.scene import Scene

OUTPUT_ROOT = Path("output")
NAME_LENGTH = 80  # characters of a scene's name in file names
FRAME_DIR = "frames"  # PNG frames, inside the output folder
CONSOLE_SCRIPT = "taichi-cloth"  # pyproject.toml's command


def safe_name(name: str) -> str:
    """``name`` as one safe file-name component: runs of anything but letters, digits, '.',
    '_' and '-' become '-', no leading dots or dashes, at most ``NAME_LENGTH`` characters
    ("scene" when nothing is left): a scene's name is never a path."""
    slug = re.sub(r"[^A-Za-z0-9._-]+", "-", name).strip(".-")[:NAME_LENGTH].rstrip(".-")
    return slug or "scene"


def output_dir(scene: Scene, out: str | None) -> Path:
    """--out, else [output].dir, else output/<the scene's safe name>."""
    if out:
        return Path(out)
    if scene.output.dir:
        return Path(scene.output.dir)
    return OUTPUT_ROOT / safe_name(scene.name)


def check_writable(directory: Path, flag: str) -> None:
    """Fail early, before simulating, if ``directory`` cannot be created or written: the nearest
    existing ancestor must be a folder in which a temporary folder can be made (and is removed
    again, so nothing is left behind; permission bits alone say nothing for root)."""
    existing = directory
    while not existing.exists():
        existing = existing.parent
    if not existing.is_dir():
        raise InputError(f"{flag} {directory}: {existing} is not a folder")
    try:
        os.rmdir(tempfile.mkdtemp(prefix=".write-check-", dir=existing))
    except OSError as error:
        raise InputError(f"{flag} {directory}: cannot write in {existing} "
                         f"({error.strerror})") from None


def run_scene(scene: Scene, frame_count: int, directory: Path, quiet: bool,
              size: tuple[int, int] | None = None, video: str = "", meshes=(),
              body_meshes: bool = False, resume: bool = False,
              limits: RunLimits = RunLimits()) -> int:
    """Write frame 0 (the start, after ``Simulation.settle``) and simulate frames 1 …
    ``frame_count``; per frame render a PNG and a video frame (when ``size``
    is given) and write meshes; then stats.json and a one-line summary. An interrupted or
    unstable run still leaves stats.json for the frames done (and, interrupted, a checkpoint that
    ``resume`` continues from). The run owns ``directory`` while it writes (``OwnedFolder``:
    locked; afterwards only files of an earlier run's manifest are removed, never others).
    ``limits``: memory and time beyond which the run stops before the work (``budget``)."""
    # the scene's [output] dir when that is where it goes, else the flag
    flag = "output.dir" if scene.output.dir and directory == Path(scene.output.dir) else "--out"
    check_writable(directory, flag)
    check_memory(scene, limits)
    with OwnedFolder(directory, flag) as folder:
        return run_in_folder(scene, frame_count, folder, quiet, size, video, meshes,
                             body_meshes, resume, limits)


def run_in_folder(scene: Scene, frame_count: int, folder: OwnedFolder, quiet: bool,
                  size: tuple[int, int] | None, video: str, meshes, body_meshes: bool,
                  resume: bool, limits: RunLimits) -> int:
    """``run_scene`` in its locked folder."""
    from taichi_cloth.physics.metrics import FrameMetrics, RunRecord
    from taichi_cloth.physics.simulation import Simulation
    from taichi_cloth.physics.settling import settle
    directory = folder.directory
    if size is not None:  # a bad texture is said before anything is simulated
        from taichi_cloth.render.texture import load_texture, texture_path
        image = texture_path(scene)
        if image is not None:
            load_texture(image)
    announce(scene.name, "building the cloth, the body and the effects", quiet)
    if "usd" in meshes:  # a missing usd-core is said before anything is simulated
        from taichi_cloth.output.usd import import_pxr
        import_pxr()
    simulation = Simulation.from_scene(scene)
    check_time(simulation, frame_count, limits)
    outputs = outputs_fingerprint(size, video, meshes, body_meshes)
    record = RunRecord()
    first_frame = 0
    if resume:
        whole = [name for name in ("xdmf", "usd", "pc2") if name in meshes]
        if whole:
            raise InputError(f"--resume: a {whole[0]} file is written whole at the end and "
                             f"cannot be continued; run again without --resume, or without "
                             f"{whole[0]}")
        checkpoint = load_checkpoint(directory, scene, simulation.model.particle_count, outputs)
        simulation.restore(checkpoint.snapshot)
        first_frame = checkpoint.next_frame
        previous = read_previous_stats(directory, first_frame)
        simulation.settle_report = previous.get("settle")
        record.frames = [FrameMetrics.from_dict(frame)
                         for frame in previous["per_frame"][:first_frame]]
        record.retries = checkpoint.retries
        record.cg_iterations = checkpoint.cg_iterations.tolist()
        if first_frame > frame_count:
            raise InputError(f"--resume: frames 0–{first_frame - 1} are done already; ask for "
                             f"more with --frames")
    else:
        if scene.simulation.settle > 0:
            announce(scene.name, f"settling on the still body before frame 0 (at most "
                                 f"{scene.simulation.settle:g} s simulated; kernels compile "
                                 f"first)", quiet)
        settle(simulation, record)
    finished = {}  # the last whole frame: its index and host copies of its state
    body = simulation.body_rig.body if simulation.body_rig is not None else None
    with contextlib.ExitStack() as stack:
        renderer = append_video = None
        if size is not None:
            from taichi_cloth.render.renderer import Renderer
            renderer = stack.enter_context(Renderer(scene, simulation.garment, body, *size))
            if video:
                append_video = stack.enter_context(video_writer(
                    directory / f"{safe_name(scene.name)}.{video}", video, scene.scene.fps))
                for frame in range(first_frame):
                    append_video(read_png(directory / FRAME_DIR / f"frame_{frame:05d}.png"))
        series = mesh_series(scene, simulation.garment, body, directory, meshes, body_meshes)
        cache = CacheWriter(directory, scene, simulation.model.particle_count)
        progress = stack.enter_context(Progress(scene.name, frame_count + 1 - first_frame, quiet))
        seconds = {"render": 0.0, "export": 0.0}

        def on_frame(frame, metrics):
            t = simulation.frame_time(frame)
            started = time.perf_counter()
            if renderer is not None:
                image = renderer.draw(simulation.state_in.x, t)
                write_png(directory / FRAME_DIR / f"frame_{frame:05d}.png", image)
                if append_video is not None:
                    append_video(image)
            rendered = time.perf_counter()
            snapshot = simulation.snapshot(effects=True)  # the frame's one read of the state
            for mesh, points in series:
                mesh.append(frame, t, points(t, snapshot.positions))
            real = simulation.model.numpy_real  # the cache keeps the simulation's own values
            cache.append(frame, t, snapshot.positions.astype(real),
                         snapshot.velocities.astype(real))
            seconds["render"] += rendered - started
            seconds["export"] += time.perf_counter() - rendered
            finished.update(frame=frame, snapshot=snapshot)
            progress.update(t)

        try:
            simulation.run(frame_count, on_frame, record, first_frame)
        except (KeyboardInterrupt, SystemExit, UnstableError, OSError) as stop:
            keep_partial_run(simulation, record, folder, finished, stop, resume, outputs)
            raise
        for mesh, _ in series:
            mesh.finish()
    if renderer is not None:
        record.wall_seconds["render"] = seconds["render"]
    if series:
        record.wall_seconds["export"] = seconds["export"]
    stats = simulation.stats(record)
    if first_frame:
        stats["resumed_at_frame"] = first_frame
    write_json(directory / "stats.json", stats)
    remove_checkpoint(directory)
    folder.finish(resume)
    if not quiet:
        print(summary(stats, directory))
    dropped = stats["per_frame"][-1].get("self_collision_overflow", 0) if stats["per_frame"] else 0
    if dropped:
        print(f"warning: {stats['scene']}: effects.self_collision: {dropped} candidate pairs or "
              f"partner patches did not fit its lists, so contacts may have been missed "
              f"(self_collision_overflow in stats.json)", file=sys.stderr)
    return 0


def read_previous_stats(directory: Path, first_frame: int) -> dict:
    """The interrupted run's stats.json, with at least ``first_frame`` frames; InputError
    naming --resume when it is missing, unreadable or short."""
    path = directory / "stats.json"
    try:
        document = json.loads(path.read_text())
        frames = document["per_frame"]
        if not isinstance(frames, list) or len(frames) < first_frame:
            raise ValueError(f"{len(frames)} frames, the checkpoint needs {first_frame}")
    except (OSError, ValueError, KeyError, TypeError) as error:
        raise InputError(f"--resume: {path} cannot continue the run ({error}); start again "
                         f"without --resume") from None
    return document


def keep_partial_run(simulation, record, folder: OwnedFolder, finished: dict, stop,
                     resumed: bool, outputs: str) -> None:
    """After a stop: stats.json for the whole frames done (marked ``stopped``) and, when
    interrupted (not unstable), a checkpoint and how to resume on stderr; the manifest of what
    the run wrote. After a file-system error (a full disk) as much of it as there is room for:
    the error that stopped the run is the one reported."""
    if not finished:
        return
    directory = folder.directory
    try:
        write_partial_outputs(simulation, record, directory, finished, stop, outputs)
    except OSError:
        if not isinstance(stop, OSError):
            raise
    finally:
        try:
            folder.finish(resumed)
        except OSError:
            if not isinstance(stop, OSError):
                raise


def write_partial_outputs(simulation, record, directory: Path, finished: dict, stop,
                          outputs: str) -> None:
    """``keep_partial_run``'s files: stats.json, and the checkpoint unless unstable."""
    done = finished["frame"] + 1
    record.frames = record.frames[:done]
    stats = simulation.stats(record)
    unstable = isinstance(stop, UnstableError)
    stats["stopped"] = "unstable" if unstable else \
        "file-system error" if isinstance(stop, OSError) else "interrupted"
    write_json(directory / "stats.json", stats)
    if unstable:
        return
    save_checkpoint(directory, Checkpoint(
        next_frame=done, snapshot=finished["snapshot"], retries=record.retries,
        fingerprint=scene_fingerprint(simulation.scene),
        cg_iterations=np.array(record.cg_iterations, np.int64), outputs=outputs))
    if isinstance(stop, OSError):  # its own one line follows
        return
    sys.stderr.write(f"stopped after frame {done - 1}: frames 0–{done - 1} and stats.json are "
                     f"in {directory}; to continue: {resume_command()}\n")


def invocation() -> list[str]:
    """The words that start this command line again: the ``taichi-cloth`` console script as it
    was called, else this interpreter (relative to the working folder when inside it, e.g.
    .venv/bin/python) with ``-m taichi_cloth``."""
    script = Path(sys.argv[0])
    if script.name == CONSOLE_SCRIPT:
        return [sys.argv[0]]
    python = Path(sys.executable)
    try:
        python = python.relative_to(Path.cwd())
    except ValueError:
        pass
    return [str(python), "-m", "taichi_cloth"]


def resume_command() -> str:
    """The command that continues this run: ``invocation()``, the same arguments, --resume
    once."""
    arguments = [argument for argument in sys.argv[1:] if argument != "--resume"]
    return shlex.join([*invocation(), *arguments, "--resume"])


def summary(stats: dict, directory: Path) -> str:
    """A few lines of at most 100 columns (the folder's path aside): frames, integrator and step
    (and how ``dt = "auto"`` chose it, or why a given one was split, with the integrator that
    takes it whole); a settling that took a smaller step or did not come to rest; strain,
    penetration and self-crossings (with how to add self-collision where the cloth crossed
    itself without it); seconds per phase and where the files are."""
    seconds = ", ".join(f"{phase} {value:.2f} s" for phase, value in stats["wall_seconds"].items())
    step = stats["time_step"]
    retries = f", {stats['retries']} halvings" if stats["retries"] else ""
    lines = [f"{stats['scene']}: {stats['frames']} frames, {stats['integrator']}, dt "
             f"{stats['dt']:.4g} s × {stats['substeps_per_frame']} a frame{retries}"]
    if step["requested"] == "auto":
        bound = "none" if step["stable_dt"] is None else f"{step['stable_dt']:.3g} s"
        pins = step.get("pin_acceleration")
        lines.append(f"  dt auto: ω_max {step['omega_max']:.3g} rad/s, stability bound {bound}"
                     + (f", pins' peak acceleration {pins:.3g} m/s²" if pins else ""))
    elif step.get("stable_dt") is not None:
        lines.append(f"  dt split below the scene's {step['requested']:g} s: self-collision's "
                     f"penalty is stable up to {step['stable_dt']:.3g} s")
        lines.append("  (backward Euler takes the scene's step with it: "
                     "--set simulation.integrator=implicit)")
    settled = stats.get("settle")
    if settled and settled.get("step_halvings"):
        lines.append(f"  settled at 1/{2 ** settled['step_halvings']} of the scene's step, "
                     f"which the dance takes (at it the garment kept moving)")
    elif settled and not settled["at_rest"]:
        lines.append(f"  settling: not at rest after {settled['simulated_seconds']:.2f} s "
                     f"(mean speed {settled['mean_speed']:.3f} m/s)")
    lines.append(f"  max strain {stats['max_strain']:.4f}, max penetration "
                 f"{stats['max_penetration'] * 1000:.2f} mm, at most "
                 f"{stats['max_self_intersections']} pairs of triangles through each other")
    if stats["max_self_intersections"] and "self_collision" not in stats.get("effects", ()):
        lines.append("  (no self-collision in this scene: --set effects.self_collision=true "
                     "adds it, on the CPU)")
    lines += textwrap.wrap(seconds, 100, initial_indent="  ", subsequent_indent="  ")
    return "\n".join(lines) + f" → {directory}"
