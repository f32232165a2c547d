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

from taichi_cloth.physics.control import KinematicTrack
from taichi_cloth.config.scene import CollisionEffect, GroundEffect


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
def normal_force_magnitude(mass, depth, normal_speed, stiffness, damping_ratio):
    """m·(k̂·d − 2ζ·√k̂·(u·n)), clamped at 0: contact pushes, never pulls [N]."""
    return ti.max(mass * (stiffness * depth - 2 * damping_ratio * ti.sqrt(stiffness) * normal_speed),
                  0.0)


@ti.func
def friction_viscosity(mass, normal_magnitude, slip_speed, stiffness, friction):
    """Regularised Coulomb friction as a viscous coefficient c_t [N·s/m], f_t = −c_t·u_t:
    c_t = min(μ·f_n, 2·m·√k̂·|u_t|) / |u_t| (2·m·√k̂ at zero slip)."""
    limit = 2 * mass * ti.sqrt(stiffness)
    return ti.min(friction * normal_magnitude / ti.max(slip_speed, 1e-30), limit)


@ti.func
def penalty_force(mass, depth, normal, relative_velocity, stiffness, damping_ratio, friction):
    """Normal penalty spring and dashpot plus regularised Coulomb friction (module docstring)."""
    normal_speed = relative_velocity.dot(normal)
    normal_magnitude = normal_force_magnitude(mass, depth, normal_speed, stiffness, damping_ratio)
    slip = relative_velocity - normal_speed * normal
    viscosity = friction_viscosity(mass, normal_magnitude, slip.norm(), stiffness, friction)
    return normal_magnitude * normal - viscosity * slip


