"""Garments from OBJ files (cloth/obj_mesh.py, cloth/mesh_garment.py): a library grid written
out as quads builds the same cloth (springs, stiffness, masses, warp, hinges) and simulates the
same; a triangle mesh takes Van Gelder's constants, its mass is ρ_A × area; warp and weft come
from the UVs across a seam; pins from groups and vertex lists; bad files are one-line errors."""

import math
from pathlib import Path

import numpy as np
import pytest

from taichi_cloth.cloth.garment import build_garment
from taichi_cloth.cloth.obj_mesh import read_obj, winding_conflicts
from taichi_cloth.config.scene import load_scene
from taichi_cloth.effects.penalty import closest_points_numpy
from taichi_cloth.errors import InputError
from taichi_cloth.physics.simulation import Simulation

SHEET = ("cloth.resolution=[7, 5]", "cloth.size=[0.6, 0.4]", "cloth.bias=30",
         "cloth.material=denim", "cloth.pin=top-edge")


def quad_obj(garment, path: Path, pinned_group: str = "") -> None:
    """Write a grid garment as an OBJ of quads (top-left, bottom-left, bottom-right,
    top-right: the grid's own split into triangles) with a UV per corner (a skirt's seam cells
    take u + 1 at their wrapped corners) and the pinned particles' faces in ``pinned_group``."""
    columns, rows = garment.columns, garment.rows
    u_period = columns * (garment.uvs[1, 0] - garment.uvs[0, 0]) if garment.periodic else 0.0
    lines = [f"v {float(x)!r} {float(y)!r} {float(z)!r}" for x, y, z in garment.positions]
    faces, pinned_faces = [], []
    cells = columns if garment.periodic else columns - 1
    for row in range(rows - 1):
        for column in range(cells):
            right = (column + 1) % columns
            corners = [(row, column), (row + 1, column), (row + 1, right), (row, right)]
            face = []
            for corner_row, corner_column in corners:
                particle = corner_row * columns + corner_column
                u, v = garment.uvs[particle]
                if corner_column == 0 and column == columns - 1:
                    u += u_period
                lines.append(f"vt {float(u)!r} {float(v)!r}")
                face.append(f"{particle + 1}/{len(lines) - len(garment.positions)}")
            order = [0, 3, 2, 1] if garment.periodic else [0, 1, 2, 3]  # the grid's winding
            text = "f " + " ".join(face[k] for k in order)
            indices = [r * columns + c for r, c in corners]
            (pinned_faces if garment.pinned[indices].any() and pinned_group else faces).append(
                text)
    groups = ["g cloth"] + faces + ([f"g {pinned_group}"] + pinned_faces if pinned_faces else [])
    path.write_text("\n".join(lines + groups) + "\n")


def mesh_twin(tmp_path, scene_name, overrides, pin=("cloth.pin=none",), group=""):
    """The grid garment of a scene and the mesh garment of its quad OBJ (its faces that hold
    a pinned particle in ``group``), pinned by ``pin``."""
    scene = load_scene(scene_name, overrides)
    grid = build_garment(scene.cloth, scene.material, None, scene.path)
    quad_obj(grid, tmp_path / "grid.obj", group)
    mesh_scene = load_scene(scene_name, overrides + ("cloth.shape=mesh",
                                                     f"cloth.mesh=\"{tmp_path / 'grid.obj'}\"")
                            + pin)
    return scene, grid, mesh_scene, build_garment(mesh_scene.cloth, mesh_scene.material, None,
                                                   mesh_scene.path)


def spring_table(garment) -> dict:
    return {family: dict(zip(map(tuple, np.sort(pairs, axis=1)),
                             garment.spring_stiffness[family]))
            for family, pairs in garment.springs.items()}


def rows_of(table, values=None) -> dict:
    """Rows of an index table (as tuples, each with its value, or 1) in a dict."""
    return {tuple(row): 1.0 if values is None else float(value)
            for row, value in zip(table.tolist(), values if values is not None else table)}


