"""Garment meshes: spring and triangle counts in closed form for a sheet and a periodic skirt,
springs joining the right grid neighbours, triangle winding (outwards on a skirt, towards +z on
a vertical sheet), UVs, lumped masses against the exact area, pins and the skirt's minimum size."""

import math

import numpy as np
import pytest

from taichi_cloth.cloth.garment import build_garment
from taichi_cloth.config.materials import PRESETS
from taichi_cloth.config.scene import load_scene
from taichi_cloth.errors import InputError


def garment_of(name, *overrides, material=None):
    scene = load_scene(name, overrides)
    return scene, build_garment(scene.cloth, material or scene.material, source=scene.path)


def sheet_counts(columns, rows):
    """Stretch: C−1 per row, R−1 per column; shear: two diagonals per cell; bend: C−2 skip-one
    pairs per row, R−2 per column."""
    return {"stretch": rows * (columns - 1) + columns * (rows - 1),
            "shear": 2 * (columns - 1) * (rows - 1),
            "bend": rows * (columns - 2) + columns * (rows - 2)}


def skirt_counts(columns, rows):
    """Around a ring of C particles there are C neighbour pairs and C skip-one pairs (the seam
    closes); down, as on a sheet; shear: two diagonals per cell, C cells per band."""
    return {"stretch": rows * columns + columns * (rows - 1),
            "shear": 2 * columns * (rows - 1),
            "bend": rows * columns + columns * (rows - 2)}


@pytest.mark.parametrize("columns, rows", [(6, 5), (3, 7), (2, 2)])
def test_sheet_spring_and_triangle_counts(columns, rows):
    _, garment = garment_of("sheet", f"cloth.resolution=[{columns}, {rows}]",
                            "cloth.bending=springs")
    assert {f: len(p) for f, p in garment.springs.items()} == sheet_counts(columns, rows)
    assert len(garment.triangles) == 2 * (columns - 1) * (rows - 1)
    assert garment.spring_count == sum(sheet_counts(columns, rows).values())


@pytest.mark.parametrize("columns, rows", [(5, 3), (8, 4)])
def test_skirt_spring_and_triangle_counts(columns, rows):
    _, garment = garment_of("skirt", f"cloth.resolution=[{columns}, {rows}]",
                            "cloth.bending=springs")
    assert {f: len(p) for f, p in garment.springs.items()} == skirt_counts(columns, rows)
    assert len(garment.triangles) == 2 * columns * (rows - 1)
    pairs = np.sort(np.concatenate(list(garment.springs.values())), axis=1)
    assert len(np.unique(pairs, axis=0)) == len(pairs)  # even 5 around: no spring twice


def test_only_the_declared_families_are_built():
    _, garment = garment_of("sheet", "cloth.resolution=[4, 4]", "cloth.springs=['stretch']",
                            "cloth.bending=springs")
    assert set(garment.springs) == set(garment.spring_stiffness) == {"stretch", "bend"}
    _, curvature = garment_of("sheet", "cloth.resolution=[4, 4]", "cloth.springs=['stretch']")
    assert set(curvature.springs) == {"stretch"}
    assert len(curvature.hinges) == 2 * (3 * 2) + 3 * 3  # interior edges of a 4 × 4 grid


def spring_lengths(garment, family):
    ends = garment.springs[family]
    return np.linalg.norm(garment.positions[ends[:, 1]] - garment.positions[ends[:, 0]], axis=1)


def test_sheet_springs_join_neighbours_diagonals_and_skip_one_neighbours():
    """A 1.0 × 0.6 m sheet of 5 × 4: spacings dx = 0.25, dz = 0.2 m."""
    _, garment = garment_of("sheet", "cloth.resolution=[5, 4]", "cloth.size=[1.0, 0.6]",
                            "cloth.bending=springs")
    dx, dz = 0.25, 0.2
    stretch = spring_lengths(garment, "stretch")
    assert np.sum(np.isclose(stretch, dx, atol=1e-12)) == 4 * 4
    assert np.sum(np.isclose(stretch, dz, atol=1e-12)) == 5 * 3
    np.testing.assert_allclose(spring_lengths(garment, "shear"), math.hypot(dx, dz), atol=1e-12)
    bend = spring_lengths(garment, "bend")
    assert np.sum(np.isclose(bend, 2 * dx, atol=1e-12)) == 4 * 3
    assert np.sum(np.isclose(bend, 2 * dz, atol=1e-12)) == 5 * 2


