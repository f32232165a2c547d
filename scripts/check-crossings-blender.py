"""Blender counts the cloth's crossings: run with Blender's Python module (pip's ``bpy==5.0.1``,
in a venv of its own: ``make check-blender``) on a run's folder written with ``--meshes ply``.

    .venv-blender/bin/python scripts/check-crossings-blender.py output/twirl

For every frame's ``meshes/cloth_NNNNN.ply`` it imports the mesh with Blender's own PLY reader
(``bpy.ops.wm.ply_import``), builds a ``mathutils.bvhtree.BVHTree`` of its triangles and counts
the pairs that ``BVHTree.overlap`` (Blender's triangle–triangle test) finds intersecting, less
those that share a vertex; then compares each count with the frame's ``self_intersections`` in
the run's ``stats.json`` (the simulator's own exact test, ``physics/intersections.py``). It
prints the frames that cross and exits 1 if any count differs. Only bpy: nothing of
taichi_cloth.
"""

import json
import sys
from pathlib import Path

import bpy
from mathutils.bvhtree import BVHTree


def crossing_pairs(path: Path) -> int:
    """Pairs of the PLY mesh's triangles that sharing no vertex intersect, by Blender."""
    bpy.ops.wm.read_factory_settings(use_empty=True)
    bpy.ops.wm.ply_import(filepath=str(path))
    mesh = bpy.context.selected_objects[0].data
    mesh.calc_loop_triangles()
    triangles = [tuple(triangle.vertices) for triangle in mesh.loop_triangles]
    tree = BVHTree.FromPolygons([vertex.co.copy() for vertex in mesh.vertices], triangles,
                                all_triangles=True, epsilon=0.0)
    return len({(min(i, j), max(i, j)) for i, j in tree.overlap(tree)
                if i != j and not set(triangles[i]) & set(triangles[j])})


def main(run: Path) -> int:
    frames = json.loads((run / "stats.json").read_text())["per_frame"]
    differing, crossing = [], []
    for frame in frames:
        blender = crossing_pairs(run / "meshes" / f"cloth_{frame['frame']:05d}.ply")
        ours = frame["self_intersections"]
        if blender:
            crossing.append(f"{frame['frame']}: {blender}")
        if blender != ours:
            differing.append(f"frame {frame['frame']}: Blender {blender}, stats.json {ours}")
    print(f"{run}: {len(frames)} frames; crossing pairs by Blender in {len(crossing)} of them"
          + (f" ({', '.join(crossing[:8])}{', ...' if len(crossing) > 8 else ''})"
             if crossing else ""))
    for line in differing:
        print("differs:", line)
    return 1 if differing else 0


if __name__ == "__main__":
    sys.exit(main(Path(sys.argv[1])))
