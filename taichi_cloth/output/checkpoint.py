"""Stopping and resuming a run: the state at the end of the last finished frame, on disk.

When a run is interrupted (Ctrl-C, SIGTERM) the command writes ``checkpoint.npz`` beside
``stats.json``: positions and velocities after the last whole frame, what the integrator carries
between steps (``Integrator.memory``: the implicit solver's warm start), the time step in force
(the guard may have halved it), the retries so far and a fingerprint of the validated scene. ``--resume``
loads it, refuses it if the scene (file or overrides) changed, and continues from the next frame.
A finished run removes its checkpoint.
"""

import hashlib
import io
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from taichi_cloth.errors import InputError
from taichi_cloth.output.files import atomic_path
from taichi_cloth.config.scene import Scene
from taichi_cloth.physics.simulation import Snapshot

CHECKPOINT_NAME = "checkpoint.npz"


def scene_fingerprint(scene: Scene) -> str:
    """A hash of every validated setting (frozen dataclasses have a deterministic repr)."""
    return hashlib.sha256(repr(scene).encode()).hexdigest()[:16]


@dataclass(frozen=True)
class Checkpoint:
    """next_frame: the first frame still to simulate; snapshot: the simulation at its start
    (``physics.simulation.Snapshot``: state, time step in force, integrator memory); retries so
    far; fingerprint of the scene; cg_iterations: the CG iterations of every step so far
    (implicit)."""

    next_frame: int
    snapshot: Snapshot
    retries: int
    fingerprint: str
    cg_iterations: np.ndarray


MEMORY_PREFIX = "memory."  # npz keys of the integrator's memory
SNAPSHOT_KEYS = ("positions", "velocities", "dt", "substeps_per_frame")


def save_checkpoint(directory: Path, checkpoint: Checkpoint) -> None:
    buffer = io.BytesIO()
    snapshot = checkpoint.snapshot
    arrays = {key: getattr(snapshot, key) for key in SNAPSHOT_KEYS}
    arrays.update(next_frame=checkpoint.next_frame, retries=checkpoint.retries,
                  fingerprint=checkpoint.fingerprint, cg_iterations=checkpoint.cg_iterations)
    arrays.update({MEMORY_PREFIX + name: value
                   for name, value in snapshot.integrator_memory.items()})
    np.savez(buffer, **arrays)
    with atomic_path(Path(directory) / CHECKPOINT_NAME) as temporary:
        temporary.write_bytes(buffer.getvalue())


def load_checkpoint(directory: Path, scene: Scene) -> Checkpoint:
    """The checkpoint in ``directory`` for this very scene; InputError naming --resume if there
    is none or it belongs to other settings."""
    path = Path(directory) / CHECKPOINT_NAME
    if not path.is_file():
        raise InputError(f"--resume: no {CHECKPOINT_NAME} in {directory} (nothing was interrupted "
                         f"there, or the run finished)")
    with np.load(path) as data:
        snapshot = Snapshot(
            positions=data["positions"], velocities=data["velocities"], dt=float(data["dt"]),
            substeps_per_frame=int(data["substeps_per_frame"]),
            integrator_memory={key[len(MEMORY_PREFIX):]: data[key] for key in data.files
                               if key.startswith(MEMORY_PREFIX)})
        checkpoint = Checkpoint(
            next_frame=int(data["next_frame"]), snapshot=snapshot, retries=int(data["retries"]),
            fingerprint=str(data["fingerprint"]), cg_iterations=data["cg_iterations"])
    if checkpoint.fingerprint != scene_fingerprint(scene):
        raise InputError(f"--resume: {path} was written for other scene settings; run the same "
                         f"scene with the same --set options, or start again without --resume")
    return checkpoint


def remove_checkpoint(directory: Path) -> None:
    (Path(directory) / CHECKPOINT_NAME).unlink(missing_ok=True)
