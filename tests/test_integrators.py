"""Integrators against the closed forms of docs/physics.md, on one undamped or damped spring."""

import math

import numpy as np
import pytest

from taichi_cloth.physics.integrators import INTEGRATORS
from taichi_cloth.physics.integrators.stability import largest_stable_step, mode_step_limit

from systems import SpringOscillator

OMEGA = 2.0


@pytest.fixture(scope="module")
def oscillators():
    """One undamped and one damped (ζ = 0.1) oscillator per integrator, compiled once."""
    return {(name, zeta): SpringOscillator(name, OMEGA, zeta)
            for name in INTEGRATORS for zeta in (0.0, 0.1)}


def energy_ratios(oscillator, steps, h):
    e0 = oscillator.energy(oscillator.amplitude, 0.0)
    return np.array([oscillator.energy(u, v) / e0 for u, v in oscillator.run(steps, h)])


def test_explicit_euler_energy_grows_by_exactly_one_plus_omega_h_squared(oscillators):
    h = 0.1 / OMEGA
    ratios = energy_ratios(oscillators[("euler", 0.0)], 100, h)
    per_step = ratios / np.concatenate([[1.0], ratios[:-1]])
    np.testing.assert_allclose(per_step, 1.01, rtol=1e-12)
    assert ratios[-1] == pytest.approx(2.70481, rel=1e-5)  # docs/physics.md: 1.01^100


def test_symplectic_euler_conserves_its_modified_energy(oscillators):
    oscillator, h = oscillators[("symplectic", 0.0)], 0.5 / OMEGA
    w2 = OMEGA ** 2
    modified = [0.5 * (v * v + w2 * u * u - w2 * h * v * u) for u, v in oscillator.run(200, h)]
    start = 0.5 * w2 * oscillator.amplitude ** 2
    np.testing.assert_allclose(modified, start, rtol=1e-11)
    plain = energy_ratios(oscillator, 200, h)
    assert plain.max() - plain.min() > 0.1  # the plain energy does oscillate: the test has teeth


def test_rk4_energy_factor_matches_its_stability_polynomial(oscillators):
    y = 1.0
    ratios = energy_ratios(oscillators[("rk4", 0.0)], 100, y / OMEGA)
    factor = 1 - y ** 6 / 72 + y ** 8 / 576
    np.testing.assert_allclose(ratios, factor ** np.arange(1, 101), rtol=1e-10)
    assert ratios[-1] == pytest.approx(0.294427, rel=1e-5)


@pytest.mark.parametrize("y, grows", [(2.83, True), (2.828, False)])
def test_rk4_stability_edge(oscillators, y, grows):
    ratio = energy_ratios(oscillators[("rk4", 0.0)], 100, y / OMEGA)[-1]
    assert (ratio > 1.0) == grows
    assert ratio == pytest.approx(2.20 if grows else 0.807, rel=0.01)


def exact_displacement(t, amplitude, zeta):
    """u(t) of ü = −ω²u − 2ζω·u̇, u(0) = amplitude, u̇(0) = 0."""
    omega_d = OMEGA * math.sqrt(1 - zeta ** 2)
    return amplitude * math.exp(-zeta * OMEGA * t) * (
        math.cos(omega_d * t) + zeta * OMEGA / omega_d * math.sin(omega_d * t))


@pytest.mark.parametrize("zeta", [0.0, 0.1])
@pytest.mark.parametrize("name, order, steps", [
    ("euler", 1, (200, 400, 800)),
    ("symplectic", 1, (200, 400, 800)),
    ("rk4", 4, (10, 20, 40)),
    ("implicit", 1, (200, 400, 800)),
])
def test_convergence_order_at_fixed_end_time(oscillators, name, order, steps, zeta):
    """Global error at T = 2 s falls as h^p (docs/physics.md); with dashpots on too, which catches an
    RK4 that damps with the step's starting velocity."""
    end_time = 2.0
    oscillator = oscillators[(name, zeta)]
    errors = []
    for n in steps:
        u, _ = oscillator.run(n, end_time / n)[-1]
        errors.append(abs(u - exact_displacement(end_time, oscillator.amplitude, zeta)))
    measured = np.log2(np.array(errors[:-1]) / np.array(errors[1:]))
    np.testing.assert_allclose(measured, order, atol=0.15 * order)


@pytest.mark.parametrize("zeta, expected", [
    (0.0, {"euler": 0.0, "symplectic": 2.0, "rk4": 2.828}),
    (0.1, {"euler": 0.20, "symplectic": 1.810, "rk4": 2.951}),
    (0.5, {"euler": 1.00, "symplectic": 1.236, "rk4": 2.623}),
    (1.0, {"euler": 2.00, "symplectic": 0.828, "rk4": 2.785}),
])
def test_stability_limits_match_the_oracle_table(zeta, expected):
    for name, limit in expected.items():
        assert mode_step_limit(name, 1.0, zeta) == pytest.approx(limit, abs=2e-3)


