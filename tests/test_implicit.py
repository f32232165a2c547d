"""Backward Euler's ingredients and the stability machinery: Jacobians by finite differences, an
SPD system, CG convergence, dt = "auto" against a measured limit, and the blow-up guard."""

import numpy as np
import pytest
import taichi as ti
from systems import assemble

from taichi_cloth.effects import EFFECT_BY_NAME
from taichi_cloth.effects.collision import CapsuleContact, CollisionSettings
from taichi_cloth.effects.drag import Drag, DragSettings
from taichi_cloth.effects.gravity import Gravity, GravitySettings
from taichi_cloth.effects.ground import GroundContact, GroundSettings
from taichi_cloth.effects.wind import Wind, WindSettings
from taichi_cloth.cloth.garment import build_garment
from taichi_cloth.physics.integrators.conjugate_gradient import SolverBreakdown
from taichi_cloth.physics.integrators.implicit import BackwardEuler
from taichi_cloth.physics.metrics import state_problem
from taichi_cloth.physics.model import Model
from taichi_cloth.config.scene import load_scene
from taichi_cloth.physics.simulation import Simulation


class SheetWithBar:
    """A strained 6×5 sheet (f64) crossed by a capsule, so springs are stretched and compressed
    and some particles are inside the capsule."""

    def __init__(self):
        scene = load_scene("sheet", ("cloth.resolution=[6, 5]", "cloth.pin='none'",
                                     "cloth.material.stretch_stiffness=300",
                                     "cloth.material.shear_stiffness=40",
                                     "cloth.material.bend_stiffness=0.01"))
        garment = build_garment(scene.cloth, scene.material)
        self.model = Model(garment, "f64", 1.0)  # with dashpots
        # particle contact only: its Jacobian is exact (tests/test_surface_contact.py has the
        # surface samples')
        physics = assemble(self.model, [(CapsuleContact, CollisionSettings(
            stiffness=1e4, damping=0.3, friction=0.0, thickness=0.01, surface=False))],
            capsule_radius=[0.08])
        physics.control.capsule_track.hold(np.array([[-0.6, 1.3, 0.0], [0.6, 1.3, 0.0]]))
        self.forces = physics.forces
        self.state = self.model.state()
        n = self.model.particle_count
        self.force = ti.Vector.field(3, ti.f64, n)
        self.u = ti.Vector.field(3, ti.f64, n)
        self.stiffness_product = ti.Vector.field(3, ti.f64, n)
        self.damping_product = ti.Vector.field(3, ti.f64, n)
        rng = np.random.default_rng(4)
        self.x = garment.positions + 0.03 * rng.standard_normal(garment.positions.shape)
        self.rng = rng

    def force_at(self, x, v):
        self.state.x.from_numpy(x)
        self.state.v.from_numpy(v)
        self.forces.evaluate(self.state.x, self.state.v, 0.0, self.force)
        return self.force.to_numpy()

    def products(self, x, u, definite):
        self.state.x.from_numpy(x)
        self.state.v.fill(0.0)
        self.u.from_numpy(u)
        self.forces.evaluate_jacobian_products(self.state.x, self.state.v, self.u, 0.0, definite,
                                               self.stiffness_product, self.damping_product)
        return self.stiffness_product.to_numpy(), self.damping_product.to_numpy()


@pytest.fixture(scope="module")
def system():
    return SheetWithBar()


def test_the_configuration_has_compressed_springs_and_active_contacts(system):
    ends, rest = system.model.host_spring_ends, system.model.host_rest_length
    length = np.linalg.norm(system.x[ends[:, 1]] - system.x[ends[:, 0]], axis=1)
    assert (length < rest).sum() > 10 and (length > rest).sum() > 10
    inside = np.hypot(system.x[:, 1] - 1.3, system.x[:, 2]) < 0.09
    assert inside.sum() >= 2


def test_jacobian_products_equal_central_differences(system):
    zero = np.zeros_like(system.x)
    for _ in range(3):
        u = system.rng.standard_normal(system.x.shape)
        stiffness_u, damping_u = system.products(system.x, u, definite=False)
        eps = 1e-6
        numeric_stiffness = (system.force_at(system.x + eps * u, zero)
                             - system.force_at(system.x - eps * u, zero)) / (2 * eps)
        numeric_damping = (system.force_at(system.x, eps * u)
                           - system.force_at(system.x, -eps * u)) / (2 * eps)
        assert np.abs(stiffness_u).max() > 1.0 and np.abs(damping_u).max() > 1e-3
        np.testing.assert_allclose(stiffness_u, numeric_stiffness,
                                   atol=1e-6 * np.abs(stiffness_u).max())
        np.testing.assert_allclose(damping_u, numeric_damping, atol=1e-6 * np.abs(damping_u).max())


