"""Blender reads the animation: run with Blender's Python module (pip's ``bpy==5.0.1``, in a venv
of its own: ``make check-blender``) on a run's meshes/ folder written with ``--meshes
obj,usd,pc2``.

    .venv-blender/bin/python scripts/check-blender.py output/hula/meshes

It imports ``animation.usd`` (``bpy.ops.wm.usd_import``) and, in a fresh file, ``cloth.obj``
with a Mesh Cache modifier on ``cloth.pc2`` (default axes), and at three frames compares the
cloth's evaluated world-space vertices with that frame's OBJ file (``cloth_NNNNN.obj``, y up,
which Blender shows z up: (x, y, z) → (x, −z, y)): the OBJ's vertices for the point cache, and
for the stage, which has one vertex per particle, the OBJ's distinct positions in the order they
first appear (the OBJ repeats a particle on a UV seam for each of its other UVs; its first
copy comes in particle order). The stage's UVs, one per face corner, must be the OBJ's UVs of
the same corners (the faces are in the same order). It prints one line per check and exits 1
if any differs by more than float32 rounding (1e-5 m, or 1e-5 in UV). Only NumPy and bpy:
nothing of taichi_cloth.
"""

import sys
from pathlib import Path

import bpy
import numpy as np

TOLERANCE = 1e-5  # m


def obj_points(path: Path) -> np.ndarray:
    return np.array([[float(c) for c in line.split()[1:4]]
                     for line in path.read_text().splitlines() if line.startswith("v ")])


def obj_corner_uvs(path: Path) -> np.ndarray:
    """The UV of every face corner of an OBJ with ``f v/vt`` faces, face by face."""
    lines = path.read_text().splitlines()
    uvs = np.array([[float(c) for c in line.split()[1:3]] for line in lines
                    if line.startswith("vt ")])
    corners = [int(corner.split("/")[1]) - 1 for line in lines if line.startswith("f ")
               for corner in line.split()[1:]]
    return uvs[corners]


def welded(points: np.ndarray) -> np.ndarray:
    """The distinct rows of ``points``, in the order they first appear."""
    _, first = np.unique(points, axis=0, return_index=True)
    return points[np.sort(first)]


def evaluated_points(obj) -> np.ndarray:
    evaluated = obj.evaluated_get(bpy.context.evaluated_depsgraph_get())
    return np.array([(evaluated.matrix_world @ v.co)[:] for v in evaluated.data.vertices])


def z_up(points: np.ndarray) -> np.ndarray:
    return np.stack([points[:, 0], -points[:, 2], points[:, 1]], axis=1)


def check(label: str, obj, folder: Path, frames, weld: bool = False) -> bool:
    good = True
    for frame in frames:
        bpy.context.scene.frame_set(frame)
        expected = obj_points(folder / f"cloth_{frame:05d}.obj")
        expected = z_up(welded(expected) if weld else expected)
        points = evaluated_points(obj)
        error = float(np.abs(points - expected).max()) if points.shape == expected.shape \
            else float("inf")
        good &= error <= TOLERANCE
        print(f"{label} frame {frame}: {len(points)} vertices, largest difference {error:.2e} m")
    return good


def main(folder: Path) -> int:
    frames = sorted(int(p.stem.rsplit("_", 1)[1]) for p in folder.glob("cloth_[0-9]*.obj"))
    chosen = [frames[0], frames[len(frames) // 2], frames[-1]]
    bpy.ops.wm.read_factory_settings(use_empty=True)
    bpy.ops.wm.usd_import(filepath=str(folder / "animation.usd"))
    cloth = next(o for o in bpy.data.objects if o.type == "MESH" and o.name.startswith("Cloth"))
    good = check("usd", cloth, folder, chosen, weld=True)
    uv_layer = cloth.data.uv_layers.active
    expected = obj_corner_uvs(folder / "cloth_00000.obj")
    uvs = np.array([uv.uv[:] for uv in uv_layer.data]) if uv_layer else np.zeros((0, 2))
    error = float(np.abs(uvs - expected).max()) if uvs.shape == expected.shape else float("inf")
    good &= error <= TOLERANCE
    print(f"usd UVs: {len(uvs)} for {len(expected)} face corners, largest difference "
          f"{error:.2e}")
    bpy.ops.wm.read_factory_settings(use_empty=True)
    bpy.ops.wm.obj_import(filepath=str(folder / "cloth.obj"))
    obj = bpy.context.selected_objects[0]
    cache = obj.modifiers.new("cache", "MESH_CACHE")
    cache.cache_format = "PC2"
    cache.filepath = str(folder / "cloth.pc2")
    good &= check("obj+pc2", obj, folder, chosen)
    return 0 if good else 1


if __name__ == "__main__":
    sys.exit(main(Path(sys.argv[1])))
