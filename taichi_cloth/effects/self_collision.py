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

Broad phase (``effects/spatial_hash.py``), in the kernel: particles, triangle centroids and edge
midpoints hashed on a grid of cell = the longest current edge + the reach (thickness + padding),
each kind in buckets of its own (a particle walks only centroids, a triangle particles, an edge
midpoints); an item's candidate list holds the pairable items within the reach (bounding
spheres, then the exact distance), ascending, at most ``CANDIDATES`` (more count as
``self_collision_overflow``), rebuilt when a particle has moved half the padding since the last
build: a pair not listed was beyond the reach and has closed by at most the padding.

Gathered, no atomics on forces: a pair's force is computed by each primitive it acts on, over the
candidate lists: a particle sums its vertex–triangle forces, a triangle its corners' shares into
a field per corner, an edge its ends' shares of edge–edge forces into a field per end, every edge
pair evaluated in one order (lower edge first). ``force`` then gathers a particle's own sum and
its triangles' and edges' shares through static incidence lists. The computations of one pair
are the same function of the same numbers: they match to the bit, and a run is bit-reproducible
on the CPU.

Implicit integrator: per-particle blocks of each pair (w²-weighted), the couplings between a
pair's particles left out; tunnelling, the thickness bound and the measured cost: docs/physics.md.
"""

from dataclasses import dataclass

import numpy as np
import taichi as ti

from taichi_cloth.effects.base import Effect, EffectContext
from taichi_cloth.effects.penalty import (normal_force_magnitude, penalty_damping_block,
                                          penalty_force)
from taichi_cloth.errors import InputError
from taichi_cloth.gather import incidence_lists
from taichi_cloth.effects.proximity import closest_between_segments, closest_on_triangle
from taichi_cloth.effects.spatial_hash import SpatialHash
from taichi_cloth.settings import setting
from taichi_cloth.uploads import upload

CANDIDATES = 32  # the longest candidate list of a particle, triangle or edge
PADDING = 1.0  # the candidate lists' padding in thicknesses: rebuilt after half of it is moved
CONTACTS_PER_PARTICLE = 4  # the stiffness bound for dt = "auto": a vertex, corner and edge shares
PARTICLE, TRIANGLE, EDGE = 0, 1, 2  # hashed items' kinds: particle–triangle, edge–edge pairs


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
        real = model.real
        triangles, edges = garment.triangles, garment.edges
        rest = np.linalg.norm(np.diff(garment.positions[edges], axis=1), axis=2)
        shortest = float(rest.min(initial=np.inf))
        if settings.thickness >= 0.5 * shortest:
            raise InputError(f"effects.self_collision.thickness: {settings.thickness:g} m must be "
                             f"below half the cloth's shortest edge, {shortest:g} m")
        self.thickness, self.stiffness = settings.thickness, settings.stiffness
        self.damping_ratio, self.friction = settings.damping, settings.friction
        self.triangle_count, self.edge_count = len(triangles), len(edges)
        # hashed items: the particles, then the triangles' centroids, then the edges' midpoints
        self.item_count = model.particle_count + self.triangle_count + self.edge_count
        self.items = SpatialHash(self.item_count, real)
        self.item_radius = ti.field(real, self.item_count)  # m: what the item spans around it
        self.corners = ti.Vector.field(3, ti.i32, self.triangle_count)
        self.ends = ti.Vector.field(2, ti.i32, self.edge_count)
        self.padding = PADDING * settings.thickness  # m: lists hold pairs within thickness + it
        self.longest_edge = ti.field(real, ())  # m, at the last build: the hash cell's base
        self.moved = ti.field(real, ())  # the farthest a particle went since the lists' build
        self.stale = ti.field(ti.i32, ())  # whether this evaluation rebuilds the lists
        self.overflow = ti.field(ti.i32, ())  # candidates dropped from full lists, ever
        self.built_at = ti.Vector.field(3, real, model.particle_count)
        self.candidates = ti.field(ti.i32, (self.item_count, CANDIDATES))  # items, ascending
        self.candidate_count = ti.field(ti.i32, self.item_count)
        self.vertex_force = ti.Vector.field(3, real, model.particle_count)
        self.vertex_stiffness = ti.Matrix.field(3, 3, real, model.particle_count)
        self.vertex_damping = ti.Matrix.field(3, 3, real, model.particle_count)
        self.corner_force = ti.Vector.field(3, real, (self.triangle_count, 3))
        self.corner_stiffness = ti.Matrix.field(3, 3, real, (self.triangle_count, 3))
        self.corner_damping = ti.Matrix.field(3, 3, real, (self.triangle_count, 3))
        self.end_force = ti.Vector.field(3, real, (self.edge_count, 2))
        self.end_stiffness = ti.Matrix.field(3, 3, real, (self.edge_count, 2))
        self.end_damping = ti.Matrix.field(3, 3, real, (self.edge_count, 2))
        self._lists = (incidence_lists(triangles, model.particle_count),
                       incidence_lists(edges, model.particle_count))
        # per particle, CSR: its triangles with its corner there, its edges with its end there
        self.triangle_start, self.triangle_item, self.triangle_slot, \
            self.edge_start, self.edge_item, self.edge_slot = (
                ti.field(ti.i32, len(values) if k == 0 else max(1, len(values)))
                for start_item_slot in self._lists for k, values in enumerate(start_item_slot))
        self._host = (triangles, edges)

    def upload(self) -> None:
        triangles, edges = self._host
        kinds = np.repeat(np.array([PARTICLE, TRIANGLE, EDGE], np.int32), (
            self.model.particle_count, self.triangle_count, self.edge_count))
        targets = (self.triangle_start, self.triangle_item, self.triangle_slot,
                   self.edge_start, self.edge_item, self.edge_slot)
        upload([(self.built_at, np.full(self.built_at.shape + (3,), np.inf)),  # no lists yet
                (self.corners, triangles.astype(np.int32)), (self.ends, edges.astype(np.int32)),
                (self.items.kind, kinds),
                *((target, values.astype(np.int32)) for target, values in
                  zip(targets, (v for lists in self._lists for v in lists)) if len(values))])

    @ti.func
    def prepare(self, x, v, t):
        """The candidate lists, rebuilt when a particle has moved half the padding since the
        last build, then every particle's, triangle corner's and edge end's share of the pair
        forces and blocks over them (module docstring)."""
        real = self.model.real
        particles, triangles = self.model.particle_count, self.triangle_count
        self.moved[None] = 0.0
        for i_p in range(particles):
            ti.atomic_max(self.moved[None], (x[i_p] - self.built_at[i_p]).norm())
        self.stale[None] = int(self.moved[None] > 0.5 * real(self.padding))
        self.longest_edge[None] = 0.0
        for item in range(self.item_count):
            if self.stale[None]:
                self._place(x, item)
        size = self.longest_edge[None] + real(self.thickness + self.padding)
        self.items.build(size, self.stale)
        for item in range(self.item_count):
            if self.stale[None]:
                self._list_near(x, item, size)
        for item in range(particles + triangles):
            self._vertex_triangle_pass(x, v, item)
        for e in range(self.edge_count):
            self._edge_pass(x, v, e)

    @ti.func
    def _place(self, x, item):
        """Hashed item ``item`` at x: its point (a particle, a triangle's centroid, an edge's
        midpoint) and the radius around it that holds it; a particle's build position; the
        longest edge into ``longest_edge``."""
        particles, triangles = self.model.particle_count, self.triangle_count
        if item < particles:
            self.items.point[item] = x[item]
            self.item_radius[item] = 0.0
            self.built_at[item] = x[item]
        elif item < particles + triangles:
            corners = self.corners[item - particles]
            centroid = (x[corners[0]] + x[corners[1]] + x[corners[2]]) / 3
            self.items.point[item] = centroid
            self.item_radius[item] = ti.max((x[corners[0]] - centroid).norm(), ti.max(
                (x[corners[1]] - centroid).norm(), (x[corners[2]] - centroid).norm()))
        else:
            ends = self.ends[item - particles - triangles]
            length = (x[ends[1]] - x[ends[0]]).norm()
            self.items.point[item] = 0.5 * (x[ends[0]] + x[ends[1]])
            self.item_radius[item] = 0.5 * length
            ti.atomic_max(self.longest_edge[None], length)

    @ti.func
    def _pairable(self, item, other) -> ti.i32:
        """Whether two hashed items form a pair the effect acts on: a particle and a triangle it
        is not a corner of (either way round), or two edges that share no particle."""
        particles, triangles = self.model.particle_count, self.triangle_count
        pairable = 0
        if item < particles and particles <= other < particles + triangles:
            pairable = int((self.corners[other - particles] != item).all())
        elif other < particles and particles <= item < particles + triangles:
            pairable = int((self.corners[item - particles] != other).all())
        elif item >= particles + triangles and other >= particles + triangles:
            ends = self.ends[item - particles - triangles]
            other_ends = self.ends[other - particles - triangles]
            pairable = int(other_ends[0] != ends[0] and other_ends[0] != ends[1]
                           and other_ends[1] != ends[0] and other_ends[1] != ends[1])
        return pairable

    @ti.func
    def _list_near(self, x, item, size):
        """Item ``item``'s candidates: the pairable items within thickness + padding of it
        (their spheres first, then the exact distance), among those hashed in the 27 cells
        around it (an item's sphere is within a cell of any point it spans: the cell is the
        longest edge plus that reach)."""
        reach = self.model.real(self.thickness + self.padding)
        self.candidate_count[item] = 0
        point, radius = self.items.point[item], self.item_radius[item]
        base = self.items.cell_of(point, size)
        wanted = ti.select(self.items.kind[item] == EDGE, EDGE, TRIANGLE - self.items.kind[item])
        for offset in ti.grouped(ti.ndrange((-1, 2), (-1, 2), (-1, 2))):
            cell = base + offset
            bucket = self.items.bucket(cell, wanted)
            for k in range(self.items.bucket_start[bucket], self.items.bucket_start[bucket + 1]):
                other = self.items.filed[k]
                if (self.items.cell[other] == cell).all() and self._pairable(item, other) \
                        and (self.items.point[other] - point).norm() \
                        <= radius + self.item_radius[other] + reach:
                    if self._distance(x, item, other) <= reach:  # (``and`` evaluates both)
                        self._append(item, other)

    @ti.func
    def _distance(self, x, item, other):
        """The distance [m] between the primitives of two pairable items at x: a particle and
        a triangle (either way round), or two edges."""
        particles, triangles = self.model.particle_count, self.triangle_count
        distance = self.model.real(0.0)
        if item >= particles + triangles:
            _, _, offset = self._edge_edge_offset(x, self.ends[item - particles - triangles],
                                                  self.ends[other - particles - triangles])
            distance = offset.norm()
        else:
            i_p, i_t = item, other - particles
            if item >= particles:
                i_p, i_t = other, item - particles
            distance = self._vertex_triangle_offset(x, i_p, self.corners[i_t])[1].norm()
        return distance

    @ti.func
    def _append(self, owner, other):
        """Insert item ``other`` into ``owner``'s candidate list, kept in increasing order (so
        sums over it do not depend on when it was built; counted as overflow when full)."""
        count = self.candidate_count[owner]
        if count < CANDIDATES:
            slot = count
            while slot > 0 and self.candidates[owner, slot - 1] > other:
                self.candidates[owner, slot] = self.candidates[owner, slot - 1]
                slot -= 1
            self.candidates[owner, slot] = other
            self.candidate_count[owner] = count + 1
        else:
            ti.atomic_add(self.overflow[None], 1)

    @ti.func
    def _vertex_triangle_pass(self, x, v, item):
        """Vertex–triangle forces over hashed item ``item``'s candidates: a particle's own sum,
        or a triangle's corners' shares −w_k·F (blocks w_k²·…; only with ``blocks``)."""
        real = self.model.real
        particles = self.model.particle_count
        if item < particles:
            self.vertex_force[item] = ti.Vector.zero(real, 3)
            if ti.static(self.blocks):
                self.vertex_stiffness[item] = ti.Matrix.zero(real, 3, 3)
                self.vertex_damping[item] = ti.Matrix.zero(real, 3, 3)
        else:
            for c in ti.static(range(3)):
                self.corner_force[item - particles, c] = ti.Vector.zero(real, 3)
                if ti.static(self.blocks):
                    self.corner_stiffness[item - particles, c] = ti.Matrix.zero(real, 3, 3)
                    self.corner_damping[item - particles, c] = ti.Matrix.zero(real, 3, 3)
        for k in range(self.candidate_count[item]):
            other = self.candidates[item, k]
            i_p, i_t = item, other - particles
            if item >= particles:
                i_p, i_t = other, item - particles
            active, weights, pair_force, pair_stiffness, pair_damping = self._vertex_triangle(
                x, v, i_p, self.corners[i_t])
            if active and item < particles:
                self.vertex_force[i_p] += pair_force
                if ti.static(self.blocks):
                    self.vertex_stiffness[i_p] += pair_stiffness
                    self.vertex_damping[i_p] += pair_damping
            elif active:
                for c in ti.static(range(3)):
                    self.corner_force[i_t, c] -= weights[c] * pair_force
                    if ti.static(self.blocks):
                        self.corner_stiffness[i_t, c] += weights[c] ** 2 * pair_stiffness
                        self.corner_damping[i_t, c] += weights[c] ** 2 * pair_damping

    @ti.func
    def _edge_pass(self, x, v, e):
        """Edge e's ends' shares of the edge–edge forces with its candidate edges (each pair
        evaluated lower edge first)."""
        real = self.model.real
        for c in ti.static(range(2)):
            self.end_force[e, c] = ti.Vector.zero(real, 3)
            if ti.static(self.blocks):
                self.end_stiffness[e, c] = ti.Matrix.zero(real, 3, 3)
                self.end_damping[e, c] = ti.Matrix.zero(real, 3, 3)
        first_edge = self.model.particle_count + self.triangle_count
        for k in range(self.candidate_count[first_edge + e]):
            other = self.candidates[first_edge + e, k] - first_edge
            first, second = ti.min(e, other), ti.max(e, other)
            active, s, u, pair_force, pair_stiffness, pair_damping = self._edge_edge(
                x, v, self.ends[first], self.ends[second])
            if active:
                along, sign = s, real(1.0)
                if e != first:
                    along, sign = u, real(-1.0)
                shares = ti.Vector([1 - along, along], real)
                for c in ti.static(range(2)):
                    self.end_force[e, c] += sign * shares[c] * pair_force
                    if ti.static(self.blocks):
                        self.end_stiffness[e, c] += shares[c] ** 2 * pair_stiffness
                        self.end_damping[e, c] += shares[c] ** 2 * pair_damping

    @ti.func
    def _pair(self, mass, offset, relative_velocity):
        """The penalty between two points ``offset`` apart [m] (first minus second) with that
        relative velocity, for ``mass`` [kg]: (active, force on the first [N], its stiffness
        block −m·k̂·n·nᵀ and damping block), inactive beyond the thickness or when the normal
        force is clamped to 0 (leaving fast: its blocks would make release sticky)."""
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
        return active, force, stiffness, damping

    @ti.func
    def _vertex_triangle_offset(self, x, i_p, corners):
        """(barycentric weights of the point of the triangle of ``corners`` closest to particle
        i_p, the particle minus that point [m])."""
        a, b, c = x[corners[0]], x[corners[1]], x[corners[2]]
        weights = closest_on_triangle(x[i_p], a, b, c, self.model.real)
        return weights, x[i_p] - (weights[0] * a + weights[1] * b + weights[2] * c)

    @ti.func
    def _edge_edge_offset(self, x, first, second):
        """(s, u, the first edge's closest point minus the second's [m]) of two edges given by
        their particles."""
        a, b, c, d = x[first[0]], x[first[1]], x[second[0]], x[second[1]]
        s, u = closest_between_segments(a, b, c, d, self.model.real)
        return s, u, (a + s * (b - a)) - (c + u * (d - c))

    @ti.func
    def _vertex_triangle(self, x, v, i_p, corners):
        """Vertex i_p against the triangle of ``corners``: (active, barycentric weights of the
        closest point, force on the vertex, blocks)."""
        weights, offset = self._vertex_triangle_offset(x, i_p, corners)
        closest_velocity = weights[0] * v[corners[0]] + weights[1] * v[corners[1]] \
            + weights[2] * v[corners[2]]
        active, force, stiffness, damping = self._pair(
            self.model.particle_mass[i_p], offset, v[i_p] - closest_velocity)
        return active, weights, force, stiffness, damping

    @ti.func
    def _edge_edge(self, x, v, first, second):
        """Edge ``first`` (its two particles) against edge ``second``: (active, s, u, force on
        the first edge's closest point, blocks), with the four particles' mean mass."""
        s, u, offset = self._edge_edge_offset(x, first, second)
        velocity_first = (1 - s) * v[first[0]] + s * v[first[1]]
        velocity_second = (1 - u) * v[second[0]] + u * v[second[1]]
        mass = ti.static(self.model.particle_mass)
        mean_mass = 0.25 * (mass[first[0]] + mass[first[1]] + mass[second[0]] + mass[second[1]])
        active, force, stiffness, damping = self._pair(mean_mass, offset,
                                                       velocity_first - velocity_second)
        return active, s, u, force, stiffness, damping

    @ti.func
    def force(self, model, x, v, i_p, t):
        """The particle's own vertex–triangle forces, then its shares as a triangle corner and
        as an edge end, gathered in list order."""
        f = self.vertex_force[i_p]
        for k in range(self.triangle_start[i_p], self.triangle_start[i_p + 1]):
            f += self.corner_force[self.triangle_item[k], self.triangle_slot[k]]
        for k in range(self.edge_start[i_p], self.edge_start[i_p + 1]):
            f += self.end_force[self.edge_item[k], self.edge_slot[k]]
        return f

    @ti.func
    def local_jacobian(self, model, x, v, i_p, t, definite: ti.template()):
        """(∂f/∂x, ∂f/∂v) of particle i_p: its slots' blocks from the last ``prepare`` (the
        couplings between a pair's particles left out: module docstring)."""
        stiffness = self.vertex_stiffness[i_p]
        damping = self.vertex_damping[i_p]
        for k in range(self.triangle_start[i_p], self.triangle_start[i_p + 1]):
            stiffness += self.corner_stiffness[self.triangle_item[k], self.triangle_slot[k]]
            damping += self.corner_damping[self.triangle_item[k], self.triangle_slot[k]]
        for k in range(self.edge_start[i_p], self.edge_start[i_p + 1]):
            stiffness += self.end_stiffness[self.edge_item[k], self.edge_slot[k]]
            damping += self.end_damping[self.edge_item[k], self.edge_slot[k]]
        return stiffness, damping

    def frame_metrics(self, x: np.ndarray) -> dict:
        """Candidate pairs dropped from full lists since the start (0 unless ``CANDIDATES`` is
        too small for the scene: then contacts can be missed)."""
        return {"self_collision_overflow": int(self.overflow[None])}

    def stability_modes(self) -> list[tuple[float, float]]:
        """The penalty's mode, with up to ``CONTACTS_PER_PARTICLE`` contacts on one particle."""
        return [(self.stiffness * CONTACTS_PER_PARTICLE, self.damping_ratio)]