def assembled_operator(system, h, definite):
    """A = M − h·D − h²·K as a dense matrix, one column per unit vector."""
    n = system.model.particle_count
    mass = system.model.host_mass[:, None]
    columns = []
    for k in range(3 * n):
        u = np.zeros((n, 3))
        u.flat[k] = 1.0
        stiffness_u, damping_u = system.products(system.x, u, definite)
        columns.append((mass * u - h * damping_u - h * h * stiffness_u).ravel())
    return np.array(columns).T


def test_the_solver_operator_is_symmetric_positive_definite(system):
    """With the definite Jacobians A is SPD (so CG applies); with the exact ones, the compressed
    springs and the contact's curvature make it indefinite at the default step: the fix matters."""
    h = 1.0 / 60.0
    definite = assembled_operator(system, h, True)
    exact = assembled_operator(system, h, False)
    np.testing.assert_allclose(definite, definite.T, atol=1e-9 * np.abs(definite).max())
    np.testing.assert_allclose(exact, exact.T, atol=1e-9 * np.abs(exact).max())
    assert np.linalg.eigvalsh(definite).min() > 0
    assert np.linalg.eigvalsh(exact).min() < 0


class MovingSheet:
    """A strained, moving 8×6 sheet (f64, dashpots, two pinned corners) crossed by a capsule,
    dipping into the ground, in drag and wind: springs stretched and compressed and every kind
    of local block (contact, ground, drag, wind) in the implicit system."""

    h = 1.0 / 60.0
    t = 0.2

    def __init__(self):
        scene = load_scene("sheet", ("cloth.resolution=[8, 6]",
                                     "cloth.material.stretch_stiffness=300",
                                     "cloth.material.shear_stiffness=40",
                                     "cloth.material.bend_stiffness=0.01"))
        garment = build_garment(scene.cloth, scene.material)
        self.model = Model(garment, "f64", 1.0)
        effects = [(Gravity, GravitySettings()), (Drag, DragSettings()),
                   (Wind, WindSettings(gusts=0.5)),
                   (CapsuleContact, CollisionSettings(stiffness=1e4, damping=0.3, friction=0.4,
                                                      thickness=0.01, surface=False)),
                   (GroundContact, GroundSettings(height=0.68, stiffness=1e4, friction=0.4))]
        self.physics = assemble(self.model, effects, capsule_radius=[0.08])
        self.physics.control.capsule_track.hold(np.array([[-0.6, 1.3, 0.0], [0.6, 1.3, 0.0]]))
        self.forces = self.physics.forces
        rng = np.random.default_rng(7)
        self.x = garment.positions + 0.03 * rng.standard_normal(garment.positions.shape)
        self.v = 0.5 * rng.standard_normal(garment.positions.shape)
        self.v[garment.pinned] = 0.0
        self.rng = rng
        self.state, self.state_out = self.model.state(), self.model.state()
        n = self.model.particle_count
        self.u, self.out, self.stiffness_product, self.damping_product = (
            ti.Vector.field(3, ti.f64, n) for _ in range(4))

    def start(self):
        """The state back at (x, v)."""
        self.state.x.from_numpy(self.x)
        self.state.v.from_numpy(self.v)

    def reference_operator(self, integrator, u):
        """M·u − h·D·u − h²·K·u from ``Forces.evaluate_jacobian_products`` (definite) at the
        integrator's candidate and the step's end time."""
        self.u.from_numpy(u)
        candidate = integrator.candidate
        self.forces.evaluate_jacobian_products(candidate.x, candidate.v, self.u, self.t + self.h,
                                               True, self.stiffness_product, self.damping_product)
        return self.model.host_mass[:, None] * u - self.h * self.damping_product.to_numpy() \
            - self.h ** 2 * self.stiffness_product.to_numpy()

    def operator(self, integrator, u):
        """A·u from the integrator's precomputed blocks."""
        self.u.from_numpy(u)
        integrator.evaluate_operator(self.u, self.out)
        return self.out.to_numpy()


@pytest.fixture(scope="module")
def moving():
    return MovingSheet()