def test_stability_limit_is_where_the_integrator_really_blows_up(oscillators):
    """The bound from the amplification matrix separates decaying from growing runs of the real
    kernels (symplectic, ζ = 0.1: ωh = 1.810)."""
    oscillator = oscillators[("symplectic", 0.1)]
    limit = mode_step_limit("symplectic", OMEGA, 0.1)
    assert limit * OMEGA == pytest.approx(1.810, abs=2e-3)
    below = energy_ratios(oscillator, 400, 0.97 * limit)[-1]
    above = energy_ratios(oscillator, 400, 1.03 * limit)[-1]
    assert below < 1.0 < above


def test_rayleigh_damped_cloth_is_limited_by_its_highest_mode():
    """With ζ = β·ω/2 the symplectic bound shrinks with ω, so the cloth's bound is its top mode's."""
    omega_max, damping_time = 5000.0, 2e-4
    bound = largest_stable_step("symplectic", omega_max, damping_time)
    assert bound == pytest.approx(
        mode_step_limit("symplectic", omega_max, 0.5 * damping_time * omega_max), rel=1e-6)
    assert largest_stable_step("euler", omega_max, 0.0) == 0.0  # undamped: never stable


def test_backward_euler_energy_decreases_every_step_even_at_huge_steps(oscillators):
    """docs/physics.md: backward Euler's energy decreases every step, at any h; here ωh = 0.5 and 100."""
    for y, steps in ((0.5, 50), (100.0, 5)):  # at ωh = 100, 1e-4 per step: 5 steps to 1e-20
        ratios = energy_ratios(oscillators[("implicit", 0.0)], steps, y / OMEGA)
        assert np.all(np.diff(np.concatenate([[1.0], ratios])) < 0)
        assert np.all(np.isfinite(ratios))
    assert ratios[0] == pytest.approx(1.0 / (1.0 + 100.0 ** 2), rel=1e-9)  # |1/(1 − iy)|²


class MovingAnchor:
    """The one-spring system with its anchor (particle 0) moving as A·sin(Ωt) along x, sampled
    densely into the pin track (Hermite between samples, error ~1e-12 m here)."""

    def __init__(self, integrator: str, zeta: float, end_time: float = 2.0):
        from taichi_cloth.physics.model import Model
        from systems import assemble, one_spring_garment
        self.garment = one_spring_garment(OMEGA, damping_time=2.0 * zeta / OMEGA)
        samples = 2001
        self.model = Model(self.garment, "f64", 1.0 if zeta > 0 else None)
        physics = assemble(self.model, integrator=integrator, sample_count=samples)
        times = np.linspace(0.0, end_time, samples)
        anchor = np.zeros((samples, 2, 3))
        anchor_velocity = np.zeros((samples, 2, 3))
        anchor[:, 0, 0] = 0.2 * np.sin(3.0 * times)
        anchor_velocity[:, 0, 0] = 0.6 * np.cos(3.0 * times)
        anchor[:, 1] = self.garment.positions[2]
        physics.control.pin_track.upload(0.0, times[1], anchor, anchor_velocity)
        self.integrator = physics.integrator
        self.states = self.model.state(), self.model.state()

    def displacement_at(self, end_time: float, steps: int) -> float:
        state_in, state_out = self.states
        state_in.x.from_numpy(self.garment.positions)
        velocity = np.zeros_like(self.garment.positions)
        velocity[0, 0] = 0.6  # the anchor starts at its own speed (else the dashpot's first
        state_in.v.from_numpy(velocity)  # step sees a jump, an O(h) error of its own)
        h = end_time / steps
        for n in range(steps):
            self.integrator.step(state_in, state_out, n * h, h)
            state_in, state_out = state_out, state_in
        return state_in.x.to_numpy()[1, 0]


@pytest.mark.parametrize("name, order", [("rk4", 4), ("symplectic", 1)])
def test_convergence_order_holds_with_a_moving_pin(name, order):
    """A moving anchor (the skirt's waist on the dancer): RK4 stays fourth order only if its
    inner stages see the pin where it really is, not on a straight line from the step's start."""
    system = MovingAnchor(name, zeta=0.1)
    steps = (20, 40, 80) if order == 4 else (200, 400, 800)
    reference = system.displacement_at(2.0, 8 * steps[-1])
    errors = [abs(system.displacement_at(2.0, n) - reference) for n in steps]
    measured = np.log2(np.array(errors[:-1]) / np.array(errors[1:]))
    np.testing.assert_allclose(measured, order, atol=0.2 * order)
