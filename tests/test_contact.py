"""Point–capsule contact (seed §2.6.3) against a NumPy reference, and the penalty/friction law."""

import numpy as np
import pytest
import taichi as ti

from taichi_cloth.effects.collision import CapsuleContact, CollisionSettings
from taichi_cloth.effects.penalty import (capsule_penetration_depths, closest_on_segment,
                                          closest_points_numpy)
from taichi_cloth.physics.model import Model

from systems import assemble, one_spring_garment


def brute_force_distance(x, a, b, samples=20001):
    """Distance from x to segment a–b by dense sampling: no clamping formula involved."""
    s = np.linspace(0.0, 1.0, samples)
    points = a[None] + s[:, None] * (b - a)[None]
    return np.linalg.norm(points - x[None], axis=1).min()


@ti.kernel
def segment_distance_kernel(x: ti.types.ndarray(), a: ti.types.ndarray(), b: ti.types.ndarray(),
                            out: ti.types.ndarray()):
    for i in range(x.shape[0]):
        p = ti.Vector([x[i, 0], x[i, 1], x[i, 2]], dt=ti.f64)
        pa = ti.Vector([a[0], a[1], a[2]], dt=ti.f64)
        pb = ti.Vector([b[0], b[1], b[2]], dt=ti.f64)
        s = closest_on_segment(p, pa, pb)
        out[i] = (p - (pa + s * (pb - pa))).norm()


@pytest.mark.parametrize("a, b", [
    ((0.0, 0.0, 0.0), (0.0, 0.4, 0.0)),      # vertical bone
    ((0.1, 0.9, 0.0), (-0.2, 0.5, 0.3)),    # oblique
    ((0.2, 0.3, 0.1), (0.2, 0.3, 0.1)),     # degenerate: a sphere
])
def test_point_to_segment_distance_matches_dense_sampling(a, b):
    a, b = np.array(a), np.array(b)
    rng = np.random.default_rng(3)
    centre = 0.5 * (a + b)
    x = np.concatenate([
        centre + 0.3 * rng.standard_normal((60, 3)),            # anywhere around
        a + 0.05 * rng.standard_normal((20, 3)),                # near cap a
        b + 0.05 * rng.standard_normal((20, 3)),                # near cap b
        a + np.linspace(-0.5, 1.5, 21)[:, None] * (b - a),      # on the axis, beyond both ends
    ])
    kernel_distance = np.zeros(len(x))
    segment_distance_kernel(x, a, b, kernel_distance)
    _, _, numpy_distance = closest_points_numpy(x, a[None], b[None])
    reference = np.array([brute_force_distance(p, a, b) for p in x])
    tolerance = 1e-4 * max(np.linalg.norm(b - a), 1e-3)
    np.testing.assert_allclose(kernel_distance, reference, atol=tolerance)
    np.testing.assert_allclose(numpy_distance[:, 0], reference, atol=tolerance)


def test_penetration_depths_take_the_deepest_capsule_by_dense_sampling():
    """The penetration metric (a kernel that skips the capsules whose bounding sphere a point is
    outside) against the depth r − |x − y| taken by dense sampling of every capsule: three bones
    that overlap, one of them a sphere (a = b), points around and inside them, some exactly on a
    bounding sphere."""
    a = np.array([[0.0, 0.0, 0.0], [0.05, 0.3, 0.0], [0.2, 0.1, 0.1]])
    b = np.array([[0.0, 0.4, 0.0], [0.3, 0.45, 0.1], [0.2, 0.1, 0.1]])
    radius = np.array([0.08, 0.05, 0.12])
    rng = np.random.default_rng(7)
    centre, reach = 0.5 * (a + b), 0.5 * np.linalg.norm(b - a, axis=1) + radius
    direction = rng.standard_normal((30, 3))
    on_spheres = centre[1] + reach[1] * direction / np.linalg.norm(direction, axis=1)[:, None]
    along = [a_c + rng.uniform(-0.2, 1.2, (100, 1)) * (b_c - a_c)
             + 0.08 * rng.standard_normal((100, 3)) for a_c, b_c in zip(a, b)]
    x = np.concatenate([*along, on_spheres])
    reference = np.maximum(0.0, np.max(
        [r - np.array([brute_force_distance(p, a_c, b_c) for p in x])
         for a_c, b_c, r in zip(a, b, radius)], axis=0))
    depth = capsule_penetration_depths(x, a, b, radius)
    assert np.count_nonzero(reference > 1e-3) > 100  # many points inside
    np.testing.assert_allclose(depth, reference, atol=1e-4 * 0.4)