def test_rectangular_cells_get_the_materials_spring_constants():
    """materials: stretch k_weft·dz/dx along x (the weft) and k_warp·dx/dz down (the warp);
    shear G(dx² + dz²)/(2dx·dz); bend B/(dx·dz) (each cell the same continuum stiffness whatever
    its aspect). Cut on the bias (45°), both stretch families take the mean modulus."""
    silk = PRESETS["silk"]
    assert silk.stretch_weft != silk.stretch_stiffness  # an anisotropic preset
    _, garment = garment_of("sheet", "cloth.resolution=[5, 4]", "cloth.size=[1.0, 0.6]",
                            "cloth.bending=springs", material=silk)
    dx, dz = 0.25, 0.2
    stretch, lengths = garment.spring_stiffness["stretch"], spring_lengths(garment, "stretch")
    along_x = np.isclose(lengths, dx)
    np.testing.assert_allclose(stretch[along_x], silk.stretch_weft * dz / dx, rtol=1e-12)
    np.testing.assert_allclose(stretch[~along_x], silk.stretch_stiffness * dx / dz, rtol=1e-12)
    _, biased = garment_of("sheet", "cloth.resolution=[5, 4]", "cloth.size=[1.0, 0.6]",
                           "cloth.bias=45", material=silk)
    mean = 0.5 * (silk.stretch_stiffness + silk.stretch_weft)
    np.testing.assert_allclose(biased.spring_stiffness["stretch"][along_x], mean * dz / dx,
                               rtol=1e-12)
    np.testing.assert_allclose(garment.spring_stiffness["shear"],
                               silk.shear_stiffness * (dx * dx + dz * dz) / (2 * dx * dz),
                               rtol=1e-12)
    np.testing.assert_allclose(garment.spring_stiffness["bend"],
                               silk.bend_stiffness / (dx * dz), rtol=1e-12)


def test_skirt_seam_closes_with_springs_as_long_as_the_others():
    """Around a ring of radius r with C particles, neighbours are a chord 2r·sin(π/C) apart and
    skip-one pairs 2r·sin(2π/C), across the seam as anywhere else."""
    scene, garment = garment_of("skirt", "cloth.resolution=[7, 3]", "cloth.bending=springs")
    columns, rows = 7, 3
    radius = scene.cloth.waist_radius + (scene.cloth.hem_radius - scene.cloth.waist_radius) \
        * np.arange(rows) / (rows - 1)
    ring = np.repeat(radius, columns)
    for family, step in (("stretch", 1), ("bend", 2)):
        ends = garment.springs[family]
        around = ends[:, 0] // columns == ends[:, 1] // columns
        assert around.sum() == columns * rows
        chord = 2 * ring[ends[around, 0]] * math.sin(step * math.pi / columns)
        np.testing.assert_allclose(spring_lengths(garment, family)[around], chord, rtol=1e-12)
        seam = {(r * columns + columns - step + k, r * columns + k)
                for r in range(rows) for k in range(step)}
        assert seam <= {tuple(p) for p in ends[around].tolist()}


def triangle_normals(garment):
    p0, p1, p2 = (garment.positions[garment.triangles[:, k]] for k in range(3))
    return np.cross(p1 - p0, p2 - p0), (p0 + p1 + p2) / 3


def test_vertical_sheet_triangles_face_plus_z():
    """Counter-clockwise seen from +z (Garment's docstring): every normal is +z, none is
    degenerate."""
    _, garment = garment_of("sheet", "cloth.resolution=[5, 4]", "cloth.orientation='vertical'")
    normals, _ = triangle_normals(garment)
    np.testing.assert_allclose(normals[:, :2], 0.0, atol=1e-15)
    assert np.all(normals[:, 2] > 0)


def test_horizontal_sheet_triangles_share_one_side():
    _, garment = garment_of("sheet", "cloth.resolution=[5, 4]",
                            "cloth.orientation='horizontal'")
    normals, _ = triangle_normals(garment)
    np.testing.assert_allclose(normals[:, [0, 2]], 0.0, atol=1e-15)
    assert np.all(normals[:, 1] > 0) or np.all(normals[:, 1] < 0)


