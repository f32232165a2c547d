"""Self-collision's candidate pairs: every vertex–triangle and edge–edge pair of the cloth within
a reach (thickness + padding), in one compact list that ``effects/self_collision.py`` evaluates at
every force evaluation (docs/physics.md, "Self-collision").

Rebuilt only when the cloth has deformed by half the padding since the last build. Deformed, not
moved: distances between primitives do not change under a rigid motion, so the test takes the
rigid motion that best carries the build's positions onto the current ones (Kabsch 1976: the
polar rotation of Σ x_i·(X_i − C)ᵀ, C their centroid) and compares each particle with where it
would carry it; if none is more than half the padding off, no pair missing from the list has
closed by more than the padding (a point of a triangle or segment is a convex combination of its
corners, so it moved no more than they did). A skirt turning with the dancer keeps its list.

The build: each triangle's box grown by the reach and each edge's by half of it, and the
cloth's patches with their partners (``effects/mesh_patches.py``: the pairs of patches that may
hold layers of cloth, flat neighbourhoods left out); each particle walks the triangles of its
home patch's partners (the vertex–triangle pairs: a vertex and a triangle it is not a corner of,
whose box holds it, and that were not within the thickness in the rest shape,
``rest_neighbours.py``; a partner whose box is too far from the particle is skipped whole), and
each pair of partners once (from the higher) their home edges against each other (the edge–edge
pairs of edges sharing no particle, whose boxes overlap, and not within the thickness at the
start, into the row of the lower edge; each
patch's edges are first tested against the region both patches' boxes share, and only those
that meet it against each other); then the exact distance. All on one thread: each particle's
and edge's finds in a row of its own (up to ``FOUND_PER_ITEM``), then listed in particle order,
then edge order (up to ``PAIRS_PER_ITEM`` per particle and edge; ``overflow`` counts any
dropped). Every particle gets the CSR list of its (pair, corner) entries as 4·pair + corner, in
pair order.

Each find keeps its pair's side record beside it (``pair_records.PairRecords``, mixed in).
"""

import numpy as np
import taichi as ti

from taichi_cloth.effects.pair_records import PairRecords
from taichi_cloth.effects.proximity import EDGE_EDGE, VERTEX_TRIANGLE
from taichi_cloth.effects.mesh_patches import MeshPatches
from taichi_cloth.effects.rest_neighbours import rest_neighbours

# Capacities: with the reach near its largest for a regular mesh (thickness just below half its
# edge), a sheet folded onto itself, the layers a thickness apart and jittered by a quarter of
# it, finds up to 29 pairs in one walk and 11 per particle and edge in all
# (tests/test_self_collision.py); a third layer adds about half as many. More count as overflow,
# which the run reports.
PAIRS_PER_ITEM = 24  # the list's capacity per particle and edge
FOUND_PER_ITEM = 48  # the pairs one particle's or edge's walk may find