def test_a_grid_written_as_quads_builds_the_same_cloth(tmp_path):
    _, grid, _, mesh = mesh_twin(tmp_path, "sheet", SHEET)
    np.testing.assert_array_equal(mesh.positions, grid.positions)
    np.testing.assert_allclose(mesh.mass, grid.mass, rtol=1e-12)
    np.testing.assert_allclose(mesh.warp, grid.warp, atol=1e-12)
    grid_springs, mesh_springs = spring_table(grid), spring_table(mesh)
    assert grid_springs.keys() == mesh_springs.keys() == {"stretch", "shear"}
    for family in grid_springs:
        assert grid_springs[family].keys() == mesh_springs[family].keys()
        for pair, stiffness in grid_springs[family].items():
            assert mesh_springs[family][pair] == pytest.approx(stiffness, rel=1e-12)
    assert rows_of(mesh.triangles) == rows_of(grid.triangles)  # the same, in another order
    def hinge_table(garment):  # each hinge by its edge and its two opposite vertices, unordered
        stencils = np.concatenate([np.sort(garment.hinges[:, :2], axis=1),
                                   np.sort(garment.hinges[:, 2:], axis=1)], axis=1)
        return rows_of(stencils, garment.hinge_rigidity)

    assert hinge_table(mesh) == pytest.approx(hinge_table(grid), rel=1e-12)
    np.testing.assert_allclose(mesh.uvs, grid.uvs)


def test_a_grid_and_its_obj_export_simulate_identically(tmp_path):
    lying = SHEET + ("cloth.orientation=horizontal", "cloth.pin=corners")
    scene, grid, mesh_scene, mesh = mesh_twin(tmp_path, "sheet", lying,
                                              ("cloth.pin=vertices", "cloth.pin_vertices=[1, 7]"))
    np.testing.assert_array_equal(mesh.pinned, grid.pinned)
    runs = []
    for chosen in (scene, mesh_scene):
        simulation = Simulation(chosen)
        simulation.run(6)
        runs.append(simulation.positions())
    assert np.isfinite(runs[0]).all()
    assert np.abs(runs[0] - grid.positions).max() > 0.02  # it sags between its corners
    # the same cloth, its forces summed in another order: equal to float32 rounding (1.2e-7 m
    # at 1.6 m), not bit for bit
    np.testing.assert_allclose(runs[1], runs[0], rtol=0, atol=2e-6)


def test_a_skirt_with_a_uv_seam_keeps_its_warp_and_one_particle_per_vertex(tmp_path):
    overrides = ("cloth.resolution=[12, 5]",)
    _, grid, _, mesh = mesh_twin(tmp_path, "skirt", overrides)
    obj = read_obj(tmp_path / "grid.obj")
    assert len(obj.uvs) > len(obj.positions)  # the seam's corners have u = 1 as well as 0
    assert mesh.particle_count == grid.particle_count
    assert np.abs(np.einsum("nk,nk->n", mesh.warp, grid.warp)).min() > 0.99
    assert mesh.spring_count == grid.spring_count - len(grid.springs.get("bend", ()))
    source, uvs, triangles = mesh.uv_layout()
    assert len(source) == grid.particle_count + grid.rows  # the seam column, twice
    corner_u = uvs[triangles][:, :, 0]
    assert (corner_u.max(axis=1) - corner_u.min(axis=1)).max() < 0.5  # no triangle jumps
    assert winding_conflicts(obj) == 0


def triangle_sheet(path: Path, columns: int, rows: int, spacing: float) -> None:
    """A flat square grid of right triangles in the x–z plane at y = 1, UVs along x and z."""
    lines = [f"v {c * spacing!r} 1.0 {r * spacing!r}" for r in range(rows) for c in range(columns)]
    lines += [f"vt {c / (columns - 1)!r} {1 - r / (rows - 1)!r}"
              for r in range(rows) for c in range(columns)]
    for r in range(rows - 1):
        for c in range(columns - 1):
            a, b, d, e = (r * columns + c + 1, r * columns + c + 2,
                          (r + 1) * columns + c + 1, (r + 1) * columns + c + 2)
            lines += [f"f {a}/{a} {d}/{d} {e}/{e}", f"f {a}/{a} {e}/{e} {b}/{b}"]
    path.write_text("\n".join(lines) + "\n")


def test_a_triangle_mesh_takes_van_gelders_constants_and_its_area_mass(tmp_path):
    spacing = 0.05
    triangle_sheet(tmp_path / "tri.obj", 5, 4, spacing)
    scene = load_scene("sheet", ("cloth.shape=mesh", f"cloth.mesh=\"{tmp_path / 'tri.obj'}\"",
                                 "cloth.pin=none", "cloth.material=silk"))
    garment = build_garment(scene.cloth, scene.material, None, scene.path)
    material = scene.material
    assert set(garment.springs) == {"stretch"}
    edges = 4 * 4 + 3 * 5 + 4 * 3  # along x (4 rows), along z (5 columns), a diagonal a cell
    assert len(garment.springs["stretch"]) == edges
    assert garment.mass.sum() == pytest.approx(material.density * (4 * spacing) * (3 * spacing))
    stiffness = spring_table(garment)["stretch"]
    k_warp, k_weft = material.stretch_stiffness, material.stretch_weft
    # the warp runs down the pattern (along z here), the weft along x
    assert stiffness[(6, 7)] == pytest.approx(k_weft)  # an interior edge along x: two triangles
    assert stiffness[(0, 1)] == pytest.approx(k_weft / 2)  # on the boundary: one
    assert stiffness[(6, 11)] == pytest.approx(k_warp)  # interior, along z
    assert stiffness[(0, 6)] == pytest.approx(0.25 * (k_warp + k_weft))  # diagonal: A/|e|² = ½


