"""Self-collision's broad phase over patches: the cloth's triangles cut once into small connected
patches, and at every build of the candidate list (``effects/candidate_pairs.py``) each patch's
box and cone of normals, then each patch's partners: the patches whose boxes come within the
reach of its own and that may hold a layer of cloth against it (docs/physics.md, "Patches and
their normal cones").

A stretch of cloth whose normals all lie within a cone of half-angle α < 90° about an axis is a
height field over the plane across that axis (Volino & Magnenat-Thalmann 1994, "Efficient
self-collision detection on smoothly discretized surface animations using geometrical shape
regularity"; Provot 1997, "Collision and self-collision handling in cloth model dedicated to
design garments"): it cannot lie on itself. Two of its points at a distance d are at most
d / cos α apart along it (its slope is at most α), so with α = ``FLAT_HALF_ANGLE`` (60°) a pair
within the thickness h is within 2h along the cloth: neighbours, not layers. Such pairs are left
out of the list:

- a patch with itself, when its own cone is flat;
- two patches that share a particle, when the cone holding both of theirs is flat;
- two patches that share a particle with a common neighbour, when the cone holding the cones of
  both patches' neighbourhoods (a patch and the patches sharing a particle with it) is flat.

Every other pair of patches whose boxes (grown by half the reach) overlap is a pair of partners,
walked primitive by primitive. (The height-field argument also needs the region's outline, seen
along the axis, not to overlap itself, which Volino and Provot test; a nearly inextensible cloth
this flat, a few patches across, cannot overlap itself that way, and the outline is not tested.)
The overlapping boxes are found by sweep and prune (Baraff 1992, "Dynamic simulation of
non-penetrating rigid bodies", PhD thesis; Cohen et al. 1995, "I-COLLIDE"): the patches sorted by
their boxes' lower bound along one axis, by insertion from the last build's order, each meets
those after it until one starts past its end.

Cut once, on the host (``cut_patches``): breadth-first over triangles sharing an edge, from the
lowest unassigned one, up to ``PATCH_TRIANGLES`` each; each triangle's normal is turned to agree
with its neighbours' (``orient``), so the cones do not depend on the winding of the garment's
file. Each particle and edge belongs to the patch of the first triangle it is part of (its
home): a pair is walked from its particle's or first edge's home patch, through that patch's
partners.
"""

import collections
import math

import numpy as np
import taichi as ti

PATCH_TRIANGLES = 8  # triangles per patch at most: two quads by two on a grid
FLAT_HALF_ANGLE = math.radians(60.0)  # α: a cone of normals this wide or less is flat
SWEEP_AXIS_SWITCH = 1.25  # the sweep's axis changes to one whose spread is this much wider
MOST_PARTNERS = 512  # partners a patch may have (or every patch, when fewer); more count as the
# list's overflow
NOT_FLAT = -2.0  # the room's cosine of a cone wider than α
NOT_NEAR, SHARES_PARTICLE, SHARES_NEIGHBOUR = 0, 1, 2  # how two patches are related


def cut_patches(triangles: np.ndarray, edges: np.ndarray, particle_count: int) -> dict:
    """The patches of a mesh of ``triangles`` (T, 3) with ``edges`` (E, 2), the triangles'
    edges (module docstring): each triangle's patch and its orientation (``orient``), each
    particle's and edge's home patch (−1 for a particle of no triangle), and each patch's near
    patches with how they are related (``SHARES_PARTICLE`` or ``SHARES_NEIGHBOUR``),
    ascending."""
    triangles = np.asarray(triangles, np.int64)
    by_edge = collections.defaultdict(list)
    for t, corners in enumerate(triangles):
        for k in range(3):
            a, b = corners[k], corners[(k + 1) % 3]
            by_edge[(min(a, b), max(a, b))].append(t)
    beside = [[] for _ in triangles]
    for sharing in by_edge.values():
        for t in sharing:
            beside[t].extend(u for u in sharing if u != t)
    sign = orient(triangles, beside)
    patch = np.full(len(triangles), -1, np.int64)
    count = 0
    for seed in range(len(triangles)):
        if patch[seed] >= 0:
            continue
        queue, size = collections.deque([seed]), 0
        while queue and size < PATCH_TRIANGLES:
            t = queue.popleft()
            if patch[t] < 0:
                patch[t] = count
                size += 1
                queue.extend(u for u in sorted(beside[t]) if patch[u] < 0)
        count += 1
    particle_home = np.full(particle_count, -1, np.int64)
    patches_of_particle = [set() for _ in range(particle_count)]
    for t in range(len(triangles) - 1, -1, -1):  # the first triangle's patch written last
        particle_home[triangles[t]] = patch[t]
        for i in triangles[t]:
            patches_of_particle[i].add(int(patch[t]))
    edge_home = np.array([patch[by_edge[(min(a, b), max(a, b))][0]]
                          for a, b in np.asarray(edges, np.int64)], np.int64)
    sharing_particle = [set() for _ in range(count)]
    for patches in patches_of_particle:
        for p in patches:
            sharing_particle[p] |= patches
    near = []
    for p in range(count):
        first = sharing_particle[p] - {p}
        second = set().union(*(sharing_particle[q] for q in first)) - first - {p}
        near.append(sorted([(q, SHARES_PARTICLE) for q in first]
                           + [(q, SHARES_NEIGHBOUR) for q in second]))
    return {"triangle_patch": patch, "triangle_sign": sign, "particle_home": particle_home,
            "edge_home": edge_home, "near": near, "count": count}


