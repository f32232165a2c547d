"""Stopping and resuming a run: the state at the end of the last finished frame, on disk.

When a run is interrupted (Ctrl-C, SIGTERM) the command writes ``checkpoint.npz`` beside
``stats.json``: positions and velocities after the last whole frame, what the integrator carries
between steps (``Integrator.memory``: the implicit solver's warm start) and what the effects carry
(``Effect.memory``: self-collision's candidate pairs and side records), the time step in force
(the guard may have halved it), the retries so far and a fingerprint of the validated scene. ``--resume``
loads it, refuses it if the scene (file or overrides) or the outputs asked for (frame size,
video, mesh formats) changed, and continues from the next frame. It trusts nothing it reads: the
file carries a format version and a SHA-256 checksum of its arrays, and a file that is cut short,
overwritten, of another version or particle count, or holds a non-finite state or an impossible
frame, step or count is refused with one line (exit code 2). A finished run removes its
checkpoint.
"""

import hashlib
import io
import math
import zipfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from taichi_cloth.errors import InputError
from taichi_cloth.output.files import atomic_path
from taichi_cloth.config.scene import Scene
from taichi_cloth.physics.snapshot import Snapshot

CHECKPOINT_NAME = "checkpoint.npz"
FORMAT_VERSION = 3  # 3: the effects' memory (self-collision's pairs and records)


def scene_fingerprint(scene: Scene) -> str:
    """A hash of every validated setting (frozen dataclasses have a deterministic repr)."""
    return hashlib.sha256(repr(scene).encode()).hexdigest()[:16]


@dataclass(frozen=True)
class Checkpoint:
    """next_frame: the first frame still to simulate; snapshot: the simulation at its start
    (``physics.snapshot.Snapshot``: state, time step, integrator and effect memory); retries so
    far; fingerprint of the scene; cg_iterations: the CG iterations of every step so far
    (implicit); outputs: what the run writes besides stats.json (``outputs_fingerprint``)."""

    next_frame: int
    snapshot: Snapshot
    retries: int
    fingerprint: str
    cg_iterations: np.ndarray
    outputs: str = ""


def outputs_fingerprint(size, video: str, meshes, body_meshes: bool) -> str:
    """The outputs a run writes per frame, as text: frame size, video format, mesh formats."""
    return repr((tuple(size) if size is not None else None, video or "", sorted(meshes or ()),
                 bool(body_meshes)))


def checksum(arrays: dict) -> str:
    """SHA-256 of the arrays' names, dtypes, shapes and bytes, in name order."""
    digest = hashlib.sha256()
    for name in sorted(arrays):
        value = np.asarray(arrays[name])
        digest.update(f"{name}:{value.dtype.str}:{value.shape}".encode())
        digest.update(np.ascontiguousarray(value).tobytes())
    return digest.hexdigest()


MEMORY_PREFIX = "memory."  # npz keys of the integrator's memory
EFFECT_PREFIX = "effect."  # npz keys of the effects' memory (``Snapshot.effect_memory``)
SNAPSHOT_KEYS = ("positions", "velocities", "dt", "substeps_per_frame")


def save_checkpoint(directory: Path, checkpoint: Checkpoint) -> None:
    buffer = io.BytesIO()
    snapshot = checkpoint.snapshot
    arrays = {key: getattr(snapshot, key) for key in SNAPSHOT_KEYS}
    arrays.update(next_frame=checkpoint.next_frame, retries=checkpoint.retries,
                  fingerprint=checkpoint.fingerprint, cg_iterations=checkpoint.cg_iterations,
                  outputs=checkpoint.outputs, version=FORMAT_VERSION)
    arrays.update({MEMORY_PREFIX + name: value
                   for name, value in snapshot.integrator_memory.items()})
    arrays.update({EFFECT_PREFIX + name: value for name, value in snapshot.effect_memory.items()})
    arrays = {name: np.asarray(value) for name, value in arrays.items()}
    np.savez(buffer, checksum=checksum(arrays), **arrays)
    with atomic_path(Path(directory) / CHECKPOINT_NAME) as temporary:
        temporary.write_bytes(buffer.getvalue())