def test_the_precomputed_operator_equals_the_jacobian_products(moving):
    """The blocks the CG product gathers (n, a, b per spring, L_i per particle) give the same
    A·u as the Jacobian products that the finite-difference test checks, and the preconditioner
    inverts A's 3×3 diagonal blocks."""
    integrator = BackwardEuler(moving.forces, moving.physics.control)
    moving.start()
    integrator._start_candidate(moving.state, moving.t, moving.h)
    integrator._prepare(moving.t, moving.h, 0.0)
    x = integrator.candidate.x.to_numpy()
    ends, rest = moving.model.host_spring_ends, moving.model.host_rest_length
    length = np.linalg.norm(x[ends[:, 1]] - x[ends[:, 0]], axis=1)
    assert (length < rest).sum() > 10 and (length > rest).sum() > 10
    assert (np.hypot(x[:, 1] - 1.3, x[:, 2]) < 0.09).sum() >= 2  # inside the capsule
    assert (x[:, 1] < 0.68).sum() >= 2  # below the ground
    for _ in range(3):
        u = moving.rng.standard_normal(x.shape)
        expected = moving.reference_operator(integrator, u)
        np.testing.assert_allclose(moving.operator(integrator, u), expected,
                                   atol=1e-12 * np.abs(expected).max())
    n = moving.model.particle_count
    blocks = np.empty((n, 3, 3))
    for c in range(3):
        for i in range(n):
            u = np.zeros((n, 3))
            u[i, c] = 1.0
            blocks[i, :, c] = moving.reference_operator(integrator, u)[i]
    np.testing.assert_allclose(np.linalg.inv(integrator.inverse_block.to_numpy()), blocks,
                               rtol=1e-10, atol=1e-12 * np.abs(blocks).max())


def assembled_system(integrator, scratch):
    """A (3n × 3n) of the last ``_prepare``, column by column from ``evaluate_operator``, and
    the free particles' mask."""
    n = integrator.model.particle_count
    columns = []
    for c in range(3 * n):
        unit = np.zeros(3 * n)
        unit[c] = 1.0
        integrator.backward.from_numpy(unit.reshape(n, 3))  # its own scratch: overwritten per step
        integrator.evaluate_operator(integrator.backward, scratch)
        columns.append(scratch.to_numpy().ravel())
    return np.array(columns).T, integrator.model.particle_inv_mass.to_numpy() > 0


def preconditioned_norm_sq(integrator, scratch):
    """r ↦ r·M⁻¹·r for the free particles' system, M the integrator's preconditioner built here
    from A assembled anew: its 3×3 diagonal blocks D (block Jacobi, M = D) or symmetric block
    Gauss–Seidel M = W·D⁻¹·Wᵀ, W = D + (A's blocks below the diagonal)."""
    a, free = assembled_system(integrator, scratch)
    dofs = np.flatnonzero(np.repeat(free, 3))
    a = a[np.ix_(dofs, dofs)]
    block_of = np.arange(len(dofs)) // 3
    diagonal = np.where(block_of[:, None] == block_of[None, :], a, 0.0)
    lower = np.where(block_of[:, None] >= block_of[None, :], a, 0.0)

    def norm_sq(r):
        r = r[free].ravel()
        if not integrator.gauss_seidel:
            return r @ np.linalg.solve(diagonal, r)
        y = np.linalg.solve(lower, r)
        return y @ diagonal @ y
    return norm_sq


def stops_within_the_cold_start_tolerance(integrator, scratch) -> bool:
    """Did the last solve stop at r·M⁻¹r ≤ tol²·r₀·M⁻¹r₀, with r = S·(rhs − A·δ) recomputed,
    r₀ = S·rhs the residual of the cold start δ = 0 and M the preconditioner
    (``preconditioned_norm_sq``; 1 % margin for the rounding of the recursive residual)?
    ``scratch``: a vector field of the particle count."""
    integrator.evaluate_operator(integrator.delta_v, scratch)
    rhs = integrator.rhs.to_numpy()
    residual = rhs - scratch.to_numpy()
    norm_sq = preconditioned_norm_sq(integrator, scratch)
    return norm_sq(residual) <= (1.01 * integrator.tolerance) ** 2 * norm_sq(rhs)


