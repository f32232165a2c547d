"""The mesh exporters of a run, made once and fed every frame: the cloth in each asked format
(OBJ/PLY/VTU per frame and XDMF through ``meshes.MeshSeries``, one USD stage, an OBJ + PC2
point cache), and the body's capsules when asked. A run feeds them the live state
(``output/run.py``), a replay the cached frames (``output/replay.py``): the same files either
way."""

from pathlib import Path

from taichi_cloth.config.scene import Scene
from taichi_cloth.output.files import copy_file
from taichi_cloth.output.meshes import MeshSeries, write_material

MESH_DIR = "meshes"


def cloth_points(t, positions):
    """The cloth's vertices at time ``t`` [s]: the particles' ``positions`` (N, 3) [m]."""
    return positions


def mesh_series(scene: Scene, garment, body, directory: Path, formats,
                body_meshes: bool) -> list:
    """(exporter, points(t, positions) → (V, 3) m) for the cloth and, if ``body_meshes`` and
    there is a ``body``, the body; ``formats``: the ``--meshes`` list (none: nothing)."""
    from taichi_cloth.render.texture import texture_path
    if not formats:
        return []
    folder = directory / MESH_DIR
    source, uvs, triangles = garment.uv_layout()
    image = texture_path(scene)
    if "obj" in formats or "pc2" in formats:
        if image is not None:
            copy_file(image, folder / image.name)
        write_material(folder / "cloth.mtl", "cloth", scene.render.cloth_color,
                       image.name if image is not None else "")
    uv_layout = (source, uvs * scene.render.texture_repeat, triangles)
    series = [(MeshSeries(folder, "cloth", formats, garment.triangles, uv_layout,
                          material=True, fps=scene.scene.fps), cloth_points)]
    if "usd" in formats:
        from taichi_cloth.output.usd import USD_FILE, UsdAnimation
        if image is not None:
            copy_file(image, folder / image.name)
        series.append((UsdAnimation(folder / USD_FILE, uv_layout, scene.scene.fps,
                                    scene.render.cloth_color,
                                    image.name if image is not None else "", body),
                       cloth_points))
    if "pc2" in formats:
        from taichi_cloth.output.pointcache import PointCache
        series.append((PointCache(folder, uv_layout, "cloth"), cloth_points))
    if body_meshes and body is not None:
        from taichi_cloth.render.surfaces import BodySurface
        surface = BodySurface(body)

        def body_points(t, positions):
            surface.update(t)
            return surface.points()

        series.append((MeshSeries(folder, "body", formats, surface.triangles,
                                  fps=scene.scene.fps), body_points))
    return series