def orient(triangles: np.ndarray, beside: list) -> np.ndarray:
    """±1 per triangle: the sign that turns its normal (from its corners' order) to agree with
    its neighbours', breadth-first over triangles sharing an edge from the lowest of each
    connected piece (+1). A neighbour that runs the shared edge the same way is wound the other
    way. The cones of normals then do not depend on the mesh's winding, which a garment's file
    need not keep consistent (a non-orientable piece keeps the first sign each triangle gets)."""
    sign = np.zeros(len(triangles), np.int64)

    def runs(t, a, b):
        corners = list(triangles[t])
        return corners[(corners.index(a) + 1) % 3] == b

    for seed in range(len(triangles)):
        if sign[seed]:
            continue
        sign[seed] = 1
        queue = collections.deque([seed])
        while queue:
            t = queue.popleft()
            for u in sorted(beside[t]):
                if not sign[u]:
                    a, b = sorted(set(triangles[t]) & set(triangles[u]))[:2]
                    sign[u] = -sign[t] if runs(t, a, b) == runs(u, a, b) else sign[t]
                    queue.append(u)
    return sign


def members(home: np.ndarray, count: int) -> tuple[np.ndarray, np.ndarray]:
    """CSR of each patch's members, ascending: (start (count + 1), the indices of ``home``, the
    patch of each triangle or edge)."""
    order = np.argsort(home, kind="stable")
    start = np.zeros(count + 1, np.int64)
    np.cumsum(np.bincount(home, minlength=count), out=start[1:])
    return start, order


@ti.func
def room_less_angle(room, cosine):
    """(cos, sin) of room − θ for a room (cos, sin) in [0, α] and an angle θ ∈ [0, π] of cosine
    ``cosine``: negative (sin < 0) when θ is wider than the room. (With the room α itself: the
    room α − θ left by a cone of half-angle θ.)"""
    sine = ti.sqrt(ti.max(1.0 - cosine * cosine, 0.0))
    return ti.Vector([room[0] * cosine + room[1] * sine, room[1] * cosine - room[0] * sine])