@pytest.mark.parametrize("text, message", [
    ("v 0 0 0\nv 1 0 0\nv 0 1 0\nv 5 5 5\nf 1 2 3\n", "in no face"),
    ("v 0 0 0\nv 1 0 0\nv 0 1 0\nv 1 1 0\nv 2 2 0\nf 1 2 4 3 5\n", "5 corners"),
    ("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 7\n", "vertex index 7"),
    ("v 0 0 0\nv 1 0 0\nv 0 nan 0\nf 1 2 3\n", "finite"),
    ("v 0 0 0\nv 1 0 0\nv 2 0 0\nf 1 2 3\n", "degenerate"),
    ("v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 2\n", "repeats a vertex"),
    ("v 0 0 0\nv 1 0 0\nv 0 1 0\nv 0 -1 0\nv 0 0 1\nf 1 2 3\nf 2 1 4\nf 1 2 5\n", "manifold"),
    ("v 0 0 0\n", "no faces"),
])
def test_bad_meshes_are_one_line_errors(tmp_path, text, message):
    path = tmp_path / "bad.obj"
    path.write_text(text)
    with pytest.raises(InputError, match=message) as caught:
        read_obj(path)
    assert "\n" not in str(caught.value) and str(path) in str(caught.value)


def test_obj_statements_groups_negative_indices_and_winding(tmp_path):
    path = tmp_path / "two.obj"
    path.write_text("o skirt\nv 0 0 0\nv 1 0 0\nv 0 1 0\nv 1 1 0\nvt 0 0\nvt 1 0\nvt 0 1\n"
                    "vn 0 0 1\ng band\nf 1/1/1 2/2/1 3/3/1\ng rest\nf -3//1 -1//1 -2//1  # c\n")
    mesh = read_obj(path)
    np.testing.assert_array_equal(mesh.faces, [[0, 1, 2, -1], [1, 3, 2, -1]])
    assert sorted(mesh.groups) == ["band", "rest"]
    np.testing.assert_array_equal(mesh.groups["band"], [0, 1, 2])
    assert not mesh.has_uvs  # the second face has none
    assert winding_conflicts(mesh) == 0
    path.write_text("v 0 0 0\nv 1 0 0\nv 0 1 0\nv 1 1 0\nf 1 2 3\nf 2 3 4\n")
    assert winding_conflicts(read_obj(path)) == 1


@pytest.mark.parametrize("overrides, key", [
    (("cloth.pin=group", "cloth.pin_groups=[\"waistband\"]"), "cloth.pin_groups"),
    (("cloth.pin=vertices", "cloth.pin_vertices=[99]"), "cloth.pin_vertices"),
    (("cloth.pin=waist",), "cloth.pin"),
    (("cloth.pin=group",), "cloth.pin_groups"),
    (("cloth.mesh=\"missing.obj\"", "cloth.pin=none"), "cloth.mesh"),
    (("cloth.pin=none", "cloth.bending=springs"), "cloth.bending"),
    (("cloth.pin=none", "cloth.springs=[\"shear\"]"), "cloth.springs"),
])
def test_bad_mesh_settings_name_their_key(tmp_path, overrides, key):
    triangle_sheet(tmp_path / "tri.obj", 3, 3, 0.1)
    with pytest.raises(InputError, match=key):
        scene = load_scene("sheet", (f"cloth.mesh=\"{tmp_path / 'tri.obj'}\"", "cloth.shape=mesh")
                           + overrides)
        build_garment(scene.cloth, scene.material, None, scene.path)


def test_a_pinned_group_holds_every_vertex_of_its_faces(tmp_path):
    _, grid, _, mesh = mesh_twin(tmp_path, "sheet", SHEET,
                                 ("cloth.pin=group", "cloth.pin_groups=[\"band\"]"), "band")
    np.testing.assert_array_equal(np.flatnonzero(mesh.pinned), np.arange(14))  # rows 0 and 1
    assert grid.pinned.sum() == 7


