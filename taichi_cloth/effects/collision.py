"""Contact with the body's capsules (seed §2.6): the penalty force of ``penalty`` against every
bone capsule, posed once per force evaluation from the prescribed motion (``physics.control``).

Contact on the whole surface (``surface = true``, the default): a capsule thinner than the
particle spacing (a leg between the particles of a coarse skirt, a bar under a drape) passes
between particles that alone feel contact. Every edge midpoint and triangle centroid is then a
contact sample too, a point p = Σ_a w_a·x_a of its 2 or 3 particles (w = ½ or ⅓), with velocity
Σ w_a·v_a and mass m_s = Σ w_a·m_a. Its penalty energy E_s(p) gives each of its particles the
force w_a·F_s (∂p/∂x_a = w_a·I), so momentum and the energy balance hold. A pass per force
evaluation (``prepare``) computes F_s into a field for every sample that may touch a capsule
(stamped with the evaluation's number; the others' F_s = 0 is not stored); each particle then
gathers its own share over its samples stamped now (``gather.incidence_lists``, a fixed
order). For the implicit solver each particle's block keeps w_a²·∂F_s/∂p of its samples and
drops the couplings between the particles of a sample (a documented approximation: the Newton
step stays a descent step, the contact stiffness on the diagonal is exact). With samples, a
particle feels the contact stiffness of its own and of its samples: Gershgorin bounds the mode
by k̂·(1 + Σ w_a·m_s/m_a), which ``stability_modes`` reports for ``dt = "auto"``."""

from dataclasses import dataclass

import numpy as np
import taichi as ti

from taichi_cloth.effects.base import Effect, EffectContext
from taichi_cloth.effects.near_masks import NearMasks
from taichi_cloth.effects.penalty import (PenaltySettings, capsule_penetration_depths,
                                          closest_on_segment, penalty_blocks, penalty_force)
from taichi_cloth.gather import incidence_lists
from taichi_cloth.settings import setting



@dataclass(frozen=True)
class CollisionSettings(PenaltySettings):
    friction: float = setting(0.3, "float", low=0.0, doc="Coulomb coefficient μ")
    mode: str = setting("penalty", "str", choices=("penalty", "penalty+projection"))
    surface: bool = setting(True, "bool", doc="edge midpoints and triangle centroids feel "
                                              "contact too (module docstring)")