@ti.data_oriented
class MeshPatches:
    """A garment's patches (module docstring), with their boxes, cones and partners at the
    positions of the last build of the candidate list (``cone``, ``neighbourhood_cone``,
    ``sort_boxes``, then ``list_partners``)."""

    def __init__(self, model, reach: float):
        garment = model.garment
        self.model, self.reach = model, reach
        cut = cut_patches(garment.triangles, garment.edges, model.particle_count)
        self.count = cut["count"]
        real = model.real
        self.triangle_start = ti.field(ti.i32, self.count + 1)
        self.triangle = ti.field(ti.i32, len(garment.triangles))
        # scratch of ``cone``: each triangle's unit normal, in the patches' order of ``triangle``
        self.unit_normal = ti.Vector.field(3, real, len(garment.triangles))
        self.edge_start = ti.field(ti.i32, self.count + 1)
        self.edge = ti.field(ti.i32, len(garment.edges))
        self.triangle_sign = ti.field(ti.i32, len(garment.triangles))  # ``orient``
        self.particle_home = ti.field(ti.i32, model.particle_count)
        self.edge_home = ti.field(ti.i32, len(garment.edges))
        near_count = sum(len(n) for n in cut["near"])
        self.near_start = ti.field(ti.i32, self.count + 1)
        self.near = ti.Vector.field(2, ti.i32, max(1, near_count))  # (patch, relation)
        # each patch's box [m], grown by half the reach; the patches in ascending order of their
        # boxes' lower bound along the sweep's axis (x, y or z: 0, 1, 2)
        self.lower, self.upper = (ti.Vector.field(3, real, self.count) for _ in range(2))
        self.sweep_order = ti.field(ti.i32, self.count)
        # the boxes in ``sweep_order`` (read in a row by the sweep), their lower bounds along its
        # axis, and each near patch's relation to the patch being swept (``NOT_NEAR`` else)
        self.sorted_lower, self.sorted_upper = (ti.Vector.field(3, real, self.count)
                                                for _ in range(2))
        self.sorted_key = ti.field(real, self.count)
        self.relation_mark = ti.field(ti.i32, self.count)
        self.sweep_axis = ti.field(ti.i32, ())
        self.swept = ti.field(ti.i32, ())  # whether the last build's boxes were all finite
        # each patch's cone and its neighbourhood's: the unit axis and the room α − half-angle
        # left to flat, as (cos, sin) (``NOT_FLAT`` in the cosine where the cone is wider than α)
        self.axis, self.around_axis = (ti.Vector.field(3, real, self.count) for _ in range(2))
        self.room, self.around_room = (ti.Vector.field(2, real, self.count) for _ in range(2))
        self.partner_count = ti.field(ti.i32, self.count)
        self.partner_capacity = min(self.count, MOST_PARTNERS)
        self.partner = ti.field(ti.i32, (self.count, self.partner_capacity))
        triangle_start, triangle_order = members(cut["triangle_patch"], self.count)
        edge_start, edge_order = members(cut["edge_home"], self.count)
        # a patch's home edges are its triangles' (3·PATCH_TRIANGLES at most): the bits of an
        # i32 in ``CandidatePairs._list_edge_edge``
        assert np.diff(edge_start).max(initial=0) <= 3 * PATCH_TRIANGLES < 32
        near_start = np.concatenate([[0], np.cumsum([len(n) for n in cut["near"]])])
        near = np.array([pair for n in cut["near"] for pair in n] or [(0, 0)], np.int32)
        self._host = [(self.triangle_start, triangle_start), (self.triangle, triangle_order),
                      (self.edge_start, edge_start), (self.edge, edge_order),
                      (self.triangle_sign, cut["triangle_sign"]),
                      (self.particle_home, cut["particle_home"]),
                      (self.edge_home, cut["edge_home"]), (self.near_start, near_start),
                      (self.near, near)]
        self.triangle_patch = cut["triangle_patch"]  # host copy, for tests and docs

    def upload(self) -> None:
        self.model.uploads.add([(field, np.asarray(values, np.int32))
                                for field, values in self._host + [
                                    (self.sweep_order, np.arange(self.count))]])

    @ti.func
    def cone(self, x, corners, p):
        """Patch p's box at x [m] grown by half the reach, and its cone of normals: the axis
        the mean of its triangles' unit normals, the half-angle h the widest angle from it to
        one of them; stored as the room α − h (cos, sin), or ``NOT_FLAT``. A degenerate
        triangle (no normal: a zero vector) makes the cone at least 90° wide, never flat. No
        inverse trigonometry: cos(α − h) and sin(α − h) from cos h."""
        real = self.model.real
        total = ti.Vector.zero(real, 3)
        low = ti.Vector([real(ti.math.inf)] * 3)
        high = -low
        for k in range(self.triangle_start[p], self.triangle_start[p + 1]):
            self.unit_normal[k] = self._unit_normal(x, corners, self.triangle[k])
            total += self.unit_normal[k]
            for j in ti.static(range(3)):
                low = ti.min(low, x[corners[self.triangle[k]][j]])
                high = ti.max(high, x[corners[self.triangle[k]][j]])
        axis = total / ti.max(total.norm(), real(1e-30))
        cosine = real(1.0)  # cos h
        for k in range(self.triangle_start[p], self.triangle_start[p + 1]):
            cosine = ti.min(cosine, axis.dot(self.unit_normal[k]))
        room = ti.Vector([real(NOT_FLAT), 0.0])
        if cosine >= ti.static(math.cos(FLAT_HALF_ANGLE)):  # α less h
            room = room_less_angle(ti.Vector([ti.static(math.cos(FLAT_HALF_ANGLE)),
                                              ti.static(math.sin(FLAT_HALF_ANGLE))]), cosine)
        self.axis[p], self.room[p] = axis, room
        grow = real(0.5 * self.reach)
        self.lower[p], self.upper[p] = low - grow, high + grow

    @ti.func
    def _unit_normal(self, x, corners, t):
        """Triangle t's unit normal at x, turned by its ``orient`` sign."""
        a, b, c = x[corners[t][0]], x[corners[t][1]], x[corners[t][2]]
        normal = (b - a).cross(c - a)
        return self.triangle_sign[t] * normal / ti.max(normal.norm(), self.model.real(1e-30))

    @ti.func
    def neighbourhood_cone(self, p):
        """The cone of patch p and the patches sharing a particle with it (their cones from
        ``cone``): about the mean of their axes, the half-angle H the widest of a member's
        angle from it plus its own half-angle; stored as the room α − H, the least of the
        members' rooms less their angles, or ``NOT_FLAT``."""
        real = self.model.real
        total = self.axis[p]
        for k in range(self.near_start[p], self.near_start[p + 1]):
            if self.near[k][1] == SHARES_PARTICLE:
                total += self.axis[self.near[k][0]]
        axis = total / ti.max(total.norm(), real(1e-30))
        # each member's room less its angle from the axis, in [−π, α]: ≥ 0 (sin and cos ≥ 0)
        # for every member if the neighbourhood is flat, the least of them its room (the
        # largest cosine, all being in [0, α])
        room = room_less_angle(self.room[p], ti.math.clamp(axis.dot(self.axis[p]), -1.0, 1.0))
        flat = int(self.room[p][0] >= -1.0 and room[0] >= 0 and room[1] >= 0)
        for k in range(self.near_start[p], self.near_start[p + 1]):
            q = self.near[k][0]
            if self.near[k][1] == SHARES_PARTICLE:
                left = room_less_angle(self.room[q],
                                       ti.math.clamp(axis.dot(self.axis[q]), -1.0, 1.0))
                flat &= int(self.room[q][0] >= -1.0 and left[0] >= 0 and left[1] >= 0)
                if left[0] > room[0]:
                    room = left
        if not flat:
            room = ti.Vector([real(NOT_FLAT), 0.0])
        self.around_axis[p], self.around_room[p] = axis, room

    @ti.func
    def sort_boxes(self):
        """``sweep_order``: the patches by their boxes' lower bound along the sweep's axis, by
        insertion from the last build's order (nearly sorted already: a few moves a patch). The
        axis is the widest spread of the boxes' lower corners, kept until another's is
        ``SWEEP_AXIS_SWITCH`` times as wide (a skirt turning about its own axis would otherwise
        flip between x and z, and each flip re-sorts from an order along the other). ``swept``
        when every box is finite; a cloth with non-finite positions (a run gone unstable, which
        its frame's guard stops) lists no partners. Then the boxes copied in that order, with
        their lower bounds along the axis, for the sweep. On one thread (call it under a serial
        loop)."""
        low = ti.Vector([self.model.real(ti.math.inf)] * 3)
        high, top = -low, -low  # the lower corners' extent, the upper corners' highest
        for p in range(self.count):
            low, high = ti.min(low, self.lower[p]), ti.max(high, self.lower[p])
            top = ti.max(top, self.upper[p])
        spread = high - low
        self.swept[None] = int((top - low < ti.math.inf).all())  # false for NaN too
        axis = self.sweep_axis[None]
        for a in ti.static(range(3)):
            if spread[a] > self.model.real(SWEEP_AXIS_SWITCH) * along(spread, axis):
                axis = a
        self.sweep_axis[None] = axis
        for k in range(1, self.count):
            p = self.sweep_order[k]
            key = along(self.lower[p], axis)
            j = k
            while j > 0:
                if along(self.lower[self.sweep_order[j - 1]], axis) <= key:
                    break
                self.sweep_order[j] = self.sweep_order[j - 1]
                j -= 1
            self.sweep_order[j] = p
        for k in range(self.count):
            p = self.sweep_order[k]
            self.sorted_lower[k], self.sorted_upper[k] = self.lower[p], self.upper[p]
            self.sorted_key[k] = along(self.lower[p], axis)

    @ti.func
    def culled(self, p, q, relation) -> ti.i32:
        """Whether the pair of patches p and q, related as ``relation`` (``near``: ``NOT_NEAR`` for
        p = q), holds no layers (module docstring): a patch with itself when its cone is flat;
        near patches when their cones (sharing a particle) or their neighbourhoods' cones
        (sharing a neighbour) fit in a flat one. Cones of half-angles a, b ≤ α whose axes are θ
        apart fit in one of max(a, b, (θ + a + b)/2), flat when θ ≤ (α − a) + (α − b): cos θ ≥
        cos of the rooms' sum (at most 2α < π)."""
        result = int(p == q and self.room[p][0] >= -1.0)
        if relation != NOT_NEAR:
            axis_p, room_p = self.axis[p], self.room[p]
            axis_q, room_q = self.axis[q], self.room[q]
            if relation == SHARES_NEIGHBOUR:
                axis_p, room_p = self.around_axis[p], self.around_room[p]
                axis_q, room_q = self.around_axis[q], self.around_room[q]
            if room_p[0] >= -1.0 and room_q[0] >= -1.0:
                result = int(axis_p.dot(axis_q) >= room_p[0] * room_q[0] - room_p[1] * room_q[1])
        return result

    @ti.func
    def list_partners(self, overflow: ti.template()):
        """Every patch's partners (itself included when not flat), ascending: the patches whose
        boxes overlap its own that ``culled`` keeps, found by a sweep along ``sweep_order`` (each
        patch meets the patches after it until one's lower bound passes its upper, their boxes
        read in a row from ``sort_boxes``' copies; its near patches' relations marked in
        ``relation_mark`` while it sweeps, for ``culled``, which is symmetric, so
        each pair is tested once and listed on both sides); past ``partner_capacity`` (every
        patch, or ``MOST_PARTNERS``), counted in ``overflow`` (``_add_partner``). On one thread
        (call it under a serial loop)."""
        for p in range(self.count):
            self.partner_count[p] = 0
            if self.swept[None] and self.culled(p, p, NOT_NEAR) == 0:
                self._add_partner(p, p, overflow)
        axis = self.sweep_axis[None]
        for k in range(self.count * self.swept[None]):
            p = self.sweep_order[k]
            for n in range(self.near_start[p], self.near_start[p + 1]):
                self.relation_mark[self.near[n][0]] = self.near[n][1]
            low, high = self.sorted_lower[k], self.sorted_upper[k]
            end = along(high, axis)
            for j in range(k + 1, self.count):
                if self.sorted_key[j] > end:
                    break
                if (low <= self.sorted_upper[j]).all() and (self.sorted_lower[j] <= high).all():
                    q = self.sweep_order[j]
                    if self.culled(p, q, self.relation_mark[q]) == 0:
                        self._add_partner(p, q, overflow)
                        self._add_partner(q, p, overflow)
            for n in range(self.near_start[p], self.near_start[p + 1]):
                self.relation_mark[self.near[n][0]] = NOT_NEAR

    @ti.func
    def _add_partner(self, p, q, overflow: ti.template()):
        """q into p's partners, kept ascending (an order that does not depend on the sweep's,
        which follows the builds before); when they are full, counted in ``overflow``, and the
        highest dropped if q is lower: the partners kept are the lowest, whatever the order the
        sweep met them in."""
        n = self.partner_count[p]
        if n == ti.static(self.partner_capacity):
            ti.atomic_add(overflow[None], 1)
            if q < self.partner[p, n - 1]:
                n -= 1
        if n < ti.static(self.partner_capacity):
            j = n
            while j > 0:
                if self.partner[p, j - 1] < q:
                    break
                self.partner[p, j] = self.partner[p, j - 1]
                j -= 1
            self.partner[p, j] = q
            self.partner_count[p] = n + 1


@ti.func
def along(vector, axis):
    """Component ``axis`` (0, 1 or 2, known at run time) of a 3-vector."""
    value = vector[0]
    for a in ti.static(range(1, 3)):
        if axis == a:
            value = vector[a]
    return value