def run_steps(integrator, state, state_out, x, v, t, h, steps, scratch):
    """``steps`` steps from (x, v) at time t, each checked with
    ``stops_within_the_cold_start_tolerance``; the velocities after each step."""
    state.x.from_numpy(x)
    state.v.from_numpy(v)
    velocities = []
    for k in range(steps):
        integrator.step(state, state_out, t + k * h, h)
        assert stops_within_the_cold_start_tolerance(integrator, scratch), k
        state.copy_from(state_out)
        velocities.append(state.v.to_numpy())
    return np.array(velocities)


def test_the_one_launch_serial_solve_and_the_parallel_one_take_the_same_steps(moving):
    """With block Jacobi, the serial step (the whole step in one launch, on one thread:
    ``_serial_step``) and the parallel one (a launch per pass and per CG iteration) run the
    same block functions: same iterations, same velocities; every solve meets the tolerance of
    the cold start."""
    runs = {}
    for serial in (True, False):
        integrator = BackwardEuler(moving.forces, moving.physics.control, gauss_seidel=False)
        integrator.serial = serial
        velocities = run_steps(integrator, moving.state, moving.state_out, moving.x, moving.v,
                               moving.t, moving.h, 5, moving.out)
        runs[serial] = integrator.take_iterations(), velocities
        # a non-finite state breaks the solve down, whichever way it runs: reported, not
        # counted as a step (the frame guard then rolls back and halves the step)
        poisoned = moving.v.copy()
        poisoned[np.flatnonzero(moving.model.host_inv_mass > 0)[0]] = np.nan
        moving.state.v.from_numpy(poisoned)
        with pytest.raises(SolverBreakdown, match="not finite"):
            integrator.step(moving.state, moving.state_out, moving.t, moving.h)
        assert integrator.take_iterations() == []
        moving.start()
    assert runs[True][0] == runs[False][0]
    np.testing.assert_allclose(runs[True][1], runs[False][1], rtol=0, atol=1e-12)


def falling_sheet_runs(variants: dict) -> dict:
    """A horizontal 10×10 sheet of cotton's stretch stiffness falling and swinging from two
    corners, 12 steps of 1/60 s with each variant of ``BackwardEuler``'s settings: per variant,
    the CG iterations of each step and the velocities after it (every solve checked with
    ``stops_within_the_cold_start_tolerance``)."""
    scene = load_scene("sheet", ("cloth.resolution=[10, 10]", "cloth.orientation=horizontal",
                                 "cloth.bending=springs",
                                 "cloth.material.stretch_stiffness=12258.3125"))
    garment = build_garment(scene.cloth, scene.material)
    model = Model(garment, "f64", 1.0)
    physics = assemble(model, [(EFFECT_BY_NAME[name], settings)
                               for name, settings in scene.effects.items()])
    state, state_out = model.state(), model.state()
    scratch = ti.Vector.field(3, ti.f64, model.particle_count)
    runs = {}
    for name, settings in variants.items():
        integrator = BackwardEuler(physics.forces, physics.control, **settings)
        velocities = run_steps(integrator, state, state_out, garment.positions,
                               np.zeros_like(garment.positions), 0.0, 1.0 / 60.0, 12, scratch)
        runs[name] = integrator.take_iterations(), velocities
    return runs


TIGHT = {"tolerance": 1e-9, "max_iterations": 5000}


@pytest.fixture(scope="module")
def falling_sheet():
    """The falling sheet with the shipped settings (warm start, Gauss–Seidel where serial), a
    cold start, block Jacobi and a tight solve: each variant's integrator compiled once for
    both tests below."""
    return falling_sheet_runs({"shipped": {}, "cold": {"warm_start": False},
                               "jacobi": {"gauss_seidel": False}, "tight": TIGHT})


def test_the_warm_start_cuts_iterations_and_keeps_the_cold_start_accuracy(falling_sheet):
    """Starting CG from the last step's velocity change takes far fewer iterations once the
    motion is under way (measured: 284 against 426 over the 12 steps), every solve still meets
    the cold start's tolerance, and the velocities stay as close to a solve at tolerance 1e-9 as
    the cold start's (0.005 against 0.004 m/s at worst, at a top speed of 1.3 m/s)."""
    runs = falling_sheet
    assert sum(runs["shipped"][0]) < 0.85 * sum(runs["cold"][0])
    warm_error, cold_error = (np.abs(runs[name][1] - runs["tight"][1]).max()
                              for name in ("shipped", "cold"))
    assert warm_error < 3 * cold_error


