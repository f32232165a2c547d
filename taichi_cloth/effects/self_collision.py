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

Candidate pairs: every pair within the reach (thickness + padding), in one compact list, rebuilt
only when the cloth has deformed by half the padding since the last build. Deformed, not moved:
distances between primitives do not change under a rigid motion, so the test takes the rigid
motion that best carries the build's positions onto the current ones (Kabsch: the polar
rotation of Σ x_i·(X_i − C)ᵀ, C their centroid) and compares each particle with where it would
carry it; if none is more than half the padding off, no pair missing from the list has closed
by more than the padding (a point of a triangle or segment is a convex combination of its
corners, so it moved no more than they did). A skirt turning with the dancer keeps its list.

The build (``effects/spatial_hash.py``, serial loops): the triangles' boxes grown by the reach on
a grid of cells the size of a mean box, each particle walking the triangles filed in its own cell
(the vertex–triangle pairs), and the edges' boxes grown by half the reach, each edge walking the
edges filed in its cells (the edge–edge pairs, each found once); then the exact distance. Pairs
are listed in particle order, then edge order, and every particle gets the list of its (pair,
corner) entries, in pair order.

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
from taichi_cloth.effects.penalty import (normal_force_magnitude, penalty_damping_block,
                                          penalty_force)
from taichi_cloth.effects.proximity import closest_between_segments, closest_on_triangle
from taichi_cloth.effects.spatial_hash import BoxGrid
from taichi_cloth.errors import InputError
from taichi_cloth.runtime import runs_on_cpu
from taichi_cloth.settings import setting
from taichi_cloth.uploads import upload