@ti.func
def penalty_damping_block(mass, depth, normal, relative_velocity, stiffness, damping_ratio,
                          friction, real: ti.template()):
    """∂f/∂v of ``penalty_force`` with the friction coefficient frozen at the current slip:
    −2ζ·m·√k̂·n·nᵀ − c_t·(I − n·nᵀ). Friction then acts implicitly like a damper (an explicit
    friction of stiffness 2·m·√k̂ would overshoot at large steps); negative semi-definite."""
    normal_speed = relative_velocity.dot(normal)
    normal_magnitude = normal_force_magnitude(mass, depth, normal_speed, stiffness, damping_ratio)
    slip = relative_velocity - normal_speed * normal
    viscosity = friction_viscosity(mass, normal_magnitude, slip.norm(), stiffness, friction)
    outer = normal.outer_product(normal)
    identity = ti.Matrix.identity(real, 3)
    return -2 * damping_ratio * mass * ti.sqrt(stiffness) * outer - viscosity * (identity - outer)


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
    ``prepare`` poses the capsules once per force evaluation; a particle then first tests each
    capsule's bounding sphere (centre (a + b)/2, radius |b − a|/2 + r + margin), and only
    particles inside it pay for the exact closest-point test.
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
        # The pose at the time of the last ``prepare`` [m, m/s]; the bounding sphere [m, m²].
        self.capsule_a = ti.Vector.field(3, model.real, self.capsule_count)
        self.capsule_b = ti.Vector.field(3, model.real, self.capsule_count)
        self.capsule_velocity_a = ti.Vector.field(3, model.real, self.capsule_count)
        self.capsule_velocity_b = ti.Vector.field(3, model.real, self.capsule_count)
        self.capsule_center = ti.Vector.field(3, model.real, self.capsule_count)
        self.capsule_reach_sq = ti.field(model.real, self.capsule_count)
        # filled after every allocation: one SNode tree (model.py)
        self.capsule_radius.from_numpy(np.asarray(capsule_radius, dtype=track.numpy_real))

    has_local_jacobian = True

    @ti.func
    def prepare(self, t):
        """Pose every capsule at time t [s] once, before the particle loops: endpoints a, b and
        their velocities from the track (two Hermite evaluations per capsule instead of four per
        particle and capsule), and the bounding sphere of ``near``."""
        real = self.model.real
        for i_c in range(self.capsule_count):
            a, velocity_a = self.track.at(2 * i_c, t)
            b, velocity_b = self.track.at(2 * i_c + 1, t)
            self.capsule_a[i_c], self.capsule_b[i_c] = a, b
            self.capsule_velocity_a[i_c], self.capsule_velocity_b[i_c] = velocity_a, velocity_b
            self.capsule_center[i_c] = 0.5 * (a + b)
            reach = 0.5 * (b - a).norm() + self.capsule_radius[i_c] + real(self.margin)
            self.capsule_reach_sq[i_c] = reach * reach

    @ti.func
    def probe(self, i_c, position):
        """Capsule i_c as ``prepare`` posed it, seen from ``position``: (depth inside radius +
        margin [m], unit normal out of the capsule, distance to the axis [m], segment parameter
        s, unit axis, surface velocity at the closest point [m/s])."""
        a, b = self.capsule_a[i_c], self.capsule_b[i_c]
        velocity_a, velocity_b = self.capsule_velocity_a[i_c], self.capsule_velocity_b[i_c]
        radius = self.capsule_radius[i_c] + self.model.real(self.margin)
        s = closest_on_segment(position, a, b)
        offset = position - (a + s * (b - a))
        distance = offset.norm()
        normal = offset / ti.max(distance, 1e-30)
        axis = (b - a) / ti.max((b - a).norm(), 1e-30)
        surface_velocity = velocity_a + s * (velocity_b - velocity_a)
        return radius - distance, normal, distance, s, axis, surface_velocity

    @ti.func
    def near(self, i_c, position):
        """Cheap bound: is ``position`` inside capsule i_c's bounding sphere (centre (a + b)/2,
        radius |b − a|/2 + r + margin)?"""
        return (position - self.capsule_center[i_c]).norm_sqr() < self.capsule_reach_sq[i_c]

    @ti.func
    def force(self, model, x, v, i_p, t):
        real = model.real
        f = ti.Vector.zero(real, 3)
        for i_c in range(self.capsule_count):
            if self.near(i_c, x[i_p]):
                depth, normal, distance, _, _, surface_velocity = self.probe(i_c, x[i_p])
                if depth > 0 and distance > 0:
                    f += penalty_force(model.particle_mass[i_p], depth, normal,
                                       v[i_p] - surface_velocity, real(self.stiffness),
                                       real(self.damping_ratio), real(self.friction))
        return f

    @ti.func
    def local_jacobian(self, model, x, v, i_p, t, definite: ti.template()):
        """(∂f/∂x, ∂f/∂v) of the penalty on particle i_p:
        ∂f/∂x = m·k̂·[−n·nᵀ + (d/|x − y|)·P], P = I − n·nᵀ (− â·âᵀ on the cylinder part), friction
        left out; ∂f/∂v from ``penalty_damping_block``. The curvature term d/|x − y|·P is
        positive; ``definite`` drops it. A contact whose normal force is clamped to 0 (the
        particle leaving fast) exerts nothing and adds nothing: its blocks would make release
        sticky."""
        real = model.real
        stiffness_block = ti.Matrix.zero(real, 3, 3)
        damping_block = ti.Matrix.zero(real, 3, 3)
        mass = model.particle_mass[i_p]
        identity = ti.Matrix.identity(real, 3)
        for i_c in range(self.capsule_count):
            if self.near(i_c, x[i_p]):
                depth, normal, distance, s, axis, surface_velocity = self.probe(i_c, x[i_p])
                relative_velocity = v[i_p] - surface_velocity
                if depth > 0 and distance > 0 and normal_force_magnitude(
                        mass, depth, relative_velocity.dot(normal), real(self.stiffness),
                        real(self.damping_ratio)) > 0:
                    outer = normal.outer_product(normal)
                    stiffness_block -= mass * real(self.stiffness) * outer
                    damping_block += penalty_damping_block(
                        mass, depth, normal, relative_velocity, real(self.stiffness),
                        real(self.damping_ratio), real(self.friction), real)
                    if ti.static(not definite):
                        tangent = identity - outer
                        if 0 < s < 1:
                            tangent -= axis.outer_product(axis)
                        stiffness_block += mass * real(self.stiffness) * depth / distance * tangent
        return stiffness_block, damping_block

    @ti.func
    def apply(self, state, t):
        """The projection pass after a step (``penalty+projection``): a free particle still
        inside a capsule at time t moves to its surface (plus margin) and loses its inward
        velocity relative to the surface."""
        model = self.model
        x, v = ti.static(state.x, state.v)
        self.prepare(t)
        for i_p in range(model.particle_count):
            if model.particle_inv_mass[i_p] > 0:
                for i_c in range(self.capsule_count):
                    depth, normal, distance, _, _, surface_velocity = self.probe(i_c, x[i_p])
                    if depth > 0 and distance > 0:
                        x[i_p] += depth * normal
                        inward = (v[i_p] - surface_velocity).dot(normal)
                        if inward < 0:
                            v[i_p] -= inward * normal


@ti.data_oriented
class GroundContact:
    """Penalty contact with the plane y = height (plus margin), at rest."""

    name = "ground"

    has_local_jacobian = True

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

    @ti.func
    def local_jacobian(self, model, x, v, i_p, t, definite: ti.template()):
        """(∂f/∂x, ∂f/∂v) of the penalty: −m·k̂·e_y·e_yᵀ (exact for a plane, so ``definite``
        changes nothing) and ``penalty_damping_block``; nothing while the normal force is
        clamped to 0."""
        real = model.real
        stiffness_block = ti.Matrix.zero(real, 3, 3)
        damping_block = ti.Matrix.zero(real, 3, 3)
        depth = real(self.surface_height) - x[i_p][1]
        mass = model.particle_mass[i_p]
        if depth > 0 and normal_force_magnitude(mass, depth, v[i_p][1], real(self.stiffness),
                                                real(self.damping_ratio)) > 0:
            stiffness_block[1, 1] = -mass * real(self.stiffness)
            damping_block = penalty_damping_block(
                mass, depth, ti.Vector([0.0, 1.0, 0.0], dt=real), v[i_p], real(self.stiffness),
                real(self.damping_ratio), real(self.friction), real)
        return stiffness_block, damping_block