@ti.data_oriented
class CapsuleContact(NearMasks, Effect):
    """Penalty contact of every particle against the body's capsules.

    Capsule c has endpoints ``control.capsule_track`` points 2c (a) and 2c + 1 (b) and radius
    ``control.capsule_radius[c]`` [m]; ``margin`` [m] is the cloth's thickness kept off the surface.
    ``prepare`` poses the capsules once per force evaluation; a particle then first tests each
    capsule's bounding sphere (centre (a + b)/2, radius |b − a|/2 + r + margin), and only
    particles inside it pay for the exact closest-point test. With surface samples, the
    near-masks of ``NearMasks`` say which capsules a particle or a sample may touch.
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
        # Stored component by component (SoA): a point's loop over the capsules, which LLVM
        # vectorises across capsules, then loads each component of 8 capsules at once instead
        # of gathering it (docs/performance.md, "The capsules stored component by component")
        (self.capsule_a, self.capsule_b, self.capsule_velocity_a, self.capsule_velocity_b,
         self.capsule_center) = [ti.Vector.field(3, model.real, self.capsule_count,
                                                 layout=ti.Layout.SOA) for _ in range(5)]
        self.capsule_reach_sq = ti.field(model.real, self.capsule_count)
        self._host_radius = np.asarray(capsule_radius, dtype=track.numpy_real)
        self.surface = config.surface and len(model.garment.triangles) > 0
        self.stiffness_factor = 1.0
        self.masked = False  # near-masks (with surface samples and at most MASK_BITS capsules)
        if self.surface:
            self._allocate_samples(model)

    def _allocate_samples(self, model) -> None:
        """The surface samples (edge midpoints, then triangle centroids) as 3 particles and 3
        weights each (an edge repeats its first particle with weight 0), their force field, and
        each particle's CSR list of (sample, its weight there)."""
        triangles = model.garment.triangles
        edges = model.garment.edges
        corners = np.concatenate([np.column_stack([edges, edges[:, 0]]), triangles]).astype(np.int32)
        weights = np.concatenate([np.tile([0.5, 0.5, 0.0], (len(edges), 1)),
                                  np.full((len(triangles), 3), 1.0 / 3.0)])
        # an edge's third corner listed as a particle past the last, so that it sorts out
        listed = np.concatenate([np.column_stack([edges, np.full(len(edges), model.particle_count)]),
                                 triangles])
        start, item, slot = incidence_lists(listed, model.particle_count + 1)
        start = start[:model.particle_count + 1]
        item, slot = item[:start[-1]], slot[:start[-1]]
        mass = model.garment.mass
        sample_mass = np.einsum("sa,sa->s", weights, mass[corners])
        share = np.zeros(model.particle_count)
        np.add.at(share, corners.ravel(), (weights * sample_mass[:, None]).ravel())
        free = mass > 0
        self.stiffness_factor = float(np.max(1.0 + share[free] / mass[free])) if free.any() else 1.0
        self.sample_count = len(corners)
        rest = np.linalg.norm(np.diff(model.garment.positions[edges], axis=1), axis=2)
        self.allocate_masks(float(rest.max(initial=0.0)))
        real = model.real
        self.sample_corners = ti.Vector.field(3, ti.i32, self.sample_count)
        self.sample_weights = ti.Vector.field(3, real, self.sample_count)
        self.sample_mass = ti.field(real, self.sample_count)
        self.sample_force = ti.Vector.field(3, real, self.sample_count)
        # the evaluation (``NearMasks.evaluation``) that last stored the sample's force
        self.sample_evaluation = ti.field(ti.i32, self.sample_count)
        self.particle_sample_start = ti.field(ti.i32, model.particle_count + 1)
        self.particle_sample = ti.field(ti.i32, max(1, len(item)))
        self.particle_sample_weight = ti.field(real, max(1, len(item)))  # w_a of the entry
        self._sample_tables = (corners, weights, sample_mass, start, item, weights[item, slot])

    def upload(self) -> None:
        """The capsule radii (and the surface samples), into the model's ``uploads``."""
        pairs = [(self.capsule_radius, self._host_radius)]
        if self.surface:
            real = self.model.numpy_real
            corners, weights, sample_mass, start, item, item_weight = self._sample_tables
            pairs += [*self.mask_uploads(),
                      (self.sample_corners, corners),
                      (self.sample_weights, weights.astype(real)),
                      (self.sample_mass, sample_mass.astype(real)),
                      (self.particle_sample_start, start), (self.particle_sample, item),
                      (self.particle_sample_weight, item_weight.astype(real))]
        self.model.uploads.add(pairs)

    @ti.func
    def prepare(self, x, v, t):
        """Pose every capsule at time t [s] once, before the particle loops: endpoints a, b and
        their velocities from the track (two Hermite evaluations per capsule instead of four per
        particle and capsule), and the bounding sphere of ``near``; then with ``surface`` every
        sample's contact force at (x, v)."""
        self._pose(t)
        if ti.static(self.surface):
            if ti.static(self.masked):
                self._refresh_masks(x)
            self.evaluation[None] += 1  # (``NearMasks``)
            for i_s in range(self.sample_count):
                position, mask = self._sample_mask(x, i_s)
                if mask != 0:  # else F_s = 0, not stored: its readers find an older stamp
                    self.sample_force[i_s] = self._contact_force(
                        self.sample_mass[i_s], position, self._sample_point(v, i_s), mask)
                    self.sample_evaluation[i_s] = self.evaluation[None]
                    self._mark_touched(i_s)

    @ti.func
    def _sample_point(self, values, i_s):
        """Σ w_a·values_a over surface sample i_s's particles a."""
        corners, weights = self.sample_corners[i_s], self.sample_weights[i_s]
        point = ti.Vector.zero(self.model.real, 3)
        for a in ti.static(range(3)):
            point += weights[a] * values[corners[a]]
        return point

    @ti.func
    def _pose(self, t):
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
        s, offset = self._axis_offset(i_c, position)
        distance = offset.norm()
        normal = offset / ti.max(distance, 1e-30)
        axis = (b - a) / ti.max((b - a).norm(), 1e-30)
        surface_velocity = velocity_a + s * (velocity_b - velocity_a)
        return radius - distance, normal, distance, s, axis, surface_velocity

    @ti.func
    def _axis_offset(self, i_c, position):
        """(s, position − y [m]): y the point of capsule i_c's axis closest to ``position``."""
        a, b = self.capsule_a[i_c], self.capsule_b[i_c]
        s = closest_on_segment(position, a, b)
        return s, position - (a + s * (b - a))

    @ti.func
    def near(self, i_c, position):
        """Cheap bound: is ``position`` inside capsule i_c's bounding sphere (centre (a + b)/2,
        radius |b − a|/2 + r + margin)?"""
        return (position - self.capsule_center[i_c]).norm_sqr() < self.capsule_reach_sq[i_c]

    @ti.func
    def _contact_force(self, mass, position, velocity, mask):
        """The penalty force [N] on a point of ``mass`` at ``position`` with ``velocity``,
        summed over the capsules whose bit is set in ``mask`` (each first culled by its
        bounding sphere)."""
        real = self.model.real
        f = ti.Vector.zero(real, 3)
        i_c = self._next_capsule(0, mask)
        while i_c < self.capsule_count:
            if self.near(i_c, position):
                depth, normal, distance, _segment, _axis, surface_velocity = self.probe(
                    i_c, position)
                if depth > 0 and distance > 0:
                    f += penalty_force(mass, depth, normal, velocity - surface_velocity,
                                       real(self.stiffness), real(self.damping_ratio),
                                       real(self.friction))
            i_c = self._next_capsule(i_c + 1, mask)
        return f

    @ti.func
    def force(self, model, x, v, i_p, t):
        """The particle's own contact and, with ``surface``, w_a·F_s of each of its samples
        (none where no sample of it may touch a capsule at this evaluation: each F_s is 0)."""
        f = self._contact_force(model.particle_mass[i_p], x[i_p], v[i_p],
                                self._particle_mask(x, i_p))
        if ti.static(self.surface):
            if self._sample_may_touch(i_p):
                for k in range(self.particle_sample_start[i_p],
                               self.particle_sample_start[i_p + 1]):
                    i_s = self.particle_sample[k]
                    if self.sample_evaluation[i_s] == self.evaluation[None]:  # F_s stored now
                        f += self.particle_sample_weight[k] * self.sample_force[i_s]
        return f

    @ti.func
    def local_jacobian(self, model, x, v, i_p, t, definite: ti.template()):
        """(∂f/∂x, ∂f/∂v) of the penalty on particle i_p (``_contact_blocks``) plus, with
        ``surface``, w_a² times its samples' blocks (the couplings between a sample's particles
        left out: module docstring)."""
        stiffness_block, damping_block = self._contact_blocks(
            model.particle_mass[i_p], x[i_p], v[i_p], self._particle_mask(x, i_p), definite)
        if ti.static(self.surface):
            first, end = self.particle_sample_start[i_p], self.particle_sample_start[i_p + 1]
            if not self._sample_may_touch(i_p):
                end = first  # no sample of it may touch: none is walked
            for k in range(first, end):
                i_s = self.particle_sample[k]
                position, mask = self._sample_mask(x, i_s)
                if mask != 0:  # a sample that cannot touch a capsule has no blocks
                    weight = self.particle_sample_weight[k]
                    sample_stiffness, sample_damping = self._contact_blocks(
                        self.sample_mass[i_s], position, self._sample_point(v, i_s), mask,
                        definite)
                    stiffness_block += weight * weight * sample_stiffness
                    damping_block += weight * weight * sample_damping
        return stiffness_block, damping_block

    @ti.func
    def _contact_blocks(self, mass, position, velocity, mask, definite: ti.template()):
        """(∂F/∂p, ∂F/∂u) of ``_contact_force`` on a point of ``mass``:
        ∂F/∂p = m·k̂·[−n·nᵀ + (d/|p − y|)·P], P = I − n·nᵀ (− â·âᵀ on the cylinder part), friction
        left out; ∂F/∂u from ``penalty_damping_block``. The curvature term d/|p − y|·P is
        positive; ``definite`` drops it. A contact whose normal force is clamped to 0 (the
        point leaving fast) exerts nothing and adds nothing: its blocks would make release
        sticky."""
        real = self.model.real
        stiffness_block = ti.Matrix.zero(real, 3, 3)
        damping_block = ti.Matrix.zero(real, 3, 3)
        i_c = self._next_capsule(0, mask)
        while i_c < self.capsule_count:
            if self.near(i_c, position):
                depth, normal, distance, s, axis, surface_velocity = self.probe(i_c, position)
                if distance > 0:
                    curvature = ti.Matrix.zero(real, 3, 3)  # ∇²|p − y| = P/|p − y|
                    if ti.static(not definite):
                        curvature = ti.Matrix.identity(real, 3) - normal.outer_product(normal)
                        if 0 < s < 1:
                            curvature -= axis.outer_product(axis)
                        curvature /= distance
                    capsule_stiffness, capsule_damping = penalty_blocks(
                        mass, depth, normal, velocity - surface_velocity, curvature,
                        real(self.stiffness), real(self.damping_ratio), real(self.friction),
                        real, definite)
                    stiffness_block += capsule_stiffness
                    damping_block += capsule_damping
            i_c = self._next_capsule(i_c + 1, mask)
        return stiffness_block, damping_block

    @ti.func
    def apply(self, state, t):
        """The projection pass after a step (``penalty+projection``): a free particle still
        inside a capsule at time t moves to its surface (plus margin) and loses its inward
        velocity relative to the surface."""
        model = self.model
        x, v = ti.static(state.x, state.v)
        self._pose(t)
        for i_p in range(model.particle_count):
            if model.particle_inv_mass[i_p] > 0:
                for i_c in range(self.capsule_count):
                    depth, normal, distance, _segment, _axis, surface_velocity = self.probe(
                        i_c, x[i_p])
                    if depth > 0 and distance > 0:
                        x[i_p] += depth * normal
                        inward = (v[i_p] - surface_velocity).dot(normal)
                        if inward < 0:
                            v[i_p] -= inward * normal

    def stability_modes(self) -> list[tuple[float, float]]:
        """The penalty's mode, its stiffness raised by the surface samples' share (module
        docstring)."""
        return [(self.stiffness * self.stiffness_factor, self.damping_ratio)]

    def penetration_depths(self, points: np.ndarray) -> np.ndarray:
        """Metres inside the deepest capsule (without the margin) at the end of the frame."""
        a, b = self.control.capsule_ends_at_frame_end
        return capsule_penetration_depths(points, a, b, self.control.capsule_radius)
