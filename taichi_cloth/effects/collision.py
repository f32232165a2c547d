"""Contact with the body's capsules (seed §2.6): the penalty force of ``penalty`` against every
bone capsule, posed once per force evaluation from the prescribed motion (``physics.control``).

Contact on the whole surface (``surface = true``, the default): a capsule thinner than the
particle spacing (a leg between the particles of a coarse skirt, a bar under a drape) passes
between particles that alone feel contact. Every edge midpoint and triangle centroid is then a
contact sample too, a point p = Σ_a w_a·x_a of its 2 or 3 particles (w = ½ or ⅓), with velocity
Σ w_a·v_a and mass m_s = Σ w_a·m_a. Its penalty energy E_s(p) gives each of its particles the
force w_a·F_s (∂p/∂x_a = w_a·I), so momentum and the energy balance hold. Each particle is a
sample of its own (w = 1), listed first, so one pass serves them all: per force evaluation
(``prepare``) it computes, for every sample that touches a capsule, F_s and its blocks ∂F_s/∂p
and ∂F_s/∂u into fields (stamped with the evaluation's number; a sample that touches nothing
stores nothing); each particle then gathers its share over its samples stamped now
(``gather.incidence_lists``, a fixed order). The contact is written once in the kernels that
take it (one inlined copy of the probes instead of four: docs/performance.md, "Contact written
once in the implicit step"). For the implicit solver each particle's block keeps
w_a²·∂F_s/∂p of its samples and drops the couplings between the particles of a sample (a
documented approximation: the Newton step stays a descent step, the contact stiffness on the
diagonal is exact). With samples, a particle feels the contact stiffness of its own and of its
samples: Gershgorin bounds the mode by k̂·Σ w_a·m_s/m_a (its own sample: 1), and the samples'
dashpots and friction dampers, each in proportion to its mass as its spring is, add up in the
same proportion: ``stability_modes`` reports Σ w_a·m_s/m_a contacts for ``dt = "auto"``."""

from dataclasses import dataclass

import numpy as np
import taichi as ti

