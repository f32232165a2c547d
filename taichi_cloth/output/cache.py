"""The simulation cache: what a run computed, kept so that frames, video and meshes can be made
again without simulating (``render --from-cache DIR``).

``simulate`` and ``render`` write ``<out>/cache/``:

- ``scene.json``: the format version, the scene file's path and its TOML tables after every
  ``--set`` (``Scene.document``: the resolved scene, from which ``config.scene`` builds the same
  ``Scene`` again), the particle count and the frames per second;
- ``frame_NNNNN.npz`` per frame (NumPy, not compressed: ``hula``'s positions and velocities
  deflate by 8 % at 9× the time, 2.2 ms a frame against 0.24 ms): its time ``t`` [s] and the
  particles' ``positions`` [m] and ``velocities`` [m/s] in the simulation's precision (float32
  for f32 scenes, so a replay draws exactly what the run drew).

A frame's file is written whole or not at all (``files.atomic_path``) as soon as the frame is
done, so the cache can be read while the run goes on, and a resumed run adds the frames it
computes. The capsules are not stored: the body's pose is a function of time
(``body.dancer.Body.pose``), rebuilt from the scene.
"""

import json
from pathlib import Path

import numpy as np

from taichi_cloth.config.scene import Scene, scene_from_document
from taichi_cloth.errors import InputError
from taichi_cloth.output.files import atomic_path

CACHE_DIR = "cache"
SCENE_FILE = "scene.json"
FORMAT = 1


def frame_path(directory: Path, frame: int) -> Path:
    return Path(directory) / CACHE_DIR / f"frame_{frame:05d}.npz"


class CacheWriter:
    """Writes a run's cache under ``directory`` (module docstring)."""

    def __init__(self, directory: Path, scene: Scene, particle_count: int):
        self.directory = Path(directory)
        description = {"format": FORMAT, "scene_path": scene.path, "document": scene.document,
                       "particles": particle_count, "fps": scene.scene.fps}
        with atomic_path(self.directory / CACHE_DIR / SCENE_FILE) as temporary:
            temporary.write_text(json.dumps(description, indent=1), encoding="utf-8")

    def append(self, frame: int, t: float, positions: np.ndarray,
               velocities: np.ndarray) -> None:
        """Frame ``frame`` at time ``t`` [s]: positions [m] and velocities [m/s] (N, 3)."""
        with atomic_path(frame_path(self.directory, frame)) as temporary:
            with open(temporary, "wb") as handle:
                np.savez(handle, t=np.float64(t), positions=positions, velocities=velocities)


def read_cache(directory: Path) -> tuple[Scene, list[int]]:
    """The scene of the cache under ``directory`` and its frames, in order; an InputError
    naming the folder when there is none or it does not fit its scene."""
    folder = Path(directory) / CACHE_DIR
    try:
        description = json.loads((folder / SCENE_FILE).read_text(encoding="utf-8"))
    except (OSError, ValueError) as error:
        raise InputError(f"--from-cache {directory}: no simulation cache there "
                         f"({folder / SCENE_FILE}: {error})") from None
    if description.get("format") != FORMAT:
        raise InputError(f"--from-cache {directory}: cache format {description.get('format')} "
                         f"is not {FORMAT}")
    scene = scene_from_document(Path(description["scene_path"]), description["document"])
    frames = sorted(int(path.stem.removeprefix("frame_"))
                    for path in folder.glob("frame_[0-9]*.npz"))
    if not frames:
        raise InputError(f"--from-cache {directory}: the cache holds no frame")
    return scene, frames


def read_frame(directory: Path, frame: int, particle_count: int) -> tuple[float, np.ndarray]:
    """(t [s], positions (N, 3) [m]) of a cached frame, checked against the particle count."""
    with np.load(frame_path(directory, frame)) as data:
        t, positions = float(data["t"]), data["positions"]
    if positions.shape != (particle_count, 3):
        raise InputError(f"--from-cache {directory}: frame {frame} holds {positions.shape[0]} "
                         f"particles, its scene {particle_count}")
    return t, positions