def test_gauss_seidel_takes_fewer_iterations_than_jacobi_for_the_same_accuracy(falling_sheet):
    """Symmetric Gauss–Seidel (Eisenstat's form) against block Jacobi at the same tolerance:
    each meets it in its own preconditioner's norm, Gauss–Seidel in under 0.6 of the iterations
    and with velocities no further from the tight solve than Jacobi's (measured: 284 against
    594 iterations over the 12 steps, 0.005 against 0.021 m/s at worst)."""
    runs = falling_sheet
    assert sum(runs["shipped"][0]) < 0.6 * sum(runs["jacobi"][0])
    errors = {name: np.abs(runs[name][1] - runs["tight"][1]).max()
              for name in ("shipped", "jacobi")}
    assert errors["shipped"] <= errors["jacobi"], errors


@pytest.mark.parametrize("scene_name, overrides", [
    ("sheet", ("cloth.resolution=[12, 12]",)),
    ("hula", ()),
])
def test_conjugate_gradients_reach_their_tolerance_at_a_sixtieth_of_a_second(scene_name,
                                                                            overrides):
    scene = load_scene(scene_name, overrides + ("simulation.integrator=implicit",
                                                "simulation.dt=0.016666667"))
    simulation = Simulation(scene)
    stats = simulation.stats(simulation.run(10))
    assert stats["substeps_per_frame"] == 2
    assert stats["cg"]["unconverged_steps"] == 0
    assert 1 < stats["cg"]["iterations_mean"] < scene.simulation.cg_max_iterations


def stays_stable(simulation, dt, steps=3000):
    """Run ``steps`` symplectic substeps of dt from rest; stable if finite and unexploded."""
    simulation.states.copy(simulation.state_in, simulation.backup)
    done = 0
    while done < steps:
        simulation.state_in, simulation.state_out = simulation.integrator.advance(
            simulation.state_in, simulation.state_out, done * dt, dt, 8)
        done += 8
    return state_problem(simulation.model, simulation.scene.simulation,
                         *simulation.host_state()) is None


def test_auto_step_is_stable_and_within_a_factor_two_of_the_measured_limit():
    scene = load_scene("sheet", ("cloth.resolution=[8, 8]", "cloth.material=denim",
                                 "simulation.integrator=symplectic", "effects.drag=false"))
    simulation = Simulation(scene)
    simulation.states.copy(simulation.backup, simulation.state_in)
    chosen = simulation.time_step.dt
    low, high = chosen, 8 * chosen
    assert stays_stable(simulation, low)
    assert not stays_stable(simulation, high)
    for _ in range(12):  # bisection on the real kernels
        middle = 0.5 * (low + high)
        low, high = (middle, high) if stays_stable(simulation, middle) else (low, middle)
    assert low / 2 <= chosen <= low
    assert simulation.time_step.stable_dt == pytest.approx(low, rel=0.5)


def test_guard_rolls_back_and_halves_the_step_instead_of_writing_nan():
    """Symplectic Euler at 1.6× its stability limit: the guard retries with half steps and
    the run finishes; nothing non-finite in the record."""
    probe = Simulation(load_scene("sheet", ("cloth.resolution=[8, 8]",)))
    too_big = 1.6 * probe.time_step.stable_dt
    scene = load_scene("sheet", ("cloth.resolution=[8, 8]", f"simulation.dt={too_big}"))
    simulation = Simulation(scene)
    record = simulation.run(6)
    assert record.retries >= 1
    assert simulation.time_step.dt < too_big / 1.5
    stats = simulation.stats(record)
    assert stats["retries"] == record.retries and len(stats["per_frame"]) == 7  # frames 0–6
    import json
    json.dumps(stats, allow_nan=False)


def test_implicit_auto_step_is_half_a_frame_and_its_report_is_valid_json():
    """Backward Euler has no stability bound: dt = "auto" takes half a frame, and the report
    says so with a null bound (an infinite one once made stats.json unwritable)."""
    import json
    scene = load_scene("sheet", ("cloth.resolution=[6, 6]", "simulation.integrator=implicit"))
    simulation = Simulation(scene)
    stats = simulation.stats(simulation.run(1))
    assert stats["substeps_per_frame"] == 2 and stats["dt"] == pytest.approx(1 / 60)
    assert stats["time_step"]["stable_dt"] is None and stats["time_step"]["omega_max"] > 0
    json.dumps(stats, allow_nan=False)