class OneCapsule:
    """Particle 1 of a zero-stiffness spring system against one capsule moving at a set velocity."""

    def __init__(self, friction=0.4):
        garment = one_spring_garment(omega=0.0)
        self.model = Model(garment, "f64", None)
        self.radius = 0.1
        self.config = CollisionSettings(stiffness=1e4, damping=0.3, friction=friction,
                                        thickness=0.0, surface=False)  # the particle alone
        physics = assemble(self.model, [(CapsuleContact, self.config)],
                           capsule_radius=[self.radius])
        self.track = physics.control.capsule_track
        self.contact, self.forces = physics.effects[0], physics.forces
        self.state = self.model.state()
        self.out = ti.Vector.field(3, ti.f64, self.model.particle_count)

    def force_at(self, position, velocity, surface_velocity=(0.0, 0.0, 0.0)):
        """Capsule along z through (0.5, 0, 0); the particle at ``position``."""
        a, b = np.array([0.5, 0.0, -0.3]), np.array([0.5, 0.0, 0.3])
        surface = np.array(surface_velocity)
        self.track.upload(0.0, 1.0, np.array([[a, b], [a + surface, b + surface]]),
                          np.array([[surface, surface], [surface, surface]]))
        x = self.model.garment.positions.copy()
        v = np.zeros_like(x)
        x[1], v[1] = position, velocity
        self.state.x.from_numpy(x)
        self.state.v.from_numpy(v)
        self.forces.evaluate(self.state.x, self.state.v, 0.0, self.out)
        return self.out.to_numpy()[1]


@pytest.fixture(scope="module")
def capsule():
    return OneCapsule()


def test_penalty_force_points_out_and_grows_with_depth(capsule):
    direction = np.array([1.0, 1.0, 0.0]) / np.sqrt(2)
    previous = 0.0
    for depth in (0.001, 0.01, 0.03, 0.06):
        position = np.array([0.5, 0.0, 0.1]) + (capsule.radius - depth) * direction
        force = capsule.force_at(position, np.zeros(3))
        magnitude = np.linalg.norm(force)
        assert magnitude > previous
        np.testing.assert_allclose(force / magnitude, direction, atol=1e-12)  # straight out
        assert magnitude == pytest.approx(1.0 * 1e4 * depth, rel=1e-12)  # m·k̂·d, at rest
        previous = magnitude
    outside = np.array([0.5, 0.0, 0.0]) + 1.01 * capsule.radius * direction
    np.testing.assert_array_equal(capsule.force_at(outside, np.zeros(3)), 0.0)
    on_cap = np.array([0.5, 0.0, 0.3 + capsule.radius - 0.01])  # beyond b: the hemisphere
    force = capsule.force_at(on_cap, np.zeros(3))
    np.testing.assert_allclose(force, [0.0, 0.0, 1e4 * 0.01], atol=1e-9)


@pytest.mark.parametrize("surface_velocity", [(0.0, 0.0, 0.0), (0.0, 0.0, 0.8), (0.0, 0.0, -2.0)])
def test_friction_is_bounded_and_opposes_sliding_on_the_moving_surface(capsule, surface_velocity):
    position = np.array([0.5 + capsule.radius - 0.02, 0.0, 0.0])  # 2 cm deep on the +x side
    surface = np.array(surface_velocity)
    for slip in ([0.0, 0.0, 0.5], [0.0, -0.3, 0.1], [0.0, 1e-4, 0.0]):
        velocity = surface + np.array(slip)  # sliding tangentially relative to the surface
        force = capsule.force_at(position, velocity, surface_velocity)
        normal_force, tangential = force[0], force[1:]
        assert normal_force == pytest.approx(1e4 * 0.02)
        slip_direction = np.array(slip[1:]) / np.linalg.norm(slip[1:])
        # |f_t| = min(μ·f_n, 2·m·√k̂·|u_t|): Coulomb's bound, or the viscous regularisation at
        # small slip (m = 1 kg, k̂ = 1e4 1/s²)
        expected = min(0.4 * normal_force, 2 * 1.0 * 100.0 * np.linalg.norm(slip[1:]))
        assert np.linalg.norm(tangential) == pytest.approx(expected, rel=1e-12)
        assert np.dot(tangential, slip_direction) < 0  # opposes the slip
        np.testing.assert_allclose(np.cross(np.r_[0, tangential], np.r_[0, slip_direction]), 0,
                                   atol=1e-12)
