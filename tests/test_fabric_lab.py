"""The virtual textile lab (studies/fabric_lab.py, cantilever.py, drape.py) against the textile
closed forms: the cantilever's measured bending length c = l·(cos(θ/2)/(8·tan θ))^(1/3) within
10 % of (B/(ρ_A·g))^(1/3) at every resolution and in both directions, warp and weft in the right
order; the drape coefficient inside (0, 1), ordering the fabrics by bending length, stable under
refinement; the shadow area and fold count on shapes whose answer is known; the command's files.
The full table for every preset at two resolutions is docs/fabric-tests.md."""

import dataclasses
import math
import types

import numpy as np
import pytest

from taichi_cloth.cli import main
from taichi_cloth.config.materials import PRESETS
from taichi_cloth.studies.cantilever import cantilever, peirce_factor
from taichi_cloth.studies.drape import (BUCKLE_LIFT, DISC_RADIUS, DYNAMIC_STEPS, MOVE_TOLERANCE,
                                        SPECIMEN_RADIUS, START_STEPS, drape, drape_coefficient,
                                        node_count, settle_dynamically, shadow_area)


def test_peirce_factor_is_half_at_the_standard_angle():
    assert peirce_factor(math.radians(41.5)) == pytest.approx(0.509, abs=5e-4)


@pytest.mark.parametrize("material, direction, fraction", [
    ("cotton", "warp", 0.25), ("cotton", "warp", 0.125), ("silk", "warp", 0.5),
    ("denim", "weft", 0.5),
])  # cotton warp and weft at c/2: test_warp_and_weft_order_follows_their_rigidity
def test_cantilever_measures_the_bending_length_of_b(material, direction, fraction):
    row = cantilever((f"cloth.material={material}",), direction, fraction)
    assert abs(row["length_error"]) < 0.10
    assert abs(row["tip_angle_deg"] - 41.5) < 0.5  # the overhang was searched to the line
    assert row["residual"] < 1e-4  # at rest: no particle carries 1e-4 of its weight unbalanced


def test_a_material_set_on_the_command_line_is_measured_too():
    """A fabric defined with --set (B isotropic 4e-5 N·m on 200 g/m²)."""
    row = cantilever(("cloth.material.bend_stiffness=4e-5", "cloth.material.density=0.2"),
                     "warp", 0.5)
    expected = (4e-5 / (0.2 * 9.81)) ** (1 / 3)
    assert row["expected_bending_length_m"] == pytest.approx(expected)
    assert row["bending_length_m"] == pytest.approx(expected, rel=0.10)


def test_warp_and_weft_order_follows_their_rigidity():
    """Cotton at c/2 in both directions: each within 10 % of its own bending length, at the
    41.5° line and at rest, and the stiffer warp the longer."""
    cotton = PRESETS["cotton"]
    assert cotton.bend_stiffness > cotton.bend_weft
    warp = cantilever(("cloth.material=cotton",), "warp", 0.5)
    weft = cantilever(("cloth.material=cotton",), "weft", 0.5)
    for row in (warp, weft):
        assert abs(row["length_error"]) < 0.10
        assert abs(row["tip_angle_deg"] - 41.5) < 0.5
        assert row["residual"] < 1e-4
    assert warp["bending_length_m"] > 1.05 * weft["bending_length_m"]


def test_shadow_area_of_known_shapes():
    """A flat disc of the specimen's radius shades its area; a flat annulus outside the disc's
    radius as well (to the raster's resolution)."""
    around, rings = 64, 8
    angle = 2 * np.pi * np.arange(around) / around
    radius = np.linspace(0.0, SPECIMEN_RADIUS, rings)
    points = np.stack([np.outer(radius, np.cos(angle)), np.zeros((rings, around)),
                       np.outer(radius, np.sin(angle))], axis=-1).reshape(-1, 3)
    triangles = []
    for ring in range(rings - 1):
        for k in range(around):
            a, b = ring * around + k, ring * around + (k + 1) % around
            triangles += [(a, b, a + around), (b, b + around, a + around)]
    polygon_area = 0.5 * around * SPECIMEN_RADIUS ** 2 * np.sin(2 * np.pi / around)
    area = shadow_area(points, np.array(triangles))
    assert area == pytest.approx(polygon_area, rel=5e-3)
    assert drape_coefficient(math.pi * DISC_RADIUS ** 2) == 0.0
    assert drape_coefficient(math.pi * SPECIMEN_RADIUS ** 2) == pytest.approx(1.0)