from taichi_cloth.effects.base import Effect, EffectContext
from taichi_cloth.effects.near_masks import NearMasks
from taichi_cloth.effects.penalty import (ContactMode, PenaltySettings,
                                          capsule_penetration_depths, closest_on_segment,
                                          penalty_terms)
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
    points inside it pay for the exact closest-point test. The near-masks of ``NearMasks`` say
    which capsules a sample (a particle, an edge midpoint, a centroid) may touch.
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
        # the samples' blocks for the implicit solver's ``local_jacobian`` (not compiled for
        # an explicit integrator, which never asks for them)
        self.keeps_blocks = context.needs_jacobian
        self._allocate_samples(model)

    def _allocate_samples(self, model) -> None:
        """The contact samples (the particles, then with ``surface`` the edge midpoints and the
        triangle centroids) as 3 particles and 3 weights each (a particle is its own first
        corner with weight 1, an edge repeats its first particle with weight 0), their force
        and block fields, and each particle's CSR list of (sample, its weight there), its own
        sample first."""
        n = model.particle_count
        edges = model.garment.edges if self.surface else np.zeros((0, 2), np.int32)
        triangles = model.garment.triangles if self.surface else np.zeros((0, 3), np.int32)
        own = np.arange(n)
        corners = np.concatenate([np.column_stack([own, own, own]),
                                  np.column_stack([edges, edges[:, 0]]),
                                  triangles]).astype(np.int32)
        weights = np.concatenate([np.tile([1.0, 0.0, 0.0], (n, 1)),
                                  np.tile([0.5, 0.5, 0.0], (len(edges), 1)),
                                  np.full((len(triangles), 3), 1.0 / 3.0)])
        # corners of weight 0 listed as a particle past the last, so that they sort out
        listed = np.where(weights > 0, corners, n)
        start, item, slot = incidence_lists(listed, n + 1)
        start = start[:n + 1]
        item, slot = item[:start[-1]], slot[:start[-1]]
        mass = model.garment.mass
        sample_mass = np.einsum("sa,sa->s", weights, mass[corners])
        share = np.zeros(n)  # Σ w_a·m_s over a particle's samples, its own (m_a) included
        np.add.at(share, corners.ravel(), (weights * sample_mass[:, None]).ravel())
        free = mass > 0
        # the contacts a particle's own penalty and its samples' add up to at most (Gershgorin)
        self.sample_contacts = float(np.max(share[free] / mass[free])) if free.any() else 1.0
        self.sample_count = len(corners)
        rest = np.linalg.norm(np.diff(model.garment.positions[model.garment.edges], axis=1),
                              axis=2)
        self.allocate_masks(float(rest.max(initial=0.0)))
        real = model.real
        self.sample_corners = ti.Vector.field(3, ti.i32, self.sample_count)
        self.sample_weights = ti.Vector.field(3, real, self.sample_count)
        self.sample_mass = ti.field(real, self.sample_count)
        self.sample_force = ti.Vector.field(3, real, self.sample_count)
        if self.keeps_blocks:  # ∂F_s/∂p without and with its curvature term, and ∂F_s/∂u
            (self.sample_stiffness, self.sample_curvature, self.sample_damping) = [
                ti.Matrix.field(3, 3, real, self.sample_count) for _ in range(3)]
        # the evaluation (``NearMasks.evaluation``) that last stored the sample's force
        self.sample_evaluation = ti.field(ti.i32, self.sample_count)
        self.particle_sample_start = ti.field(ti.i32, model.particle_count + 1)
        self.particle_sample = ti.field(ti.i32, max(1, len(item)))
        self.particle_sample_weight = ti.field(real, max(1, len(item)))  # w_a of the entry
        self._sample_tables = (corners, weights, sample_mass, start, item, weights[item, slot])

    def upload(self) -> None:
        """The capsule radii and the samples, into the model's ``uploads``."""
        real = self.model.numpy_real
        corners, weights, sample_mass, start, item, item_weight = self._sample_tables
        self.model.uploads.add([(self.capsule_radius, self._host_radius), *self.mask_uploads(),
                                (self.sample_corners, corners),
                                (self.sample_weights, weights.astype(real)),
                                (self.sample_mass, sample_mass.astype(real)),
                                (self.particle_sample_start, start),
                                (self.particle_sample, item),
                                (self.particle_sample_weight, item_weight.astype(real))])

    @ti.func
    def prepare(self, x, v, t):
        """Pose every capsule at time t [s] once, before the particle loops: endpoints a, b and
        their velocities from the track (two Hermite evaluations per capsule instead of four per
        particle and capsule), and the bounding sphere of ``near``; then the contact of every
        sample with a capsule near (``NearMasks.near_sample``; every sample without masks) at
        (x, v): F_s and (``keeps_blocks``) its blocks, stored and stamped where it touches a
        capsule (elsewhere F_s = 0, not stored: its readers find an older stamp)."""
        self._pose(t)
        if ti.static(self.masked):
            self._refresh_masks(x)
        self._begin_marks()  # (``NearMasks``)
        listed = self.sample_count
        if ti.static(self.masked):
            listed = self.near_count[None]
        for k in range(listed):
            i_s = k
            if ti.static(self.masked):
                i_s = self.near_sample[k]
            position, mask = self._sample_mask(x, i_s)
            if mask != 0:
                self._sample_contact(i_s, position, self._sample_point(v, i_s), mask)

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
        for i_k in range(2 * self.capsule_count):  # the track's points: a, b of each capsule
            point, velocity = self.track.at(i_k, t)
            if i_k % 2 == 0:
                self.capsule_a[i_k // 2], self.capsule_velocity_a[i_k // 2] = point, velocity
            else:
                self.capsule_b[i_k // 2], self.capsule_velocity_b[i_k // 2] = point, velocity
        for i_c in range(self.capsule_count):
            a, b = self.capsule_a[i_c], self.capsule_b[i_c]
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
    def _sample_contact(self, i_s, position, velocity, mask):
        """Sample i_s at ``position`` with ``velocity``, summed over the capsules whose bit is
        set in ``mask`` (each first culled by its bounding sphere): where it touches one, its
        penalty force F_s [N] and (``keeps_blocks``) ∂F_s/∂p and ∂F_s/∂u stored, stamped with
        this evaluation, and its particles marked. ∂F/∂p = m·k̂·[−n·nᵀ + (d/|p − y|)·P],
        P = I − n·nᵀ (− â·âᵀ on the cylinder part), friction left out, is kept as its two
        terms (``sample_stiffness``, ``sample_curvature``: the positive curvature term, which
        ``local_jacobian``'s ``definite`` drops); ∂F/∂u from ``penalty_terms``. A
        contact whose normal force is clamped to 0 (the point leaving fast) exerts nothing and
        adds no block: its blocks would make release sticky."""
        real = self.model.real
        mass = self.sample_mass[i_s]
        touches = False
        f = ti.Vector.zero(real, 3)
        stiffness_block = ti.Matrix.zero(real, 3, 3)
        curvature_block = ti.Matrix.zero(real, 3, 3)
        damping_block = ti.Matrix.zero(real, 3, 3)
        i_c = self._next_capsule(0, mask)
        while i_c < self.capsule_count:
            if self.near(i_c, position):
                depth, normal, distance, s, axis, surface_velocity = self.probe(i_c, position)
                if depth > 0 and distance > 0:
                    touches = True
                    force, normal_magnitude, capsule_damping = penalty_terms(
                        mass, depth, normal, velocity - surface_velocity, real(self.stiffness),
                        real(self.damping_ratio), real(self.friction), real)
                    f += force
                    if ti.static(self.keeps_blocks):
                        if normal_magnitude > 0:  # (as ``penalty_blocks``)
                            curvature = ti.Matrix.identity(real, 3) \
                                - normal.outer_product(normal)
                            if 0 < s < 1:
                                curvature -= axis.outer_product(axis)
                            curvature /= distance  # ∇²|p − y| = P/|p − y|
                            stiffness_block += -mass * real(self.stiffness) \
                                * normal.outer_product(normal)
                            curvature_block += mass * real(self.stiffness) * depth * curvature
                            damping_block += capsule_damping
            i_c = self._next_capsule(i_c + 1, mask)
        if touches:
            self.sample_force[i_s] = f
            if ti.static(self.keeps_blocks):
                self.sample_stiffness[i_s] = stiffness_block
                self.sample_curvature[i_s] = curvature_block
                self.sample_damping[i_s] = damping_block
            self.sample_evaluation[i_s] = self.evaluation[None]
            self._mark_touched(i_s)

    @ti.func
    def _samples_now(self, i_p):
        """The range of particle i_p's sample list to walk: all of it where a sample of it
        touched a capsule at the evaluation that ``prepare`` made last (on a dancing skirt a
        few dozen of its particles), none elsewhere."""
        first, end = self.particle_sample_start[i_p], self.particle_sample_start[i_p + 1]
        if not self._sample_may_touch(i_p):
            end = first
        return first, end

    @ti.func
    def force(self, model, x, v, i_p, t):
        """Σ w_a·F_s over the particle's samples (its own first) stored at this evaluation."""
        f = ti.Vector.zero(model.real, 3)
        first, end = self._samples_now(i_p)
        for k in range(first, end):
            i_s = self.particle_sample[k]
            if self.sample_evaluation[i_s] == self.evaluation[None]:  # F_s stored now
                f += self.particle_sample_weight[k] * self.sample_force[i_s]
        return f

    @ti.func
    def local_jacobian(self, model, x, v, i_p, t, definite: ti.template()):
        """(∂f/∂x, ∂f/∂v) of the penalty on particle i_p: w_a² times the blocks of its samples
        (its own first) stored at this evaluation (the couplings between a sample's particles
        left out: module docstring), at the (x, v) of the last ``prepare``; ``definite`` drops
        the curvature term."""
        ti.static_assert(self.keeps_blocks, "the contact's blocks were not asked for "
                                            "(EffectContext.needs_jacobian)")
        real = model.real
        stiffness_block = ti.Matrix.zero(real, 3, 3)
        damping_block = ti.Matrix.zero(real, 3, 3)
        first, end = self._samples_now(i_p)
        for k in range(first, end):
            i_s = self.particle_sample[k]
            if self.sample_evaluation[i_s] == self.evaluation[None]:  # blocks stored now
                weight_sq = self.particle_sample_weight[k] * self.particle_sample_weight[k]
                sample_stiffness = self.sample_stiffness[i_s]
                if ti.static(not definite):
                    sample_stiffness += self.sample_curvature[i_s]
                stiffness_block += weight_sq * sample_stiffness
                damping_block += weight_sq * self.sample_damping[i_s]
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

    def stability_modes(self) -> list[ContactMode]:
        """The penalty's mode: a particle's own sample and its share of its edges' and
        triangles' add up to ``sample_contacts`` contacts, their dashpots and friction dampers
        with their springs (module docstring)."""
        return [ContactMode(self.stiffness, self.damping_ratio, contacts=self.sample_contacts)]

    def penetration_depths(self, points: np.ndarray) -> np.ndarray:
        """Metres inside the deepest capsule (without the margin) at the end of the frame."""
        a, b = self.control.capsule_ends_at_frame_end
        return capsule_penetration_depths(points, a, b, self.control.capsule_radius)
