"""The cloth's animation as a PC2 point cache beside an OBJ of its first frame (``--meshes pc2``),
for Blender's Mesh Cache modifier (and 3ds Max, Houdini, Maya, which read the same format).

``meshes/cloth.obj`` is the first frame written, in the seam-split layout with UVs and the
material (``Garment.uv_layout``, ``meshes.write_obj``); ``meshes/cloth.pc2`` holds every frame's
positions of those same vertices, in the same order. The PC2 layout (little-endian): the
12 bytes ``POINTCACHE2\\0``, int32 version 1, int32 point count, float32 start frame, float32
sampling (frames per sample, 1), int32 sample count, then per sample the points as float32
x, y, z. Coordinates are the simulation's, y up. In Blender: import the OBJ with its default
axes (the importer turns y-up into z-up through the object's transform, not the vertices), add a
Mesh Cache modifier (format PC2, this file) and keep its default axes: the cache's points then
land where the OBJ's do, frame k of the scene showing sample k (``scripts/check-blender.py``).
"""

from pathlib import Path

import numpy as np

from taichi_cloth.output.files import atomic_path
from taichi_cloth.output.meshes import obj_topology, seam_comment, write_obj

PC2_SIGNATURE = b"POINTCACHE2\0"


def write_pc2(target: Path, frames: np.ndarray, start_frame: float) -> None:
    """A PC2 file of ``frames`` (S, V, 3) [m], the first at ``start_frame``, one per frame."""
    frames = np.asarray(frames, dtype="<f4")
    header = PC2_SIGNATURE + np.array([1, frames.shape[1]], "<i4").tobytes() \
        + np.array([start_frame, 1.0], "<f4").tobytes() + np.array([len(frames)], "<i4").tobytes()
    with atomic_path(target) as temporary:
        temporary.write_bytes(header + frames.tobytes())


class PointCache:
    """The cloth's frames, gathered in memory and written whole by ``finish``."""

    def __init__(self, directory: Path, uv_layout, material: str = ""):
        """uv_layout: (source particle (V,), uvs (V, 2), triangles (T, 3)) from ``Garment.uv_layout``;
        ``material``: the OBJ's material name (its .mtl beside it), "" for none."""
        self.directory = Path(directory)
        self.source, self.uvs, self.triangles = uv_layout
        self.material = material
        self.frames, self.first = [], None

    def append(self, frame: int, t: float, positions: np.ndarray) -> None:
        """Frame ``frame`` (at ``t`` [s]): the particles' ``positions`` (N, 3) [m]."""
        points = np.asarray(positions)[self.source]
        if self.first is None:
            self.first = frame
            write_obj(self.directory / "cloth.obj", points,
                      obj_topology(self.triangles, self.uvs), self.material,
                      seam_comment(self.source))
        self.frames.append(points.astype(np.float32))

    def finish(self) -> None:
        if self.frames:
            write_pc2(self.directory / "cloth.pc2", np.stack(self.frames), float(self.first))