@pytest.mark.parametrize("columns, rows", [(5, 2), (9, 4)])
def test_skirt_triangles_face_outwards(columns, rows):
    """Counter-clockwise seen from outside: the normal points away from the y axis (the cone's
    axis), seam triangles included."""
    _, garment = garment_of("skirt", f"cloth.resolution=[{columns}, {rows}]")
    normals, centres = triangle_normals(garment)
    radial = centres * np.array([1.0, 0.0, 1.0])
    assert np.all(np.einsum("tk,tk->t", normals, radial) > 0)


@pytest.mark.parametrize("name, periodic", [("sheet", False), ("skirt", True)])
def test_uvs_span_the_unit_square_along_columns_and_down_rows(name, periodic):
    columns, rows = 6, 4
    _, garment = garment_of(name, f"cloth.resolution=[{columns}, {rows}]")
    uv = garment.uvs.reshape(rows, columns, 2)
    assert garment.uvs.min() >= 0.0 and garment.uvs.max() <= 1.0
    assert np.all(np.diff(uv[..., 0], axis=1) > 0)  # u grows along each row
    assert np.all(np.diff(uv[..., 1], axis=0) < 0)  # v falls down each column
    np.testing.assert_allclose(uv[0, :, 1], 1.0)    # top row at v = 1
    np.testing.assert_allclose(uv[-1, :, 1], 0.0)   # bottom row at v = 0
    np.testing.assert_allclose(uv[:, 0, 0], 0.0)
    # a sheet's last column reaches u = 1; a skirt's stops a cell short (the seam wraps to 0)
    np.testing.assert_allclose(uv[:, -1, 0], (columns - 1) / columns if periodic else 1.0)


@pytest.mark.parametrize("orientation", ["vertical", "horizontal"])
def test_sheet_mass_is_density_times_its_area(orientation):
    scene, garment = garment_of("sheet", "cloth.resolution=[7, 4]", "cloth.size=[1.3, 0.7]",
                                f"cloth.orientation='{orientation}'")
    assert garment.mass.sum() == pytest.approx(scene.material.density * 1.3 * 0.7, rel=1e-12)
    assert np.all(garment.mass > 0)
    # an interior particle lumps a third of six half cells: one whole cell
    interior = garment.mass.reshape(4, 7)[1:-1, 1:-1]
    np.testing.assert_allclose(interior, scene.material.density * (1.3 / 6) * (0.7 / 3),
                               rtol=1e-12)


def test_skirt_mass_is_density_times_the_faceted_frustum_area():
    """Between two rings, each cell is a planar isosceles trapezoid: parallel chords
    c = 2r·sin(π/C) and height √((Δr·cos(π/C))² + Δy²) between their midpoints."""
    columns, rows = 9, 5
    scene, garment = garment_of("skirt", f"cloth.resolution=[{columns}, {rows}]")
    cloth = scene.cloth
    fraction = np.linspace(0.0, 1.0, rows)
    radius = cloth.waist_radius + (cloth.hem_radius - cloth.waist_radius) * fraction
    drop = math.sqrt(cloth.length ** 2 - (cloth.hem_radius - cloth.waist_radius) ** 2)
    height = cloth.waist_height - drop * fraction
    chord = 2 * radius * math.sin(math.pi / columns)
    slant = np.hypot(np.diff(radius) * math.cos(math.pi / columns), np.diff(height))
    area = columns * np.sum(0.5 * (chord[:-1] + chord[1:]) * slant)
    assert garment.mass.sum() == pytest.approx(scene.material.density * area, rel=1e-12)
    rings = garment.mass.reshape(rows, columns)
    np.testing.assert_allclose(rings, np.broadcast_to(rings[:, :1], rings.shape), rtol=1e-12)


def test_skirt_hangs_from_the_given_waist_height():
    scene, garment = garment_of("skirt", "cloth.resolution=[6, 3]")
    worn = build_garment(scene.cloth, scene.material, waist_height=0.8)
    np.testing.assert_allclose(worn.positions[:6, 1], 0.8)
    np.testing.assert_allclose(worn.positions - garment.positions,
                               np.broadcast_to([0.0, 0.8 - scene.cloth.waist_height, 0.0],
                                               worn.positions.shape), atol=1e-15)


