"""Self-collision: the cloth repels itself where two of its parts come closer than ``thickness``
(docs/physics.md, "Self-collision").

Proximity, as in Bridson, Fedkiw & Anderson (2002, "Robust treatment of collisions, contact and
friction for cloth animation"), between every vertex and every triangle it is not a corner of,
and between every two edges that share no vertex. A pair at distance d < thickness along the unit
normal n between its closest points gets the penalty force of ``penalty`` (the law of body
contact: m·(k̂·(thickness − d) − 2ζ·√k̂·(u·n)), never pulling, and regularised Coulomb friction
on the relative slip u):

- vertex p and triangle t with closest point c = Σ w_k·x_k (barycentric, clamped to the
  triangle; Ericson 2005, "Real-Time Collision Detection", §5.1.5): F on p with p's mass, −w_k·F
  on each corner k;
- edges (a, b) and (c, d) with closest points P = a + s·(b − a), Q = c + u·(d − c) (Ericson
  §5.1.9): F on the first with the mean mass of the four particles, (1 − s)·F on a and s·F on b;
  −F shared the same way by the second.

The elastic part is −∇ of the energy ½·m·k̂·(thickness − d)² (the closest points move
tangentially to first order), so momentum is conserved and the energy balance holds.

Candidate pairs (``effects/candidate_pairs.py``): every pair within the reach, thickness +
padding, in one compact list, rebuilt only when the cloth has deformed (its best rigid motion
taken out) by half the padding since the last build.

Gathered, no atomics on forces: each pair's force (and blocks) is computed once per evaluation,
with each of its four particles' share weight; a particle sums its entries' shares in list
order, so a run is bit-reproducible on the CPU.

Implicit integrator: per-particle blocks of each pair (w²-weighted), the couplings between a
pair's particles left out; tunnelling, the thickness bound and the measured cost: docs/physics.md.
"""

from dataclasses import dataclass

import numpy as np
import taichi as ti

from taichi_cloth.effects.base import Effect, EffectContext
from taichi_cloth.effects.candidate_pairs import VERTEX_TRIANGLE, CandidatePairs
from taichi_cloth.effects.penalty import (normal_force_magnitude, penalty_damping_block,
                                          penalty_force)
from taichi_cloth.effects.proximity import edge_edge_offset, vertex_triangle_offset
from taichi_cloth.errors import InputError
from taichi_cloth.runtime import runs_on_cpu
from taichi_cloth.settings import setting

PADDING = 1.0  # the list's padding in thicknesses: rebuilt after half of it is deformed
CONTACTS_PER_PARTICLE = 4  # the stiffness bound for dt = "auto": a vertex, corner and edge shares


@dataclass(frozen=True)
class SelfCollisionSettings:
    thickness: float = setting(0.004, "float", low=0.0, low_inclusive=False,
                               doc="distance the cloth keeps from itself, m")
    stiffness: float = setting(1e6, "float", low=0.0, low_inclusive=False,
                               doc="penalty stiffness per unit particle mass, 1/s²: layers "
                                   "meeting faster than thickness·√stiffness pass through")
    damping: float = setting(0.5, "float", low=0.0, doc="normal damping ratio ζ")
    friction: float = setting(0.3, "float", low=0.0, doc="Coulomb coefficient μ")