PAIRS_PER_ITEM = 8  # the list's capacity per particle and edge (more count as overflow)
PADDING = 1.0  # the list's padding in thicknesses: rebuilt after half of it is deformed
CONTACTS_PER_PARTICLE = 4  # the stiffness bound for dt = "auto": a vertex, corner and edge shares
VERTEX_TRIANGLE, EDGE_EDGE = 0, 1  # kinds of pairs


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
        triangles, edges = garment.triangles, garment.edges
        rest = np.linalg.norm(np.diff(garment.positions[edges], axis=1), axis=2)
        shortest = float(rest.min(initial=np.inf))
        if settings.thickness >= 0.5 * shortest:
            raise InputError(f"effects.self_collision.thickness: {settings.thickness:g} m must be "
                             f"below half the cloth's shortest edge, {shortest:g} m")
        self.thickness, self.stiffness = settings.thickness, settings.stiffness
        self.damping_ratio, self.friction = settings.damping, settings.friction
        self.padding = PADDING * settings.thickness  # m: the list holds pairs within reach
        self.reach = settings.thickness + self.padding  # m
        particles = model.particle_count
        self.triangle_count, self.edge_count = len(triangles), len(edges)
        self.triangle_boxes = BoxGrid(self.triangle_count, real)
        self.edge_boxes = BoxGrid(self.edge_count, real)
        self.corners = ti.Vector.field(3, ti.i32, self.triangle_count)
        self.ends = ti.Vector.field(2, ti.i32, self.edge_count)
        # the rebuild test: each particle's offset from the centroid at the last build
        self.built_offset = ti.Vector.field(3, real, particles)
        self.deformed = ti.field(real, ())  # m: the largest departure from the rigid motion
        self.stale = ti.field(ti.i32, ())  # whether this evaluation rebuilds the list
        self.rebuild_asked = ti.field(ti.i32, ())  # a rebuild at the next evaluation
        self.rebuilds = ti.field(ti.i32, ())  # builds since the start
        self.overflow = ti.field(ti.i32, ())  # candidate pairs dropped from a full list, ever
        self.capacity = PAIRS_PER_ITEM * (particles + self.edge_count)
        self.pair_count = ti.field(ti.i32, ())
        self.pair_kind = ti.field(ti.i32, self.capacity)
        self.pair_particles = ti.Vector.field(4, ti.i32, self.capacity)
        # per evaluation: each pair's force on its first point, its blocks, its particles' shares
        self.pair_force = ti.Vector.field(3, real, self.capacity)
        self.pair_share = ti.Vector.field(4, real, self.capacity)
        if self.blocks:
            self.pair_stiffness = ti.Matrix.field(3, 3, real, self.capacity)
            self.pair_damping = ti.Matrix.field(3, 3, real, self.capacity)
        # per particle, CSR: its (pair, slot) entries as 4·pair + slot, in pair order
        self.entry_start = ti.field(ti.i32, particles + 1)
        self.entry_fill = ti.field(ti.i32, particles)
        self.entry = ti.field(ti.i32, 4 * self.capacity)
        self._host = (triangles, edges)

    def upload(self) -> None:
        triangles, edges = self._host
        upload([(self.corners, triangles.astype(np.int32)), (self.ends, edges.astype(np.int32))])
        self.rebuild_asked[None] = 1

    @ti.func
    def prepare(self, x, v, t):
        """The candidate list, rebuilt when the cloth has deformed by half the padding since the
        last build, then every pair's force and blocks over it (module docstring)."""
        ti.loop_config(serialize=True)
        for _ in range(1):  # serial: a reduction whose order decides the rebuild
            self._measure_deformation(x)
        ti.loop_config(serialize=True)
        for _ in range(1):  # serial: appends in a fixed order
            if self.stale[None]:
                self._build(x)
        if ti.static(self.serial):
            ti.loop_config(serialize=True)
        for k in range(self.pair_count[None]):
            self._evaluate(x, v, k)

    @ti.func
    def _measure_deformation(self, x):
        """``deformed``: the largest distance between a particle and where the rigid motion that
        best fits the cloth since the build carries its build position (module docstring);
        ``stale`` when it exceeds half the padding or a rebuild was asked."""
        real = self.model.real
        particles = self.model.particle_count
        centroid = ti.Vector.zero(real, 3)
        covariance = ti.Matrix.zero(real, 3, 3)
        for i in range(particles):
            centroid += x[i]
            covariance += x[i].outer_product(self.built_offset[i])
        centroid /= particles
        rotation, _ = ti.polar_decompose(covariance)
        deformed = real(0.0)
        for i in range(particles):
            deformed = ti.max(deformed,
                              (x[i] - centroid - rotation @ self.built_offset[i]).norm())
        self.deformed[None] = deformed
        self.stale[None] = int(self.rebuild_asked[None] != 0
                               or not deformed <= real(0.5 * self.padding))

    @ti.func
    def _build(self, x):
        """The candidate pairs at x and each particle's entries (module docstring)."""
        real = self.model.real
        particles = self.model.particle_count
        self.rebuild_asked[None] = 0
        self.rebuilds[None] += 1
        centroid = ti.Vector.zero(real, 3)
        for i in range(particles):
            centroid += x[i]
        centroid /= particles
        for i in range(particles):
            self.built_offset[i] = x[i] - centroid
        self.pair_count[None] = 0
        reach = real(self.reach)
        self.triangle_boxes.build(self._box_size(x, self.triangle_boxes, reach, 0))
        self.edge_boxes.build(self._box_size(x, self.edge_boxes, 0.5 * reach, 1))
        for i_p in range(particles):
            self._list_vertex_triangle(x, i_p)
        for e in range(self.edge_count):
            self._list_edge_edge(x, e)
        self._list_entries()

    @ti.func
    def _box_size(self, x, grid: ti.template(), grow, edges: ti.template()):
        """Each triangle's (or, with ``edges``, each edge's) box at x grown by ``grow`` [m] into
        ``grid``; returns their mean largest side [m], the grid's cell."""
        real = self.model.real
        total = real(0.0)
        for i in range(grid.count):
            low = ti.Vector.zero(real, 3)
            high = ti.Vector.zero(real, 3)
            if ti.static(edges):
                a, b = x[self.ends[i][0]], x[self.ends[i][1]]
                low, high = ti.min(a, b), ti.max(a, b)
            else:
                a, b, c = x[self.corners[i][0]], x[self.corners[i][1]], x[self.corners[i][2]]
                low, high = ti.min(ti.min(a, b), c), ti.max(ti.max(a, b), c)
            grid.lower[i] = low - grow
            grid.upper[i] = high + grow
            total += (grid.upper[i] - grid.lower[i]).max()
        return total / ti.max(grid.count, 1)

    @ti.func
    def _append(self, kind, particles):
        """A pair at the end of the list (counted as overflow when it is full)."""
        k = self.pair_count[None]
        if k < self.capacity:
            self.pair_kind[k] = kind
            self.pair_particles[k] = particles
            self.pair_count[None] = k + 1
        else:
            self.overflow[None] += 1

    @ti.func
    def _list_vertex_triangle(self, x, i_p):
        """Particle i_p's pairs: the triangles filed in its cell whose grown box holds it, that
        it is not a corner of, within the reach."""
        grid = self.triangle_boxes
        if grid.filed[None]:
            cell = grid.cell_of(x[i_p])
            bucket = grid.bucket(cell)
            for k in range(grid.bucket_start[bucket], grid.bucket_start[bucket + 1]):
                t = grid.entry_box[k]
                # nested tests: a kernel's ``and`` evaluates both sides
                if (grid.entry_cell[k] == cell).all():
                    if (grid.lower[t] <= x[i_p]).all() and (x[i_p] <= grid.upper[t]).all():
                        corners = self.corners[t]
                        if (corners != i_p).all():
                            if self._vertex_triangle_offset(x, i_p, corners)[1].norm() \
                                    <= self.model.real(self.reach):
                                self._append(VERTEX_TRIANGLE, ti.Vector(
                                    [i_p, corners[0], corners[1], corners[2]]))

    @ti.func
    def _list_edge_edge(self, x, e):
        """Edge e's pairs with the edges of higher index whose grown boxes overlap its own (each
        pair in the first cell both span), that share no particle with it, within the reach."""
        grid = self.edge_boxes
        if grid.filed[None]:
            ends = self.ends[e]
            low, high = grid.low_cell[e], grid.high_cell[e]
            for cell in ti.grouped(ti.ndrange((low[0], high[0] + 1), (low[1], high[1] + 1),
                                              (low[2], high[2] + 1))):
                bucket = grid.bucket(cell)
                first, end = grid.bucket_start[bucket], grid.bucket_start[bucket + 1]
                for back in range(end - first):  # a bucket's boxes ascend: higher ones first
                    k = end - 1 - back
                    other = grid.entry_box[k]
                    if other <= e:
                        break
                    # nested tests: a kernel's ``and`` evaluates both sides
                    if (grid.entry_cell[k] == cell).all():
                        if grid.overlap(e, other) \
                                and (grid.first_common_cell(e, other) == cell).all():
                            other_ends = self.ends[other]
                            if other_ends[0] != ends[0] and other_ends[0] != ends[1] \
                                    and other_ends[1] != ends[0] and other_ends[1] != ends[1]:
                                if self._edge_edge_offset(x, ends, other_ends)[2].norm() \
                                        <= self.model.real(self.reach):
                                    self._append(EDGE_EDGE, ti.Vector(
                                        [ends[0], ends[1], other_ends[0], other_ends[1]]))

    @ti.func
    def _list_entries(self):
        """Every particle's (pair, slot) entries, in pair order: counted, prefix-summed, filled."""
        particles = self.model.particle_count
        for i in range(particles):
            self.entry_fill[i] = 0
        for k in range(self.pair_count[None]):
            for slot in ti.static(range(4)):
                self.entry_fill[self.pair_particles[k][slot]] += 1
        self.entry_start[0] = 0
        for i in range(particles):
            self.entry_start[i + 1] = self.entry_start[i] + self.entry_fill[i]
            self.entry_fill[i] = self.entry_start[i]
        for k in range(self.pair_count[None]):
            for slot in ti.static(range(4)):
                i = self.pair_particles[k][slot]
                self.entry[self.entry_fill[i]] = 4 * k + slot
                self.entry_fill[i] += 1

    @ti.func
    def _evaluate(self, x, v, k):
        """Pair k's force on its first point, its blocks and its particles' shares (the share
        of a corner or end: its weight, negative on the second primitive)."""
        real = self.model.real
        ids = self.pair_particles[k]
        active, force, stiffness, damping = 0, ti.Vector.zero(real, 3), \
            ti.Matrix.zero(real, 3, 3), ti.Matrix.zero(real, 3, 3)
        share = ti.Vector.zero(real, 4)
        if self.pair_kind[k] == VERTEX_TRIANGLE:
            corners = ti.Vector([ids[1], ids[2], ids[3]])
            active, weights, force, stiffness, damping = self._vertex_triangle(x, v, ids[0],
                                                                               corners)
            share = ti.Vector([1.0, -weights[0], -weights[1], -weights[2]], real)
        else:
            active, s, u, force, stiffness, damping = self._edge_edge(
                x, v, ti.Vector([ids[0], ids[1]]), ti.Vector([ids[2], ids[3]]))
            share = ti.Vector([1 - s, s, u - 1, -u], real)
        if not active:
            share = ti.Vector.zero(real, 4)
            force = ti.Vector.zero(real, 3)
        self.pair_force[k] = force
        self.pair_share[k] = share
        if ti.static(self.blocks):
            self.pair_stiffness[k] = stiffness
            self.pair_damping[k] = damping

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
        """The particle's shares of its pairs' forces, gathered in list order."""
        f = ti.Vector.zero(model.real, 3)
        for k in range(self.entry_start[i_p], self.entry_start[i_p + 1]):
            pair, slot = self.entry[k] // 4, self.entry[k] % 4
            f += self.pair_share[pair][slot] * self.pair_force[pair]
        return f

    @ti.func
    def local_jacobian(self, model, x, v, i_p, t, definite: ti.template()):
        """(∂f/∂x, ∂f/∂v) of particle i_p: its shares² of its pairs' blocks from the last
        ``prepare`` (the couplings between a pair's particles left out: module docstring)."""
        stiffness = ti.Matrix.zero(model.real, 3, 3)
        damping = ti.Matrix.zero(model.real, 3, 3)
        if ti.static(self.blocks):
            for k in range(self.entry_start[i_p], self.entry_start[i_p + 1]):
                pair, slot = self.entry[k] // 4, self.entry[k] % 4
                weight = self.pair_share[pair][slot] ** 2
                stiffness += weight * self.pair_stiffness[pair]
                damping += weight * self.pair_damping[pair]
        return stiffness, damping

    def ask_rebuild(self) -> None:
        """Rebuild the candidate list at the next evaluation (``bench`` times the build)."""
        self.rebuild_asked[None] = 1

    def frame_metrics(self, x: np.ndarray) -> dict:
        """Candidate pairs dropped from the full list since the start (0 unless
        ``PAIRS_PER_ITEM`` is too small for the scene: then contacts can be missed), the list's
        builds since the start and its pairs at the last build."""
        return {"self_collision_overflow": int(self.overflow[None]),
                "self_collision_builds": int(self.rebuilds[None]),
                "self_collision_pairs": int(self.pair_count[None])}

    def stability_modes(self) -> list[tuple[float, float]]:
        """The penalty's mode, with up to ``CONTACTS_PER_PARTICLE`` contacts on one particle."""
        return [(self.stiffness * CONTACTS_PER_PARTICLE, self.damping_ratio)]