def test_pins_from_a_vertex_list_use_the_files_numbering(tmp_path):
    triangle_sheet(tmp_path / "tri.obj", 3, 3, 0.1)
    scene = load_scene("sheet", (f"cloth.mesh=\"{tmp_path / 'tri.obj'}\"", "cloth.shape=mesh",
                                 "cloth.pin=vertices", "cloth.pin_vertices=[1, 3]"))
    garment = build_garment(scene.cloth, scene.material, None, scene.path)
    np.testing.assert_array_equal(np.flatnonzero(garment.pinned), [0, 2])
    assert math.isclose(garment.positions[2, 0], 0.2)


def test_the_shipped_hilo_skirt_dances_with_its_waistband_on_the_pelvis():
    scene = load_scene("hilo", ("simulation.settle=0.25", "scene.duration=0.1"))
    simulation = Simulation(scene)
    garment = simulation.garment
    assert not garment.is_grid and garment.corner_uvs is not None
    assert garment.mass.sum() == pytest.approx(scene.material.density * triangle_area(garment))
    stats = simulation.stats(simulation.run(3))
    assert stats["finite"] and stats["max_strain"] < 0.03
    assert stats["max_penetration"] < scene.effects["collision"].thickness
    rig = simulation.body_rig
    pose = rig.pose_at_frame_end
    assert not rig.pin_on_chest.any()  # the waistband rides on the pelvis
    carried = rig.pin_local @ pose.pelvis_rotation.T + pose.pelvis_position
    np.testing.assert_allclose(simulation.positions()[garment.pinned], carried, atol=1e-5)
    assert np.abs(carried - garment.positions[garment.pinned]).max() > 1e-3  # she moved


def triangle_area(garment) -> float:
    p0, p1, p2 = (garment.positions[garment.triangles[:, k]] for k in range(3))
    return float(0.5 * np.linalg.norm(np.cross(p1 - p0, p2 - p0), axis=1).sum())


def test_a_mesh_tangled_at_rest_is_a_warning_and_still_runs(tmp_path, capsys):
    path = tmp_path / "crossed.obj"  # two squares, the second piercing the first
    path.write_text("v 0 1 0\nv 1 1 0\nv 1 1 1\nv 0 1 1\n"
                    "v 0.5 0.5 0.5\nv 0.5 1.5 0.5\nv 0.6 1.5 0.9\nv 0.6 0.5 0.9\n"
                    "f 1 2 3 4\nf 5 6 7 8\n")
    scene = load_scene("sheet", ("cloth.shape=mesh", f"cloth.mesh=\"{path}\"",
                                 "cloth.pin=vertices", "cloth.pin_vertices=[1, 2]"))
    simulation = Simulation(scene)
    assert "pairs of its triangles pass through each other at rest" in capsys.readouterr().err
    assert simulation.stats(simulation.run(1))["finite"]


def test_a_dress_hangs_from_straps_that_ride_on_the_chest():
    scene = load_scene("walk-dress", ("cloth.resolution=[24, 14]", "simulation.settle=0.2",
                                      "simulation.dt=0.016666666666666666"))
    simulation = Simulation(scene)
    stats = simulation.stats(simulation.run(9))  # 0.3 s: she has eased into her first step
    assert stats["finite"]
    rig, garment = simulation.body_rig, simulation.garment
    assert rig.pin_on_chest.all() and garment.pinned.sum() > 0
    pose = rig.pose_at_frame_end
    carried = rig.carried_pins([pose])[0][0]
    np.testing.assert_allclose(carried, pose.chest_position + rig.pin_local @ pose.chest_rotation.T)
    np.testing.assert_allclose(simulation.positions()[garment.pinned], carried, atol=1e-5)
    rest = rig.body.pose(0.0)
    assert np.abs(pose.chest_position - rest.chest_position).max() > 1e-3  # she walked
    # the straps lie over her shoulders: their apex 3 cm over the shoulder capsule, the pinned
    # parts' lowest particles (at this coarse resolution, 4.5 cm rows) at most 7 cm off it
    shoulders = rig.body.capsule_names.index("shoulders")
    _, _, distance = closest_points_numpy(carried, pose.capsule_a[[shoulders]],
                                          pose.capsule_b[[shoulders]])
    gap = distance[:, 0] - rig.body.capsule_radius[shoulders]
    assert gap.min() == pytest.approx(0.03, abs=0.005) and gap.max() < 0.07
