"""Cloth contact with the body's capsules and the ground: penalty forces with friction.

Seed §2.6: bones are capsules (a segment a–b and a radius r), particles are points, and a point
inside a capsule is pushed out by a spring on its penetration (the penalty method, §2.6.2).
Point vs capsule (§2.6.3, ORACLES.md): s = clamp(((x − a)·(b − a)) / |b − a|², 0, 1),
y = a + s·(b − a), distance |x − y| − r; s strictly inside (0, 1) is the cylinder, s = 0 or 1 a
hemispherical cap, and a = b a sphere.

The contact force is part of the shared force evaluation (so RK4 stages and the implicit solve see
it). With depth d = r + margin − |x − y| > 0, normal n = (x − y)/|x − y|, particle mass m, and the
relative velocity u = v − v_surface:

    f_n = m·(k̂·d − 2ζ·√k̂·(u·n)), clamped at 0 (contact pushes, never pulls)
    f_t = −min(μ·f_n, 2·m·√k̂·|u_t|) · u_t/|u_t|     (Coulomb, regularised for small slip)

k̂ [1/s²] is a stiffness per unit mass, so a contact's frequency √k̂ does not depend on the cloth's
resolution, ζ the damping ratio of that normal spring, μ the friction coefficient. The surface
velocity of a capsule is interpolated along its axis from the endpoint velocities.
"""

import numpy as np
import taichi as ti

from .kinematics import KinematicTrack
from .scene import CollisionEffect, GroundEffect


def closest_points_numpy(x: np.ndarray, a: np.ndarray, b: np.ndarray):
    """For points x (N,3) and segments a, b (C,3): segment parameter s (N,C), closest points
    y (N,C,3) and distances |x − y| (N,C). A degenerate segment (a = b) gives s = 0."""
    axis = b - a
    length_sq = np.einsum("ck,ck->c", axis, axis)
    offset = x[:, None, :] - a[None, :, :]
    safe = np.where(length_sq > 0, length_sq, 1.0)
    s = np.clip(np.einsum("nck,ck->nc", offset, axis) / safe, 0.0, 1.0)
    s = np.where(length_sq > 0, s, 0.0)
    closest = a[None] + s[..., None] * axis[None]
    return s, closest, np.linalg.norm(x[:, None, :] - closest, axis=-1)


def max_capsule_penetration(x: np.ndarray, a: np.ndarray, b: np.ndarray,
                            radius: np.ndarray) -> float:
    """Deepest point inside any capsule [m] (0 when none is inside)."""
    _, _, distance = closest_points_numpy(x, a, b)
    return float(max(0.0, np.max(radius[None, :] - distance)))


@ti.func
def penalty_force(mass, depth, normal, relative_velocity, stiffness, damping_ratio, friction):
    """Normal penalty spring and dashpot plus regularised Coulomb friction (module docstring)."""
    root_stiffness = ti.sqrt(stiffness)
    normal_speed = relative_velocity.dot(normal)
    normal_magnitude = ti.max(mass * (stiffness * depth
                                      - 2 * damping_ratio * root_stiffness * normal_speed), 0.0)
    force = normal_magnitude * normal
    slip = relative_velocity - normal_speed * normal
    slip_speed = slip.norm()
    if slip_speed > 0:
        friction_magnitude = ti.min(friction * normal_magnitude,
                                    2 * mass * root_stiffness * slip_speed)
        force -= friction_magnitude / slip_speed * slip
    return force


@ti.func
def closest_on_segment(x, a, b):
    """Parameter s ∈ [0, 1] of the point of segment a–b closest to x (s = 0 when a = b)."""
    axis = b - a
    return ti.min(ti.max((x - a).dot(axis) / ti.max(axis.dot(axis), 1e-30), 0.0), 1.0)