@pytest.mark.parametrize("name, pin, pinned", [
    ("sheet", "top-edge", [0, 1, 2, 3, 4]),
    ("sheet", "corners", [0, 4]),
    ("sheet", "none", []),
    ("skirt", "waist", [0, 1, 2, 3, 4]),
    ("skirt", "none", []),
])
def test_pins(name, pin, pinned):
    _, garment = garment_of(name, "cloth.resolution=[5, 3]", f"cloth.pin='{pin}'")
    assert np.flatnonzero(garment.pinned).tolist() == pinned
    top = garment.positions[:5, 1]
    assert np.all(garment.positions[garment.pinned, 1] == top.max())  # pins are on the top row


def test_a_flag_is_held_along_its_hoist_beside_its_pole():
    """pin = "left-edge": the sheet's first column, every row; the flag scene's pole stands
    just outside it, from the ground to above the flag."""
    from taichi_cloth.physics.rig import BodyRig
    scene, garment = garment_of("flag", "cloth.resolution=[5, 3]")
    assert np.flatnonzero(garment.pinned).tolist() == [0, 5, 10]
    np.testing.assert_allclose(garment.positions[garment.pinned, 0], -scene.cloth.size[0] / 2)
    pole = BodyRig(scene).body
    a, b = pole.pose(0.0).capsule_a[0], pole.pose(0.0).capsule_b[0]
    np.testing.assert_allclose([a[1], b[1]], [0.0, 2.2])  # upright, from the ground
    np.testing.assert_allclose(a[[0, 2]], b[[0, 2]])
    gap = -scene.cloth.size[0] / 2 - a[0] - pole.capsule_radius[0]
    assert 0.0 < gap < 0.01  # the hoist a few mm outside the pole's surface
    assert b[1] > garment.positions[:, 1].max()


@pytest.mark.parametrize("columns", [2, 4])
def test_skirt_with_fewer_than_five_columns_is_refused(columns):
    """Four around would put a skip-one spring on top of the one across the seam, twice."""
    scene = load_scene("skirt", (f"cloth.resolution=[{columns}, 4]",))
    with pytest.raises(InputError, match="at least 5"):
        build_garment(scene.cloth, scene.material, source=scene.path)


def test_skirt_shorter_than_its_flare_is_refused():
    scene = load_scene("skirt", ("cloth.resolution=[8, 4]", "cloth.length=0.2"))
    with pytest.raises(InputError, match="cloth.length"):
        build_garment(scene.cloth, scene.material, source=scene.path)


@pytest.mark.parametrize("circle", [1.0, 0.5])
def test_circle_skirt_is_the_cone_its_annulus_pattern_sews_into(circle):
    """A circle skirt cut from the fraction ``circle`` of an annulus of inner radius
    waist_radius/circle: worn, its waist ring has the waist's radius, every column runs the
    skirt's length down the fabric, and the hem ring's radius is waist_radius + circle·length
    (a full circle lies flat at the waist, a half circle is a cone of half-angle 30°)."""
    waist, length = 0.17, 0.45
    scene, garment = garment_of("skirt", "cloth.shape='circle-skirt'", f"cloth.circle={circle}",
                                f"cloth.waist_radius={waist}", f"cloth.length={length}",
                                "cloth.resolution=[24, 10]")
    grid = garment.positions.reshape(10, 24, 3)
    radius = np.hypot(grid[..., 0], grid[..., 2])
    np.testing.assert_allclose(radius[0], waist, rtol=1e-12)
    np.testing.assert_allclose(radius[-1], waist + circle * length, rtol=1e-12)
    slant = np.linalg.norm(np.diff(grid, axis=0), axis=2).sum(axis=0)
    np.testing.assert_allclose(slant, length, rtol=1e-12)
    drop = grid[0, :, 1] - grid[-1, :, 1]
    np.testing.assert_allclose(drop, length * np.sqrt(1 - circle ** 2), atol=1e-12)


