"""Curvature bending (effects/bending.py) against closed forms: a tube of radius R stores
½·B·(1/R)²·area and converges under refinement, a flat or rigidly moved mesh stores nothing, the
force is −∇E and its Jacobian the force's derivative (finite differences), warp and weft take
their own rigidity, the implicit operator includes it, every integrator runs it, and
``dt = "auto"`` sees its stiffness."""

import dataclasses

import numpy as np
import pytest
import taichi as ti
from systems import assemble, energy_gradient

from taichi_cloth.cloth.garment import build_garment, hinge_rigidity
from taichi_cloth.config.scene import load_scene
from taichi_cloth.effects.bending import Bending, BendingSettings
from taichi_cloth.physics.integrators.implicit import BackwardEuler
from taichi_cloth.physics.model import Model
from taichi_cloth.physics.simulation import Simulation

RIGIDITY = 2e-5  # N·m


def bending_of(scene_name: str, *overrides, precision: str = "f64"):
    """(garment, Physics with the bending effect alone) of a scene's cloth, B = RIGIDITY both
    ways."""
    scene = load_scene(scene_name, overrides + (f"cloth.material.bend_stiffness={RIGIDITY}",
                                                f"simulation.precision='{precision}'"))
    garment = build_garment(scene.cloth, scene.material)
    physics = assemble(Model(garment, precision, None), [(Bending, BendingSettings())])
    return garment, physics


def mesh_area(positions: np.ndarray, triangles: np.ndarray) -> float:
    corner = positions[triangles]
    return 0.5 * float(np.linalg.norm(np.cross(corner[:, 1] - corner[:, 0],
                                               corner[:, 2] - corner[:, 0]), axis=1).sum())


def tube(around: int, down: int):
    """A cylinder of radius 0.1 m and length 0.3 m (a skirt with equal waist and hem)."""
    return bending_of("skirt", f"cloth.resolution=[{around}, {down}]", "cloth.waist_radius=0.1",
                      "cloth.hem_radius=0.1", "cloth.length=0.3")


def test_a_tube_stores_half_b_over_r_squared_per_area_and_converges():
    """Against the smooth tube ½·B/R²·2πRL within 3 %, closer at every refinement; and on the
    faceted tube itself (curvature 2·sin(π/n)/chord, its own area) exactly."""
    errors = []
    smooth = 0.5 * RIGIDITY / 0.1 ** 2 * 2 * np.pi * 0.1 * 0.3
    for around, down in ((24, 8), (48, 16), (96, 32)):
        garment, physics = tube(around, down)
        energy = physics.effects[0].energy(garment.positions)
        errors.append(abs(energy / smooth - 1))
        chord = 2 * 0.1 * np.sin(np.pi / around)
        faceted = 0.5 * RIGIDITY * (2 * np.sin(np.pi / around) / chord) ** 2 \
            * mesh_area(garment.positions, garment.triangles)
        assert energy == pytest.approx(faceted, rel=1e-9)
    assert max(errors) < 0.03
    assert errors[0] > errors[1] > errors[2]


def test_flat_and_rigidly_moved_meshes_store_nothing():
    garment, physics = bending_of("sheet", "cloth.resolution=[7, 6]")
    bending = physics.effects[0]
    scale = 0.5 * RIGIDITY * mesh_area(garment.positions, garment.triangles) / 0.1 ** 2
    assert bending.energy(garment.positions) < 1e-12 * scale
    rotation, _ = np.linalg.qr(np.random.default_rng(1).standard_normal((3, 3)))
    moved = garment.positions @ rotation.T + [0.3, -1.0, 2.0]
    assert bending.energy(moved) < 1e-12 * scale
    tube_garment, tube_physics = tube(24, 8)
    tube_bending = tube_physics.effects[0]
    assert tube_bending.energy(tube_garment.positions @ rotation.T + 1.0) == pytest.approx(
        tube_bending.energy(tube_garment.positions), rel=1e-10)