@ti.data_oriented
class CandidatePairs(PairRecords):
    """The vertex–triangle and edge–edge pairs of a model's cloth within ``reach`` = ``thickness``
    + ``padding`` [m], kept while the cloth deforms by less than half of ``padding`` (module
    docstring); ``thickness`` is also the records' margin (``PairRecords._consider``)."""

    def __init__(self, model, thickness: float, padding: float):
        garment = model.garment
        self.model = model
        self.thickness, self.padding = thickness, padding
        self.reach = thickness + padding
        particles = model.particle_count
        self.triangle_count, self.edge_count = len(garment.triangles), len(garment.edges)
        # boxes [m]: a triangle's grown by the reach, an edge's by half of it
        self.triangle_lower, self.triangle_upper, self.edge_lower, self.edge_upper = (
            ti.Vector.field(3, model.real, count)
            for count in (self.triangle_count, self.triangle_count, self.edge_count,
                          self.edge_count))
        self.patches = MeshPatches(model, self.reach)
        self.corners = ti.Vector.field(3, ti.i32, self.triangle_count)
        self.ends = ti.Vector.field(2, ti.i32, self.edge_count)
        # the rebuild test: each particle's offset from the centroid at the last build
        self.built_offset = ti.Vector.field(3, model.real, particles)
        self.centroid = ti.Vector.field(3, model.real, ())  # m: of the last evaluation's x
        self.rotation = ti.Matrix.field(3, 3, model.real, ())  # the last fit's
        self.deformed = ti.field(model.real, ())  # m: the largest departure from a rigid motion
        self.stale = ti.field(ti.i32, ())  # whether this evaluation rebuilds the list
        self.rebuild_asked = ti.field(ti.i32, ())  # a rebuild at the next evaluation
        self.rebuilds = ti.field(ti.i32, ())  # builds since the start
        self.overflow = ti.field(ti.i32, ())  # candidate pairs dropped from a full list, ever
        self.capacity = PAIRS_PER_ITEM * (particles + self.edge_count)
        self.pair_count = ti.field(ti.i32, ())
        self.pair_kind = ti.field(ti.i32, self.capacity)
        self.pair_particles = ti.Vector.field(4, ti.i32, self.capacity)
        # each walk's finds: a particle's triangles, then an edge's edges of higher index
        self.found = ti.field(ti.i32, (particles + self.edge_count, FOUND_PER_ITEM))
        self.found_count = ti.field(ti.i32, particles + self.edge_count)
        self.pair_slot = ti.field(ti.i32, self.capacity)  # its find: row·FOUND_PER_ITEM + place
        self.allocate_records()
        self.entry_start = ti.field(ti.i32, particles + 1)
        self.entry_fill = ti.field(ti.i32, particles)
        self.entry = ti.field(ti.i32, 4 * self.capacity)
        # the pairs left out for good (``rest_neighbours``): per row (a particle's, then an
        # edge's, as ``found``) the triangles or edges of higher index, CSR
        vertex_triangle, edge_edge = rest_neighbours(garment.positions, garment.triangles,
                                                     garment.edges, thickness)
        rows = np.concatenate([vertex_triangle[:, 0], particles + edge_edge[:, 0]])
        others = np.concatenate([vertex_triangle[:, 1], edge_edge[:, 1]])
        start = np.cumsum(np.bincount(rows, minlength=particles + self.edge_count))
        self.rest_start = ti.field(ti.i32, particles + self.edge_count + 1)
        self.rest_other = ti.field(ti.i32, max(len(others), 1))
        self._host = (garment.triangles, garment.edges, np.concatenate([[0], start]),
                      others if len(others) else np.array([-1]))

    def upload(self) -> None:
        triangles, edges, rest_start, rest_other = self._host
        self.model.uploads.add([(self.corners, triangles.astype(np.int32)),
                                (self.ends, edges.astype(np.int32)),
                                (self.rest_start, rest_start.astype(np.int32)),
                                (self.rest_other, rest_other.astype(np.int32)),
                                (self.rotation, np.eye(3)), (self.rebuild_asked, np.array(1))])
        self.patches.upload()

    # what the list carries from step to step: the finds with their records (the list and the
    # entries follow from them), the positions the records and the rebuild test refer to
    MEMORY_FIELDS = ("found_count", "found", "found_record", "reference_x", "last_x",
                     "built_offset", "centroid", "rotation", "committed", "rebuild_asked",
                     "rebuilds", "overflow")

    def memory(self) -> dict:
        """Host copies of ``MEMORY_FIELDS`` by name (a checkpoint)."""
        return {name: getattr(self, name).to_numpy() for name in self.MEMORY_FIELDS}

    def restore_memory(self, memory: dict) -> None:
        """Put back what ``memory`` returned, and the list and entries gathered from its finds
        as the build gathered them (the same pairs in the same order)."""
        for name in self.MEMORY_FIELDS:
            getattr(self, name).from_numpy(memory[name])
        self._relist()
        self.overflow.from_numpy(memory["overflow"])  # counted once, by the run that listed

    @ti.kernel
    def _relist(self):
        self._list(True)

    def ask_rebuild(self) -> None:
        """Rebuild the list at the next ``update`` (``bench`` times the build)."""
        self.rebuild_asked[None] = 1

    @ti.func
    def update(self, x):
        """The list at positions x [m]: measured against the last build and, when stale, built
        again, all on one thread: the boxes and the patches' cones and sweep order, each patch's
        partners, each particle's walk into its row, each pair of partners' edges into the edges'
        rows (all started first, their crossed pairs kept after), then the list and the entries
        in particle and edge order. (A hand-off to a second thread costs ~50 µs and the second
        thread wakes ~0.3 ms late on the 2-core machines measured, longer than these loops take:
        docs/performance.md, "The rebuild on one thread".)"""
        ti.loop_config(serialize=True)
        for _ in range(1):
            self._measure_deformation(x, True)
        ti.loop_config(serialize=True)
        for _ in range(1):
            if self.stale[None]:
                self._build_boxes(x)
                self.patches.list_partners(self.overflow)
                for i_p in range(self.model.particle_count):
                    self._list_vertex_triangle(x, i_p)
                for e in range(self.edge_count):
                    self._start_row(self.model.particle_count + e)
                for patch in range(self.patches.count):
                    self._list_edge_edge(x, patch)
                for e in range(self.edge_count):
                    self._keep_crossed(self.model.particle_count + e)
        self._list(self.stale[None])

    @ti.func
    def _list(self, listing):
        """When ``listing``, the list and the entries gathered from the rows of finds, on one
        thread (``_gather_found``, ``_list_entries``)."""
        ti.loop_config(serialize=True)
        for _ in range(1):
            if listing:
                self._gather_found()
                self._list_entries()

    @ti.func
    def _measure_deformation(self, x, fit: ti.template()):
        """``deformed``: the largest distance between a particle and where a rigid motion
        carries its build position (module docstring): with ``fit``, the one that best fits the
        cloth since the build (kept in ``rotation``); without, the last fit's rotation about
        today's centroid (any rotation keeps the bound true, and the step's end is close to the
        evaluation that fitted it; no SVD inlined a second time). ``stale`` when it exceeds
        half the padding or a rebuild was asked."""
        real = self.model.real
        particles = self.model.particle_count
        centroid = ti.Vector.zero(real, 3)
        covariance = ti.Matrix.zero(real, 3, 3)
        anchor = x[0]  # Σ (x_i − anchor)·(X_i − C)ᵀ: C's rounding not scaled by |x| far away
        for i in range(particles):
            centroid += x[i]
            if ti.static(fit):
                covariance += (x[i] - anchor).outer_product(self.built_offset[i])
        centroid /= particles
        self.centroid[None] = centroid
        if ti.static(fit):
            self.rotation[None], _ = ti.polar_decompose(covariance)
        rotation = self.rotation[None]
        deformed = real(0.0)
        for i in range(particles):
            deformed = ti.max(deformed,
                              (x[i] - centroid - rotation @ self.built_offset[i]).norm())
        self.deformed[None] = deformed
        self.stale[None] = int(self.rebuild_asked[None] != 0
                               or not deformed <= real(0.5 * self.padding))

    @ti.func
    def _build_boxes(self, x):
        """The build's reference positions (offsets from the centroid that the rebuild test
        took of x), the triangles' and edges' boxes at x, and the patches' cones and boxes,
        sorted for the sweep (``MeshPatches``). On one thread: a hand-off to the thread pool
        cost more than this work (~0.1 ms on ``twirl``)."""
        real = self.model.real
        self.rebuild_asked[None] = 0
        self.rebuilds[None] += 1
        for i in range(self.model.particle_count):
            self.built_offset[i] = x[i] - self.centroid[None]
        reach = real(self.reach)
        for t in range(self.triangle_count):
            a, b, c = x[self.corners[t][0]], x[self.corners[t][1]], x[self.corners[t][2]]
            self.triangle_lower[t] = ti.min(ti.min(a, b), c) - reach
            self.triangle_upper[t] = ti.max(ti.max(a, b), c) + reach
        for e in range(self.edge_count):
            a, b = x[self.ends[e][0]], x[self.ends[e][1]]
            self.edge_lower[e] = ti.min(a, b) - 0.5 * reach
            self.edge_upper[e] = ti.max(a, b) + 0.5 * reach
        for patch in range(self.patches.count):
            self.patches.cone(x, self.corners, patch)
        for patch in range(self.patches.count):
            self.patches.neighbourhood_cone(patch)
        self.patches.sort_boxes()

    @ti.func
    def _find(self, owner, other, record):
        """Item ``other`` with its side ``record`` into walk ``owner``'s row of ``found`` (counted
        as overflow when full)."""
        n = self.found_count[owner]
        if n < FOUND_PER_ITEM:
            self.found[owner, n] = other
            self.found_record[owner, n] = record
            self.found_count[owner] = n + 1
        else:
            ti.atomic_add(self.overflow[None], 1)

    @ti.func
    def _pair_of(self, owner, other):
        """(kind, its four particles) of the pair that walk ``owner`` found as item ``other``:
        a particle and a triangle, or an edge and an edge."""
        particles = self.model.particle_count
        kind, ids = VERTEX_TRIANGLE, ti.Vector([0, 0, 0, 0])
        if owner < particles:
            corners = self.corners[other]
            ids = ti.Vector([owner, corners[0], corners[1], corners[2]])
        else:
            ends, other_ends = self.ends[owner - particles], self.ends[other]
            kind = EDGE_EDGE
            ids = ti.Vector([ends[0], ends[1], other_ends[0], other_ends[1]])
        return kind, ids

    @ti.func
    def _gather_found(self):
        """The list: every particle's finds, then every edge's, as pairs of four particles
        (counted as overflow past the list's capacity)."""
        self.pair_count[None] = 0
        for owner in range(self.model.particle_count + self.edge_count):
            for n in range(self.found_count[owner]):
                kind, ids = self._pair_of(owner, self.found[owner, n])
                k = self.pair_count[None]
                if k < self.capacity:
                    self.pair_kind[k] = kind
                    self.pair_particles[k] = ids
                    self.pair_slot[k] = owner * FOUND_PER_ITEM + n
                    self.pair_count[None] = k + 1
                else:
                    self.overflow[None] += 1

    @ti.func
    def _list_vertex_triangle(self, x, i_p):
        """Particle i_p's pairs: the triangles of its home patch's partners whose box holds it,
        that it is not a corner of, within the reach, and its crossed ones: its row of
        ``found``."""
        patches = self.patches
        self._start_row(i_p)
        home = patches.particle_home[i_p]
        # the reach's other half and a tenth of it: rounding cannot then put a point of a
        # triangle's box (its corners' least less the reach) outside the patch's box grown so
        beyond = self.model.real(0.6 * self.reach)
        if home >= 0:
            for n in range(patches.partner_count[home]):
                partner = patches.partner[home, n]
                # the partner's box, grown by half the reach, holds its triangles' boxes shrunk
                # by the other half: a particle outside the box grown by more is in none
                first = patches.triangle_start[partner + 1]
                if (patches.lower[partner] - beyond <= x[i_p]).all() \
                        and (x[i_p] <= patches.upper[partner] + beyond).all():
                    first = patches.triangle_start[partner]
                for k in range(first, patches.triangle_start[partner + 1]):
                    t = patches.triangle[k]
                    corners = self.corners[t]
                    # one test of all, evaluated whole (as the edges' below)
                    if (self.triangle_lower[t] <= x[i_p]).all() \
                            and (x[i_p] <= self.triangle_upper[t]).all() \
                            and (corners != i_p).all():
                        if self._left_out(i_p, t) == 0:
                            self._consider(x, i_p, t, ti.Vector([i_p, corners[0], corners[1],
                                                                 corners[2]]), VERTEX_TRIANGLE)
        self._keep_crossed(i_p)

    @ti.func
    def _list_edge_edge(self, x, p):
        """The edge–edge pairs between patch p's home edges and those of each of its partners q ≤ p
        (each pair of patches walked once, from the higher: a full partner list keeps the lowest
        partners): each two edges whose boxes overlap, that share no particle, within the reach,
        into the row of the lower (its rows started and their crossed pairs kept before and after
        all patches' walks). Only the edges of either patch whose boxes meet the region that both
        patches' boxes share are tested against each other (each patch's box holds its edges')."""
        patches = self.patches
        particles = self.model.particle_count
        first, end = patches.edge_start[p], patches.edge_start[p + 1]
        for n in range(patches.partner_count[p] * int(first < end)):  # (a patch may own none)
            q = patches.partner[p, n]
            q_first, q_end = patches.edge_start[q], patches.edge_start[q + 1]
            if q <= p and q_first < q_end:
                low = ti.max(patches.lower[p], patches.lower[q])
                high = ti.min(patches.upper[p], patches.upper[q])
                meeting = 0  # bit k: p's edge first + k meets the region
                for k in range(first, end):
                    e = patches.edge[k]
                    meeting |= int((self.edge_lower[e] <= high).all()
                                   and (low <= self.edge_upper[e]).all()) << (k - first)
                theirs = 0  # bit k: q's edge q_first + k meets the region
                for k in range(q_first, q_end):
                    other = patches.edge[k]
                    theirs |= int((self.edge_lower[other] <= high).all()
                                  and (low <= self.edge_upper[other]).all()) << (k - q_first)
                while theirs != 0:
                    highest = 31 - ti.math.clz(theirs)
                    theirs ^= 1 << highest
                    other = patches.edge[q_first + highest]
                    other_ends = self.ends[other]
                    near = 0  # bit k: p's edge first + k is a candidate with ``other``
                    for k in range(first, end):
                        e = patches.edge[k]
                        ends = self.ends[e]
                        near |= int((meeting >> (k - first)) & 1 == 1 and (q != p or e < other)
                                    and (self.edge_lower[e] <= self.edge_upper[other]).all()
                                    and (self.edge_lower[other] <= self.edge_upper[e]).all()
                                    and other_ends[0] != ends[0] and other_ends[0] != ends[1]
                                    and other_ends[1] != ends[0] and other_ends[1] != ends[1]) \
                            << (k - first)
                    while near != 0:
                        lowest = near & -near
                        near ^= lowest
                        e = patches.edge[first + 31 - ti.math.clz(lowest)]
                        low_edge, high_edge = ti.min(e, other), ti.max(e, other)
                        ends, high_ends = self.ends[low_edge], self.ends[high_edge]
                        if self._left_out(particles + low_edge, high_edge) == 0:
                            self._consider(x, particles + low_edge, high_edge, ti.Vector(
                                [ends[0], ends[1], high_ends[0], high_ends[1]]), EDGE_EDGE)

    @ti.func
    def _left_out(self, row, other):
        """Whether the pair of row ``row`` (a particle, or particles + an edge) with triangle or
        edge ``other`` was within the thickness in the rest shape (``rest_neighbours``)."""
        left_out = 0
        for k in range(self.rest_start[row], self.rest_start[row + 1]):
            left_out |= int(self.rest_other[k] == other)
        return left_out

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

