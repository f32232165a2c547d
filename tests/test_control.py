"""Prescribed motion: the kinematic track's cubic Hermite interpolation is exact for cubic motion
and clamps outside its span, and the control holds pinned particles at their rest positions and
marks free ones."""

import numpy as np
import pytest
import taichi as ti

from taichi_cloth.physics.control import Control, KinematicTrack


@ti.kernel
def sample_track(track: ti.template(), point: ti.i32, times: ti.types.ndarray(),
                 position: ti.types.ndarray(), velocity: ti.types.ndarray()):
    for i in range(times.shape[0]):
        p, v = track.at(point, times[i])
        for k in ti.static(range(3)):
            position[i, k] = p[k]
            velocity[i, k] = v[k]


@ti.kernel
def sample_pins(control: ti.template(), particles: ti.types.ndarray(), t: ti.f64,
                position: ti.types.ndarray(), velocity: ti.types.ndarray()):
    for i in range(particles.shape[0]):
        p, v = control.pin_target(particles[i], t)
        for k in ti.static(range(3)):
            position[i, k] = p[k]
            velocity[i, k] = v[k]


def sampled(track, point, times):
    position, velocity = np.zeros((len(times), 3)), np.zeros((len(times), 3))
    sample_track(track, point, np.asarray(times, dtype=np.float64), position, velocity)
    return position, velocity


def polynomial(coefficients, t):
    """p(t) = Σ c_k t^k and p'(t), coefficients (K, 3)."""
    t = np.asarray(t)[:, None]
    value = sum(c * t ** k for k, c in enumerate(coefficients))
    slope = sum(k * c * t ** (k - 1) for k, c in enumerate(coefficients) if k)
    return value, slope


FIRST, INTERVAL, SAMPLES = 0.35, 0.125, 4
CUBICS = np.array([  # two points, each its own cubic: (point, power, xyz)
    [[0.1, -0.2, 0.3], [1.0, 0.5, -0.4], [-2.0, 0.3, 0.7], [0.6, -1.1, 0.2]],
    [[-0.4, 1.2, 0.0], [0.0, -0.7, 2.0], [1.5, 0.0, -0.3], [-0.9, 0.4, 0.8]],
])


@pytest.fixture(scope="module")
def track():
    """Two points sampled at 4 times from 0.35 s, 0.125 s apart, moving on their cubics."""
    times = FIRST + INTERVAL * np.arange(SAMPLES)
    samples = [polynomial(cubic, times) for cubic in CUBICS]
    track = KinematicTrack(len(CUBICS), SAMPLES, ti.f64)
    track.upload(FIRST, INTERVAL, np.stack([p for p, _ in samples], axis=1),
                 np.stack([v for _, v in samples], axis=1))
    return track


@pytest.mark.parametrize("point", [0, 1])
def test_hermite_track_reproduces_cubic_motion_and_its_velocity(track, point):
    """A cubic spline through cubic data with exact end slopes is the cubic itself."""
    times = np.linspace(FIRST, FIRST + INTERVAL * (SAMPLES - 1), 23)
    position, velocity = sampled(track, point, times)
    expected_position, expected_velocity = polynomial(CUBICS[point], times)
    np.testing.assert_allclose(position, expected_position, atol=1e-13)
    np.testing.assert_allclose(velocity, expected_velocity, atol=1e-12)


def test_hermite_track_is_not_exact_for_a_quartic():
    """The test above could not pass by accident: t⁴ is beyond a cubic spline (its error is
    Δ⁴/384 · p'''' at a midpoint)."""
    quartic = np.zeros((5, 3))
    quartic[4] = 1.0
    times = FIRST + INTERVAL * np.arange(SAMPLES)
    position, velocity = polynomial(quartic, times)
    track = KinematicTrack(1, SAMPLES, ti.f64)
    track.upload(FIRST, INTERVAL, position[:, None, :], velocity[:, None, :])
    midpoint = FIRST + 0.5 * INTERVAL
    got, _ = sampled(track, 0, [midpoint])
    expected, _ = polynomial(quartic, [midpoint])
    assert expected[0, 0] - got[0, 0] == pytest.approx((INTERVAL / 2) ** 4, rel=1e-9)


@pytest.mark.parametrize("point", [0, 1])
def test_times_outside_the_span_clamp_to_its_ends(track, point):
    last = FIRST + INTERVAL * (SAMPLES - 1)
    ends_position, ends_velocity = polynomial(CUBICS[point], [FIRST, last])
    position, velocity = sampled(track, point, [FIRST - 10.0, FIRST - 1e-9])
    np.testing.assert_allclose(position, np.broadcast_to(ends_position[0], (2, 3)), atol=1e-8)
    np.testing.assert_allclose(velocity, np.broadcast_to(ends_velocity[0], (2, 3)), atol=1e-7)
    position, velocity = sampled(track, point, [last + 1e-9, last + 3.0])
    np.testing.assert_allclose(position, np.broadcast_to(ends_position[1], (2, 3)), atol=1e-8)
    np.testing.assert_allclose(velocity, np.broadcast_to(ends_velocity[1], (2, 3)), atol=1e-7)
    far, _ = sampled(track, point, [FIRST - 10.0, last + 3.0])
    at_ends, _ = sampled(track, point, [FIRST, last])
    np.testing.assert_array_equal(far, at_ends)  # exactly the end samples, however far out


def test_hold_keeps_points_still_at_every_time():
    rest = np.array([[0.3, 1.1, -0.2], [-0.5, 0.0, 0.9]])
    track = KinematicTrack(2, 3, ti.f64)
    track.hold(rest)
    for point in range(2):
        position, velocity = sampled(track, point, [-1.0, 0.0, 0.37, 1.5, 2.0, 50.0])
        # the Hermite weights h00 + h01 sum to 1 up to rounding: a held point wobbles 1 ulp
        np.testing.assert_allclose(position, np.broadcast_to(rest[point], position.shape),
                                   rtol=0, atol=2e-16)
        np.testing.assert_array_equal(velocity, 0.0)


@pytest.mark.parametrize("precision", [ti.f64, ti.f32])
def test_control_holds_pins_at_rest_and_marks_free_particles(precision):
    rng = np.random.default_rng(4)
    rest = rng.uniform(-1.0, 1.0, (12, 3))
    pinned = np.zeros(12, dtype=bool)
    pinned[[0, 3, 4, 11]] = True
    control = Control(pinned, rest, precision)
    control.upload()
    slot = control.pin_slot.to_numpy()
    np.testing.assert_array_equal(slot[~pinned], -1)
    assert sorted(slot[pinned].tolist()) == list(range(4))  # one track point each
    particles = np.flatnonzero(pinned).astype(np.int32)
    tolerance = 2e-16 if precision == ti.f64 else 1e-7
    for t in (0.0, 0.4, 7.0):
        position, velocity = np.zeros((4, 3)), np.zeros((4, 3))
        sample_pins(control, particles, t, position, velocity)
        np.testing.assert_allclose(position, rest[pinned], rtol=0, atol=tolerance)
        np.testing.assert_array_equal(velocity, 0.0)


def test_control_without_pins_or_capsules_has_no_slots_and_no_capsule_track():
    control = Control(np.zeros(5, dtype=bool), np.zeros((5, 3)), ti.f64)
    control.upload()
    np.testing.assert_array_equal(control.pin_slot.to_numpy(), -1)
    assert control.capsule_track is None and control.capsule_count == 0