class ForceProbe:
    """Evaluates a Physics' total force at host states, reusing its fields (each new field pair
    would cost a Taichi SNode tree)."""

    def __init__(self, physics):
        self.physics = physics
        n = physics.model.particle_count
        self.state = physics.model.state()
        self.out, self.u = ti.Vector.field(3, ti.f64, n), ti.Vector.field(3, ti.f64, n)
        self.stiffness, self.damping = (ti.Vector.field(3, ti.f64, n),
                                        ti.Vector.field(3, ti.f64, n))

    def force(self, x: np.ndarray, v: np.ndarray) -> np.ndarray:
        self.state.x.from_numpy(x)
        self.state.v.from_numpy(v)
        self.physics.forces.evaluate(self.state.x, self.state.v, 0.0, self.out)
        return self.out.to_numpy()

    def jacobian_products(self, x, v, u):
        """((∂f/∂x)·u, (∂f/∂v)·u), exact (not the solver's definite clamp)."""
        self.state.x.from_numpy(x)
        self.state.v.from_numpy(v)
        self.u.from_numpy(u)
        self.physics.forces.evaluate_jacobian_products(self.state.x, self.state.v, self.u, 0.0,
                                                       False, self.stiffness, self.damping)
        return self.stiffness.to_numpy(), self.damping.to_numpy()


def test_force_is_minus_the_energy_gradient():
    garment, physics = bending_of("sheet", "cloth.resolution=[6, 5]", "cloth.springs=['shear']")
    bending = physics.effects[0]
    rng = np.random.default_rng(2)
    x = garment.positions + 0.01 * rng.standard_normal(garment.positions.shape)
    springs_only = ForceProbe(assemble(physics.model))
    force = ForceProbe(physics).force(x, np.zeros_like(x)) - springs_only.force(x, 0 * x)
    assert np.abs(force).max() > 1e-6  # non-trivial
    gradient = energy_gradient(bending.energy, x, 1e-6)
    np.testing.assert_allclose(force, -gradient, atol=1e-6 * np.abs(force).max())


def test_jacobians_are_the_derivatives_of_the_force():
    """∂f/∂x (at rest velocities, where the dashpots' ∂/∂x vanishes) and, with dashpots,
    ∂f/∂v, by central differences of the whole force (springs and bending)."""
    scene = load_scene("sheet", ("cloth.resolution=[5, 4]", "simulation.precision='f64'",
                                 f"cloth.material.bend_stiffness={RIGIDITY}",
                                 "cloth.material.damping=0.01"))
    garment = build_garment(scene.cloth, scene.material)
    probe = ForceProbe(assemble(Model(garment, "f64", 1.0), [(Bending, BendingSettings())]))
    n = garment.particle_count
    rng = np.random.default_rng(3)
    x = garment.positions + 0.01 * rng.standard_normal((n, 3))
    v = 0.1 * rng.standard_normal((n, 3))
    u = rng.standard_normal((n, 3))
    step = 1e-5
    stiffness, _ = probe.jacobian_products(x, 0 * v, u)
    by_x = (probe.force(x + step * u, 0 * v) - probe.force(x - step * u, 0 * v)) / (2 * step)
    np.testing.assert_allclose(stiffness, by_x, atol=1e-6 * np.abs(by_x).max())
    _, damping = probe.jacobian_products(x, v, u)
    by_v = (probe.force(x, v + step * u) - probe.force(x, v - step * u)) / (2 * step)
    assert np.abs(by_v).max() > 0
    np.testing.assert_allclose(damping, by_v, atol=1e-6 * np.abs(by_v).max())


def test_warp_and_weft_each_bend_with_their_own_rigidity():
    """A hinge along the weft folds the warp (B_warp), one along the warp the weft (B_weft),
    a diagonal one the mean; a bias turns the warp."""
    positions = np.array([[0.0, 0, 0], [1.0, 0, 0], [0.0, 1, 0], [1.0, 1, 0], [0.0, -1, 0]])
    warp = np.tile([0.0, 1.0, 0.0], (5, 1))  # warp along y
    stencils = np.array([[0, 1, 2, 4], [0, 2, 1, 3], [0, 3, 1, 2]])  # edges along x, y, diagonal
    np.testing.assert_allclose(hinge_rigidity(positions, warp, stencils, 3.0, 1.0),
                               [3.0, 1.0, 2.0])
    biased = np.tile([np.sin(np.pi / 4), np.cos(np.pi / 4), 0.0], (5, 1))
    np.testing.assert_allclose(hinge_rigidity(positions, biased, stencils, 3.0, 1.0)[:2],
                               [2.0, 2.0])