@ti.data_oriented
class SelfCollision(Effect):
    """Penalty repulsion between the cloth's own vertices and triangles and between its edges
    (module docstring)."""

    name = "self_collision"
    Settings = SelfCollisionSettings
    has_jacobian = True

    def __init__(self, settings: SelfCollisionSettings, context: EffectContext):
        super().__init__(settings, context)
        model = context.model
        garment = model.garment
        self.model = model
        self.blocks = context.needs_jacobian  # the implicit solver's blocks, else none
        self.serial = runs_on_cpu()  # the per-evaluation loops: one thread beats a hand-off
        real = model.real
        rest = np.linalg.norm(np.diff(garment.positions[garment.edges], axis=1), axis=2)
        shortest = float(rest.min(initial=np.inf))
        if settings.thickness >= 0.5 * shortest:
            raise InputError(f"effects.self_collision.thickness: {settings.thickness:g} m must be "
                             f"below half the cloth's shortest edge, {shortest:g} m")
        self.thickness, self.stiffness = settings.thickness, settings.stiffness
        self.damping_ratio, self.friction = settings.damping, settings.friction
        self.padding = PADDING * settings.thickness  # m: the list holds pairs within reach
        self.reach = settings.thickness + self.padding  # m
        self.pairs = CandidatePairs(model, self.reach, self.padding)
        capacity = self.pairs.capacity
        # per evaluation: each pair's force on its first point, its blocks, its particles' shares
        self.pair_force = ti.Vector.field(3, real, capacity)
        self.pair_share = ti.Vector.field(4, real, capacity)
        if self.blocks:
            self.pair_stiffness = ti.Matrix.field(3, 3, real, capacity)
            self.pair_damping = ti.Matrix.field(3, 3, real, capacity)

    def upload(self) -> None:
        self.pairs.upload()

    @ti.func
    def prepare(self, x, v, t):
        """The candidate list brought up to date (``CandidatePairs.update``), then every listed
        pair's force and blocks."""
        self.pairs.update(x)
        if ti.static(self.serial):
            ti.loop_config(serialize=True)
        for k in range(self.pairs.pair_count[None]):
            self._evaluate(x, v, k)

    @ti.func
    def _evaluate(self, x, v, k):
        """Pair k's force on its first point, its blocks and its particles' shares (the share
        of a corner or end: its weight, negative on the second primitive)."""
        real = self.model.real
        ids = self.pairs.pair_particles[k]
        force, stiffness, damping = ti.Vector.zero(real, 3), ti.Matrix.zero(real, 3, 3), \
            ti.Matrix.zero(real, 3, 3)
        share = ti.Vector.zero(real, 4)
        if self.pairs.pair_kind[k] == VERTEX_TRIANGLE:  # (an inactive pair's force is 0)
            corners = ti.Vector([ids[1], ids[2], ids[3]])
            weights, force, stiffness, damping = self._vertex_triangle(x, v, ids[0], corners)
            share = ti.Vector([1.0, -weights[0], -weights[1], -weights[2]], real)
        else:
            s, u, force, stiffness, damping = self._edge_edge(
                x, v, ti.Vector([ids[0], ids[1]]), ti.Vector([ids[2], ids[3]]))
            share = ti.Vector([1 - s, s, u - 1, -u], real)
        self.pair_force[k] = force
        self.pair_share[k] = share
        if ti.static(self.blocks):
            self.pair_stiffness[k] = stiffness
            self.pair_damping[k] = damping

    @ti.func
    def _pair(self, mass, offset, relative_velocity):
        """The penalty between two points ``offset`` apart [m] (first minus second) with that
        relative velocity, for ``mass`` [kg]: (force on the first [N], its stiffness block
        −m·k̂·n·nᵀ and damping block), all zero beyond the thickness or when the normal force is
        clamped to 0 (leaving fast: its blocks would make release sticky)."""
        real = self.model.real
        distance = offset.norm()
        normal = offset / ti.max(distance, 1e-30)
        depth = real(self.thickness) - distance
        k_hat, zeta, mu = real(self.stiffness), real(self.damping_ratio), real(self.friction)
        active = distance > 0 and depth > 0 and normal_force_magnitude(
            mass, depth, relative_velocity.dot(normal), k_hat, zeta) > 0
        force = ti.Vector.zero(real, 3)
        stiffness = ti.Matrix.zero(real, 3, 3)
        damping = ti.Matrix.zero(real, 3, 3)
        if active:
            force = penalty_force(mass, depth, normal, relative_velocity, k_hat, zeta, mu)
            if ti.static(self.blocks):
                stiffness = -mass * k_hat * normal.outer_product(normal)
                damping = penalty_damping_block(mass, depth, normal, relative_velocity, k_hat,
                                                zeta, mu, real)
        return force, stiffness, damping

    @ti.func
    def _vertex_triangle(self, x, v, i_p, corners):
        """Vertex i_p against the triangle of ``corners``: (barycentric weights of the closest
        point, force on the vertex, blocks)."""
        weights, offset = vertex_triangle_offset(x, i_p, corners, self.model.real)
        closest_velocity = weights[0] * v[corners[0]] + weights[1] * v[corners[1]] \
            + weights[2] * v[corners[2]]
        force, stiffness, damping = self._pair(self.model.particle_mass[i_p], offset,
                                               v[i_p] - closest_velocity)
        return weights, force, stiffness, damping

    @ti.func
    def _edge_edge(self, x, v, first, second):
        """Edge ``first`` (its two particles) against edge ``second``: (s, u, force on the first
        edge's closest point, blocks), with the four particles' mean mass."""
        s, u, offset = edge_edge_offset(x, first, second, self.model.real)
        velocity_first = (1 - s) * v[first[0]] + s * v[first[1]]
        velocity_second = (1 - u) * v[second[0]] + u * v[second[1]]
        mass = ti.static(self.model.particle_mass)
        mean_mass = 0.25 * (mass[first[0]] + mass[first[1]] + mass[second[0]] + mass[second[1]])
        force, stiffness, damping = self._pair(mean_mass, offset, velocity_first - velocity_second)
        return s, u, force, stiffness, damping

    @ti.func
    def force(self, model, x, v, i_p, t):
        """The particle's shares of its pairs' forces, gathered in list order."""
        f = ti.Vector.zero(model.real, 3)
        entries = self.pairs
        for k in range(entries.entry_start[i_p], entries.entry_start[i_p + 1]):
            pair, slot = entries.entry[k] // 4, entries.entry[k] % 4
            f += self.pair_share[pair][slot] * self.pair_force[pair]
        return f

    @ti.func
    def local_jacobian(self, model, x, v, i_p, t, definite: ti.template()):
        """(∂f/∂x, ∂f/∂v) of particle i_p: its shares² of its pairs' blocks from the last
        ``prepare`` (the couplings between a pair's particles left out: module docstring)."""
        stiffness = ti.Matrix.zero(model.real, 3, 3)
        damping = ti.Matrix.zero(model.real, 3, 3)
        if ti.static(self.blocks):
            entries = self.pairs
            for k in range(entries.entry_start[i_p], entries.entry_start[i_p + 1]):
                pair, slot = entries.entry[k] // 4, entries.entry[k] % 4
                weight = self.pair_share[pair][slot] ** 2
                stiffness += weight * self.pair_stiffness[pair]
                damping += weight * self.pair_damping[pair]
        return stiffness, damping

    def frame_metrics(self, x: np.ndarray) -> dict:
        """Candidate pairs dropped since the start (0 unless the capacities of
        ``candidate_pairs`` are too small for the scene: then contacts can be missed), the list's
        builds since the start and its pairs at the last build."""
        return {"self_collision_overflow": int(self.pairs.overflow[None]),
                "self_collision_builds": int(self.pairs.rebuilds[None]),
                "self_collision_pairs": int(self.pairs.pair_count[None])}

    def stability_modes(self) -> list[tuple[float, float]]:
        """The penalty's mode, with up to ``CONTACTS_PER_PARTICLE`` contacts on one particle."""
        return [(self.stiffness * CONTACTS_PER_PARTICLE, self.damping_ratio)]