@ti.data_oriented
class CapsuleContact:
    """Penalty contact of every particle against the body's capsules.

    Capsule c has endpoints ``track`` points 2c (a) and 2c + 1 (b) and radius
    ``capsule_radius[c]`` [m]; ``margin`` [m] is the cloth's thickness kept off the surface.
    A particle first tests the capsule's bounding sphere (centre (a + b)/2, radius |b − a|/2 + r +
    margin); only particles inside it pay for the exact closest-point test.
    """

    name = "collision"

    def __init__(self, config: CollisionEffect, capsule_radius: np.ndarray, track: KinematicTrack,
                 model):
        self.stiffness, self.damping_ratio = config.stiffness, config.damping
        self.friction, self.margin = config.friction, config.thickness
        self.capsule_count = len(capsule_radius)
        self.track = track
        self.model = model
        self.capsule_radius = ti.field(model.real, self.capsule_count)
        self.capsule_radius.from_numpy(np.asarray(capsule_radius, dtype=track.numpy_real))

    @ti.func
    def capsule_at(self, i_c, t):
        a, velocity_a = self.track.at(2 * i_c, t)
        b, velocity_b = self.track.at(2 * i_c + 1, t)
        return a, b, velocity_a, velocity_b

    @ti.func
    def force(self, model, x, v, i_p, t):
        real = model.real
        f = ti.Vector.zero(real, 3)
        position = x[i_p]
        margin = real(self.margin)
        for i_c in range(self.capsule_count):
            a, b, velocity_a, velocity_b = self.capsule_at(i_c, t)
            radius = self.capsule_radius[i_c] + margin
            reach = 0.5 * (b - a).norm() + radius
            if (position - 0.5 * (a + b)).norm_sqr() < reach * reach:
                s = closest_on_segment(position, a, b)
                offset = position - (a + s * (b - a))
                distance = offset.norm()
                depth = radius - distance
                if depth > 0 and distance > 0:
                    surface_velocity = velocity_a + s * (velocity_b - velocity_a)
                    f += penalty_force(model.particle_mass[i_p], depth, offset / distance,
                                       v[i_p] - surface_velocity, real(self.stiffness),
                                       real(self.damping_ratio), real(self.friction))
        return f

    @ti.func
    def apply(self, state, t):
        """The projection pass after a step (``penalty+projection``): a free particle still
        inside a capsule moves to its surface (plus margin) and loses its inward velocity
        relative to the surface."""
        model = self.model
        x, v = ti.static(state.x, state.v)
        margin = model.real(self.margin)
        for i_p in x:
            if model.particle_inv_mass[i_p] > 0:
                for i_c in range(self.capsule_count):
                    a, b, velocity_a, velocity_b = self.capsule_at(i_c, t)
                    s = closest_on_segment(x[i_p], a, b)
                    offset = x[i_p] - (a + s * (b - a))
                    distance = offset.norm()
                    radius = self.capsule_radius[i_c] + margin
                    if distance < radius and distance > 0:
                        normal = offset / distance
                        x[i_p] += (radius - distance) * normal
                        surface_velocity = velocity_a + s * (velocity_b - velocity_a)
                        inward = (v[i_p] - surface_velocity).dot(normal)
                        if inward < 0:
                            v[i_p] -= inward * normal


@ti.data_oriented
class GroundContact:
    """Penalty contact with the plane y = height (plus margin), at rest."""

    name = "ground"

    def __init__(self, config: GroundEffect):
        self.surface_height = config.height + config.thickness
        self.stiffness, self.damping_ratio = config.stiffness, config.damping
        self.friction = config.friction

    @ti.func
    def force(self, model, x, v, i_p, t):
        real = model.real
        depth = real(self.surface_height) - x[i_p][1]
        f = ti.Vector.zero(real, 3)
        if depth > 0:
            f = penalty_force(model.particle_mass[i_p], depth, ti.Vector([0.0, 1.0, 0.0], dt=real),
                              v[i_p], real(self.stiffness), real(self.damping_ratio),
                              real(self.friction))
        return f