def test_the_implicit_operator_includes_bending():
    """(A·u) = M·u − h·D·u − h²·K·u with the bending blocks (and the springs'), against the
    Jacobian products."""
    garment, physics = bending_of("sheet", "cloth.resolution=[5, 4]")
    model = physics.model
    integrator = assemble(model, [(Bending, BendingSettings())], integrator="implicit")
    stepper = integrator.integrator
    n = model.particle_count
    state_in, state_out = model.state(), model.state()
    h = 1.0 / 60.0
    stepper.step(state_in, state_out, 0.0, h)
    u = ti.Vector.field(3, ti.f64, n)
    rng = np.random.default_rng(4)
    direction = rng.standard_normal((n, 3)) * (~garment.pinned)[:, None]
    u.from_numpy(direction)
    product = ti.Vector.field(3, ti.f64, n)
    stepper.evaluate_operator(u, product)
    stiffness, damping = ti.Vector.field(3, ti.f64, n), ti.Vector.field(3, ti.f64, n)
    integrator.forces.evaluate_jacobian_products(stepper.candidate.x, stepper.candidate.v, u,
                                                 h, True, stiffness, damping)
    expected = (garment.mass[:, None] * direction - h * damping.to_numpy()
                - h * h * stiffness.to_numpy())
    free = ~garment.pinned
    np.testing.assert_allclose(product.to_numpy()[free], expected[free],
                               atol=1e-9 * np.abs(expected).max())


def test_the_gauss_seidel_sweeps_solve_the_system_with_bending_folded_into_the_springs():
    """The sweeps read A's off-diagonal blocks from rows of their own, bending's H_ij folded
    into the springs' blocks (``gather.sweep_rows``): solved tightly, their δ satisfies
    A·δ = rhs for A from the product that gathers the springs and bending apart
    (``evaluate_operator``), dashpots included, on a crumpled sheet whose bending is as stiff
    as its springs."""
    scene = load_scene("sheet", ("cloth.resolution=[6, 5]", "cloth.material.bend_stiffness=0.2",
                                 "cloth.material.stretch_stiffness=300",
                                 "cloth.material.shear_stiffness=40"))
    garment = build_garment(scene.cloth, scene.material)
    model = Model(garment, "f64", 1.0)
    physics = assemble(model, [(Bending, BendingSettings())])
    stepper = BackwardEuler(physics.forces, physics.control, tolerance=1e-12,
                            max_iterations=5000)
    assert stepper.gauss_seidel and model.dashpot_time > 0
    state_in, state_out = model.state(), model.state()
    rng = np.random.default_rng(5)
    state_in.x.from_numpy(garment.positions + 0.02 * rng.standard_normal(garment.positions.shape))
    state_in.v.from_numpy(0.1 * rng.standard_normal(garment.positions.shape))
    stepper.step(state_in, state_out, 0.0, 1.0 / 60.0)
    n = model.particle_count
    product = ti.Vector.field(3, ti.f64, n)
    stepper.evaluate_operator(stepper.delta_v, product)
    free = ~garment.pinned
    rhs = stepper.rhs.to_numpy()[free]
    bending_share = np.abs(physics.effects[0].host_row_coefficient).max()
    assert bending_share > 0.1 * model.host_stiffness.max()  # bending matters in A
    residual = rhs - product.to_numpy()[free]
    assert np.linalg.norm(residual) <= 1e-8 * np.linalg.norm(rhs)


@pytest.mark.parametrize("integrator", ["euler", "symplectic", "rk4", "implicit"])
def test_every_integrator_runs_curvature_bending(integrator):
    simulation = Simulation.from_scene("sheet", ("cloth.resolution=[6, 6]",
                                                 f"simulation.integrator={integrator}"))
    assert "bending" in simulation.effect_names
    record = simulation.run(3)
    assert len(record.frames) == 4 and record.retries == 0  # frame 0 (the start) and 3 more
    assert record.frames[-1].extra["bending_energy"] > 0  # it bends as it swings


def test_auto_step_accounts_for_bending_stiffness():
    """A much stiffer B raises ω_max and shortens the symplectic step; the run stays stable."""
    soft = Simulation.from_scene("sheet", ("cloth.resolution=[6, 6]",))
    stiff = Simulation.from_scene("sheet", ("cloth.resolution=[6, 6]",
                                            "cloth.material.bend_stiffness=500.0"))
    assert stiff.time_step.omega_max > 2 * soft.time_step.omega_max
    assert stiff.time_step.dt < 0.5 * soft.time_step.dt
    record = stiff.run(2)
    assert record.retries == 0


def test_bending_is_declared_by_the_cloth_and_springs_stay_selectable():
    curvature = load_scene("sheet")
    assert "bending" in curvature.effects
    springs = load_scene("sheet", ("cloth.bending=springs",))
    assert "bending" not in springs.effects
    assert "bend" in build_garment(springs.cloth, springs.material).springs
    none = load_scene("sheet", ("cloth.bending=none",))
    assert "bending" not in none.effects
    scaled = load_scene("sheet", ("effects.bending.scale=2",))
    assert dataclasses.asdict(scaled.effects["bending"]) == {"scale": 2.0}