def load_checkpoint(directory: Path, scene: Scene, particle_count: int | None = None,
                    outputs: str | None = None) -> Checkpoint:
    """The checkpoint in ``directory`` for this very scene (and ``particle_count``, ``outputs``
    when given); InputError naming --resume if there is none, it belongs to other settings, or it
    is damaged or inconsistent (module docstring)."""
    path = Path(directory) / CHECKPOINT_NAME
    if not path.is_file():
        raise InputError(f"--resume: no {CHECKPOINT_NAME} in {directory} (nothing was interrupted "
                         f"there, or the run finished)")
    damaged = f"--resume: {path} is damaged or not a checkpoint of this version"
    try:
        with np.load(path, allow_pickle=False) as data:
            arrays = {name: data[name] for name in data.files}
    except (OSError, ValueError, EOFError, zipfile.BadZipFile, KeyError) as error:
        raise InputError(f"{damaged} ({type(error).__name__}); start again without "
                         f"--resume") from None
    stored = arrays.pop("checksum", None)
    if stored is None or str(stored) != checksum(arrays) or \
            int(arrays.get("version", -1)) != FORMAT_VERSION:
        raise InputError(f"{damaged} (its checksum or version does not match); start again "
                         f"without --resume")
    try:
        checkpoint = checkpoint_from_arrays(arrays)
    except (KeyError, ValueError, TypeError) as error:
        raise InputError(f"{damaged} ({error}); start again without --resume") from None
    if checkpoint.fingerprint != scene_fingerprint(scene):
        raise InputError(f"--resume: {path} was written for other scene settings; run the same "
                         f"scene with the same --set options, or start again without --resume")
    if outputs is not None and checkpoint.outputs != outputs:
        raise InputError(f"--resume: {path} was written by a run with other outputs (frame "
                         f"size, --video, --meshes); resume with the same flags, or start again "
                         f"without --resume")
    problem = checkpoint_problem(checkpoint, particle_count)
    if problem:
        raise InputError(f"--resume: {path} {problem}; start again without --resume")
    return checkpoint


def checkpoint_from_arrays(arrays: dict) -> Checkpoint:
    """The checkpoint in the arrays of its file (KeyError, ValueError or TypeError when one is
    missing or of the wrong kind)."""
    snapshot = Snapshot(
        positions=arrays["positions"], velocities=arrays["velocities"], dt=float(arrays["dt"]),
        substeps_per_frame=int(arrays["substeps_per_frame"]),
        integrator_memory={key[len(MEMORY_PREFIX):]: value for key, value in arrays.items()
                           if key.startswith(MEMORY_PREFIX)},
        effect_memory={key[len(EFFECT_PREFIX):]: value for key, value in arrays.items()
                       if key.startswith(EFFECT_PREFIX)})
    return Checkpoint(next_frame=int(arrays["next_frame"]), snapshot=snapshot,
                      retries=int(arrays["retries"]), fingerprint=str(arrays["fingerprint"]),
                      cg_iterations=arrays["cg_iterations"], outputs=str(arrays["outputs"]))


def checkpoint_problem(checkpoint: Checkpoint, particle_count: int | None) -> str:
    """What makes a well-formed checkpoint unusable, or ""."""
    snapshot = checkpoint.snapshot
    count = len(snapshot.positions)
    if snapshot.positions.shape != (count, 3) or snapshot.velocities.shape != (count, 3) or \
            (particle_count is not None and count != particle_count):
        return f"holds {count} particles' state, not the scene's {particle_count}"
    if not (np.isfinite(snapshot.positions).all() and np.isfinite(snapshot.velocities).all()):
        return "holds a non-finite state"
    if any(not np.isfinite(np.asarray(value, float)).all()
           for value in (*snapshot.integrator_memory.values(), *snapshot.effect_memory.values())):
        return "holds a non-finite solver or effect memory"
    if checkpoint.next_frame < 1 or checkpoint.retries < 0 or snapshot.substeps_per_frame < 1 \
            or not (math.isfinite(snapshot.dt) and snapshot.dt > 0):
        return (f"holds an impossible frame, step or count (next frame {checkpoint.next_frame}, "
                f"dt {snapshot.dt}, {snapshot.substeps_per_frame} substeps)")
    return ""


def remove_checkpoint(directory: Path) -> None:
    (Path(directory) / CHECKPOINT_NAME).unlink(missing_ok=True)