@pytest.mark.parametrize("orientation, across", [("vertical", 2), ("horizontal", 1)])
def test_sheet_ripple_bends_the_start_without_stretching_it(orientation, across):
    """``cloth.ripple = [a, k]`` starts a sheet on the wave a·sin(π·k·u/L) across its plane
    (u along the fabric from the top row), bent without stretching: every spring at its rest
    length; the rest shape stays flat. A wave steeper than 45° is refused."""
    settings = ("cloth.resolution=[6, 41]", "cloth.size=[0.5, 1.0]",
                f"cloth.orientation='{orientation}'")
    scene, garment = garment_of("sheet", *settings, "cloth.ripple=[0.02, 3.0]")
    flat = garment_of("sheet", *settings)[1]
    np.testing.assert_array_equal(garment.positions, flat.positions)
    assert flat.start_offset is None
    start = garment.start_positions.reshape(41, 6, 3)
    wave = 0.02 * np.sin(np.pi * 3.0 * np.linspace(0, 1, 41))
    np.testing.assert_allclose(start[..., across] - flat.positions.reshape(41, 6, 3)[..., across],
                               np.repeat(wave[:, None], 6, axis=1), atol=1e-15)
    for pairs in garment.springs.values():
        rest = np.linalg.norm(np.diff(garment.positions[pairs], axis=1), axis=2)
        now = np.linalg.norm(np.diff(garment.start_positions[pairs], axis=1), axis=2)
        # the chord of a bent spring is shorter than its arc by ~(h·κ)²/24
        np.testing.assert_allclose(now, rest, rtol=2e-4)
    with pytest.raises(InputError, match="cloth.ripple"):
        garment_of("sheet", *settings, "cloth.ripple=[0.2, 3.0]")


def test_a_pleated_skirt_zigzags_round_its_waist_with_the_fabric_of_its_pleats():
    """pleated: each ring's radius is the cone's ± pleat_depth/2 in a triangle wave of `pleats`
    periods (with two particles a pleat: inner folds on even ones, outer on odd ones), the waist ring's rest length is
    the zigzag's, longer than the circle's by the pleats' fabric, and its mass that fabric's."""
    pleats, depth = 6, 0.03
    scene, garment = garment_of("skirt", "cloth.shape='pleated'", f"cloth.pleats={pleats}",
                                f"cloth.pleat_depth={depth}", "cloth.resolution=[12, 5]")
    _, plain = garment_of("skirt", "cloth.resolution=[12, 5]")
    radius = np.hypot(garment.positions[:, 0], garment.positions[:, 2]).reshape(5, 12)
    cone = np.hypot(plain.positions[:, 0], plain.positions[:, 2]).reshape(5, 12)
    offset = radius - cone
    np.testing.assert_allclose(offset[:, ::2], -depth / 2, atol=1e-12)  # inner folds
    np.testing.assert_allclose(offset[:, 1::2], depth / 2, atol=1e-12)  # outer folds
    def perimeter(ring):
        return np.linalg.norm(np.roll(ring, -1, axis=0) - ring, axis=1).sum()

    assert perimeter(garment.positions[:12]) > 1.02 * perimeter(plain.positions[:12])  # pleats
    assert garment.mass.sum() > plain.mass.sum()
    assert np.flatnonzero(garment.pinned).tolist() == list(range(12))  # held at the waist
    with pytest.raises(InputError, match="multiple of 2 × pleats"):
        garment_of("skirt", "cloth.shape='pleated'", "cloth.pleats=7", "cloth.resolution=[24, 5]")


def test_knife_pleats_step_out_one_way_and_fold_back_under_the_next():
    """Knife pleats: within a pleat of n columns the radius steps from the cone's − depth/2 to
    + depth/2 in n − 1 equal steps, then falls back (the fold under the next pleat): a sawtooth
    whose steps all run the same way round."""
    pleats, depth = 4, 0.03
    _, garment = garment_of("skirt", "cloth.shape='pleated'", "cloth.pleat_style='knife'",
                            f"cloth.pleats={pleats}", f"cloth.pleat_depth={depth}",
                            "cloth.resolution=[16, 5]")
    _, plain = garment_of("skirt", "cloth.resolution=[16, 5]")
    offset = (np.hypot(garment.positions[:, 0], garment.positions[:, 2])
              - np.hypot(plain.positions[:, 0], plain.positions[:, 2])).reshape(5, 16)
    np.testing.assert_allclose(offset, np.tile(depth * (np.arange(4) / 3 - 0.5), (5, pleats)),
                               atol=1e-12)
    steps = np.diff(np.concatenate([offset[0], offset[0, :1]]))
    assert (steps[np.arange(16) % 4 != 3] > 0).all() and (steps[3::4] < 0).all()
    with pytest.raises(InputError, match="at least 3 a pleat"):
        garment_of("skirt", "cloth.shape='pleated'", "cloth.pleat_style='knife'",
                   "cloth.pleats=8", "cloth.resolution=[16, 5]")