@pytest.mark.parametrize("spacing", [0.025, 0.0143, 0.0101, 0.0072, 0.0036])
def test_the_specimen_has_a_ring_on_the_support_edge_and_rings_within_the_spacing(spacing):
    from taichi_cloth.studies.drape import CENTRE_HOLE, disc_overrides
    settings = dict(item.split("=", 1) for item in disc_overrides(spacing))
    around, rings = (int(n) for n in settings["cloth.resolution"].strip("[]").split(","))
    radii = np.linspace(CENTRE_HOLE, SPECIMEN_RADIUS, rings)
    assert np.min(np.abs(radii - DISC_RADIUS)) < 1e-12
    assert radii[1] - radii[0] <= spacing + 1e-12
    assert 2 * math.pi * SPECIMEN_RADIUS / around <= spacing
    assert float(settings["effects.support.radius"]) == DISC_RADIUS


def test_drape_spacing_resolves_the_overhang_as_well_as_the_bending_length():
    from taichi_cloth.studies.drape import reference_length
    assert reference_length(0.0143) == 0.0143  # silk: its bending length
    assert reference_length(0.0252) == pytest.approx((SPECIMEN_RADIUS - DISC_RADIUS) / 3)


def test_node_count_counts_the_bulges_of_the_hem():
    angle = np.linspace(0, 2 * np.pi, 240, endpoint=False)
    for folds in (4, 6, 9):
        radius = 0.12 + 0.01 * np.cos(folds * angle + 0.3) + 0.0005 * np.sin(37 * angle)
        assert node_count(radius) == folds
    assert node_count(np.full(50, 0.1)) == 0


@pytest.fixture(scope="module")
def drapes():
    """Wool, cotton and denim at the coarse spacing (one reference length), and cotton at 0.7 of
    it (silk drapes above wool for all its shorter bending length, its shear rigidity the
    larger; polyester's specimen takes ~20 s, denim's finer ones ~500 Newton steps:
    docs/fabric-tests.md)."""
    return {(material, fraction): drape((f"cloth.material={material}",), fraction, specimens=1)
            for material, fraction in (("wool", 1.0), ("cotton", 1.0), ("denim", 1.0),
                                       ("cotton", 0.7))}


def test_drape_coefficients_order_the_fabrics_and_stay_under_refinement(drapes):
    coarse = [drapes[(material, 1.0)] for material in ("wool", "cotton", "denim")]
    for row in drapes.values():
        assert 0.0 < row["drape_coefficient"] < 1.0
        assert row["nodes"] >= 3
        assert row["residual"] < 1e-3
        assert 0.0 < row["lift_m"] < BUCKLE_LIFT  # draped, lifting a little between the folds
    assert [row["bending_length_m"] for row in coarse] == sorted(
        row["bending_length_m"] for row in coarse)
    assert [row["drape_coefficient"] for row in coarse] == sorted(
        row["drape_coefficient"] for row in coarse)
    assert abs(drapes[("cotton", 0.7)]["drape_coefficient"]
               - drapes[("cotton", 1.0)]["drape_coefficient"]) < 0.05


@dataclasses.dataclass
class ScriptedState:
    positions: np.ndarray  # m
    velocities: np.ndarray  # m/s
    dt: float = 0.5  # s
    substeps_per_frame: int = 1


