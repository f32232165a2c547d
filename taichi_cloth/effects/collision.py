"""Contact with the body's capsules (seed §2.6): the penalty force of ``penalty`` against every
bone capsule, posed once per force evaluation from the prescribed motion (``physics.control``)."""

from dataclasses import dataclass

import numpy as np
import taichi as ti

from taichi_cloth.effects.base import Effect, EffectContext
from taichi_cloth.effects.penalty import (closest_on_segment, max_capsule_penetration,
                                          normal_force_magnitude, penalty_damping_block,
                                          penalty_force)
from taichi_cloth.settings import setting


@dataclass(frozen=True)
class CollisionSettings:
    stiffness: float = setting(1e5, "float", low=0.0, low_inclusive=False,
                               doc="penalty stiffness per unit particle mass, 1/s²")
    damping: float = setting(0.1, "float", low=0.0, doc="normal damping ratio ζ")
    friction: float = setting(0.3, "float", low=0.0, doc="Coulomb coefficient μ")
    thickness: float = setting(0.005, "float", low=0.0, doc="contact margin around capsules, m")
    mode: str = setting("penalty", "str", choices=("penalty", "penalty+projection"))


@ti.data_oriented
class CapsuleContact(Effect):
    """Penalty contact of every particle against the body's capsules.

    Capsule c has endpoints ``control.capsule_track`` points 2c (a) and 2c + 1 (b) and radius
    ``control.capsule_radius[c]`` [m]; ``margin`` [m] is the cloth's thickness kept off the surface.
    ``prepare`` poses the capsules once per force evaluation; a particle then first tests each
    capsule's bounding sphere (centre (a + b)/2, radius |b − a|/2 + r + margin), and only
    particles inside it pay for the exact closest-point test.
    """

    name = "collision"
    Settings = CollisionSettings
    has_jacobian = True
    needs_body = True

    def __init__(self, settings: CollisionSettings, context: EffectContext):
        super().__init__(settings, context)
        config, model, control = settings, context.model, context.control
        capsule_radius, track = control.capsule_radius, control.capsule_track
        self.control = control
        self.post_step = self if settings.mode == "penalty+projection" else None
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
        self._host_radius = np.asarray(capsule_radius, dtype=track.numpy_real)

    def upload(self) -> None:
        """The capsule radii into their field (after every allocation: one SNode tree)."""
        self.capsule_radius.from_numpy(self._host_radius)

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

    def stability_modes(self) -> list[tuple[float, float]]:
        return [(self.stiffness, self.damping_ratio)]

    def max_penetration(self, x: np.ndarray) -> float:
        """Metres inside any capsule (without the margin) at the end of the frame."""
        a, b = self.control.capsule_ends_at_frame_end
        return max_capsule_penetration(x, a, b, self.control.capsule_radius)