DRESS = ("cloth.shape=dress", "cloth.pin=shoulders", "cloth.resolution=[32, 18]",
         "cloth.hem_radius=0.38", "cloth.length=0.5")


def test_dress_is_one_outward_manifold_piece_of_the_right_area():
    from taichi_cloth.cloth.dress import STRAP_RISE, dress_mesh
    from taichi_cloth.cloth.obj_mesh import check_mesh, winding_conflicts
    scene, garment = garment_of("hula", *DRESS)
    cloth = scene.cloth
    mesh, _ = dress_mesh(cloth, cloth.waist_height, "dress")
    check_mesh(mesh, "dress")  # no degenerate faces, no edge of three faces, no loose vertex
    assert winding_conflicts(mesh) == 0
    # area: the bodice's prism and the skirt's frustum (polygons of 32 sides), and two straps,
    # each a band of half ellipses (z cos φ, STRAP_RISE sin φ) as wide as its chord across
    around, top = cloth.resolution[0], cloth.waist_height + cloth.bodice_height
    polygon = around * math.sin(math.pi / around) / math.pi  # perimeter over the circle's
    flare = cloth.hem_radius - cloth.bodice_radius
    tube = polygon * 2 * math.pi * (cloth.bodice_radius * cloth.bodice_height
                                    + (cloth.bodice_radius + flare / 2) * cloth.length)
    p0, p1, p2 = (garment.positions[garment.triangles[:, k]] for k in range(3))
    area, centre = 0.5 * np.linalg.norm(np.cross(p1 - p0, p2 - p0), axis=1), (p0 + p1 + p2) / 3
    assert area[centre[:, 1] < top].sum() == pytest.approx(tube, rel=0.002)
    apex = garment.positions[garment.pinned]
    strap_x = np.unique(np.round(apex[apex[:, 0] > 0, 0], 12))  # a strap's columns
    phi = np.linspace(0, math.pi, 20001)[:, None]
    strips = 0.0
    for x0, x1 in zip(strap_x[:-1], strap_x[1:]):  # the band between two columns' ellipses
        z0, z1 = (math.sqrt(cloth.bodice_radius ** 2 - x ** 2) for x in (x0, x1))
        tangent = np.hstack([0 * phi, STRAP_RISE * np.cos(phi), -0.5 * (z0 + z1) * np.sin(phi)])
        across = np.hstack([np.full_like(phi, x1 - x0), 0 * phi, (z1 - z0) * np.cos(phi)])
        strips += np.trapezoid(np.linalg.norm(np.cross(tangent, across), axis=1), phi[:, 0])
    # the strap's chords, ~4.5 cm at this resolution, cut its turn over the shoulder (a 5 cm
    # radius at the apex) by ~4 %
    assert area[centre[:, 1] > top].sum() == pytest.approx(2 * strips, rel=0.06)
    assert garment.mass.sum() == pytest.approx(scene.material.density * area.sum())
    # the triangles face outwards: from the axis on the tube
    normal = np.cross(p1 - p0, p2 - p0)
    on_tube = centre[:, 1] < top
    assert (np.einsum("tk,tk->t", normal[on_tube][:, [0, 2]], centre[on_tube][:, [0, 2]]) > 0).all()


def test_dress_hangs_from_its_straps_with_the_warp_down_the_dress():
    scene, garment = garment_of("hula", *DRESS)
    from taichi_cloth.cloth.dress import STRAP_RISE
    pins = garment.positions[garment.pinned]
    assert np.count_nonzero(pins[:, 0] > 0) == np.count_nonzero(pins[:, 0] < 0) > 6
    top = scene.cloth.waist_height + scene.cloth.bodice_height
    assert pins[:, 1].min() > top + 0.5 * STRAP_RISE  # the straps over the shoulders
    np.testing.assert_allclose(np.sort(pins[:, 0]), np.sort(-pins[:, 0]), atol=1e-12)  # mirrored
    tube = garment.positions[:, 1] < top - 1e-9
    down_the_dress = np.abs(garment.warp[tube, 1])
    assert np.median(down_the_dress) > 0.85  # the bodice and the skirt's cone hang on the grain
    straps = garment.positions[:, 1] > top + 1e-9
    across = np.abs(garment.warp[straps, 0])
    assert across.max() < 0.2  # a strap's grain runs along it (in the y–z plane)