class ChatteringSpecimen:
    """A stand-in for the drape's simulation whose fall is scripted: a particle over the plate
    rises by ``bump`` at 1 cm/s on odd steps and falls back at 0.5 cm/s on even ones, so that the
    kinetic energy peaks every two steps and the damping zeroes it at the foot of the bump; the
    foot moves by ``drift`` at each step down (0: it comes back to the same place)."""

    def __init__(self, bump: float, drift: float):
        self.bump, self.drift, self.steps = bump, drift, 0
        self.model = types.SimpleNamespace(host_mass=np.ones(2))
        self.state = ScriptedState(np.array([[0.12, 0.5, 0.0], [0.0, 0.5, 0.12]]), np.zeros((2, 3)))

    def snapshot(self) -> ScriptedState:
        return dataclasses.replace(self.state, positions=self.state.positions.copy(),
                                   velocities=self.state.velocities.copy())

    def restore(self, state: ScriptedState) -> None:  # copied in, as into the fields
        self.state = dataclasses.replace(state, positions=state.positions.copy(),
                                         velocities=state.velocities.copy())

    def set_time_step(self, dt: float, substeps: int) -> None:
        self.state.dt, self.state.substeps_per_frame = dt, substeps

    def advance_frame(self, frame: int, record) -> None:
        self.steps += 1
        up = self.steps % 2 == 1
        self.state.positions[0, 1] += self.bump if up else self.drift - self.bump
        self.state.velocities[0] = [0.0, 0.01 if up else 0.005, 0.0]


@pytest.mark.parametrize("drift, falls_to_the_cap", [(0.0, False), (10 * MOVE_TOLERANCE, True)])
def test_the_fall_ends_when_a_zeroing_finds_the_cloth_where_the_last_one_left_it(drift,
                                                                                 falls_to_the_cap):
    """A fall chattering on one spot stops at its second zeroing in the same place; one whose
    feet drift by more than the move tolerance goes on to the cap."""
    specimen = ChatteringSpecimen(bump=1e-4, drift=drift)
    steps = settle_dynamically(specimen, 0)
    assert steps == (START_STEPS + DYNAMIC_STEPS if falls_to_the_cap else 6)
    assert specimen.steps == steps
    if not falls_to_the_cap:  # stopped at a zeroing: left at rest for the Newton steps
        assert not specimen.state.velocities.any()


def test_fabric_test_command_writes_table_csv_and_pictures(tmp_path, capsys):
    assert main(["fabric-test", "cantilever", "--material", "silk", "--resolution", "0.5",
                 "--out", str(tmp_path), "--quiet"]) == 0
    printed = capsys.readouterr().out
    assert "silk" in printed and "c from B" in printed
    lines = (tmp_path / "results.csv").read_text().splitlines()
    assert len(lines) == 3 and lines[0].startswith("test,material,direction")
    assert sorted(p.name for p in tmp_path.glob("*.png")) == [
        "cantilever_silk_warp_0.5.png", "cantilever_silk_weft_0.5.png"]


@pytest.mark.parametrize("argv, flag", [
    (["fabric-test", "cantilever", "--material", "linen"], "--material"),
    (["fabric-test", "drape", "--resolution", "2"], "--resolution"),
    (["fabric-test", "drape", "--resolution", "x"], "--resolution"),
    (["fabric-test", "drape", "--specimens", "0"], "--specimens"),
    (["fabric-test", "cantilever", "--set", "cloth.material.density=-1"], "density"),
])
def test_bad_lab_input_is_one_line_exit_2(argv, flag, capsys):
    assert main(argv) == 2
    message = capsys.readouterr().err.strip()
    assert flag in message and "\n" not in message


def test_each_specimen_starts_from_its_own_ripple_on_every_mesh():
    """The start ripple is a function of the angle alone (so a refined mesh meets the same
    start), its largest value is RIPPLE, and two specimens start differently."""
    from taichi_cloth.studies.drape import RIPPLE, start_ripple
    coarse = np.linspace(0.0, 2 * np.pi, 64, endpoint=False)
    fine = np.linspace(0.0, 2 * np.pi, 256, endpoint=False)
    np.testing.assert_allclose(start_ripple(fine, 1)[::4], start_ripple(coarse, 1), rtol=1e-12)
    assert np.abs(start_ripple(fine, 0)).max() == pytest.approx(RIPPLE, rel=0.01)
    assert np.abs(start_ripple(fine, 0) - start_ripple(fine, 1)).max() > 0.3 * RIPPLE
