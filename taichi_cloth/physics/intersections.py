"""How many pairs of the cloth's triangles pass through each other: a metric that does not trust
the self-collision method (docs/physics.md, "Self-intersections").

Every pair of non-adjacent triangles (no shared vertex) is tested, per frame, by the exact
triangle–triangle test of Möller (1997, "A fast triangle-triangle intersection test", J. Graphics
Tools 2(2)) in float64: each triangle's vertices against the other's plane (all on one side: no
intersection), then the two intervals in which the planes' line meets the triangles, which
intersect if and only if those overlap; coplanar pairs are tested in 2D (an edge of one crossing
an edge of the other, or a vertex of one inside the other). Touching counts as intersecting.

Broad phase: a uniform grid whose cell is the mean side of the triangles' bounding boxes (doubled
while the boxes would take more than ``FILINGS_PER_TRIANGLE`` cells each on average). Each box is
filed under every cell it overlaps (a hashed table, counted, prefix-summed and filled in one
Taichi kernel; filed serially, so each bucket lists its triangles in ascending order), each
triangle walks the triangles of higher index filed in its cells (from a bucket's end down to its
own index), and a pair whose boxes overlap is tested in the first cell both span, so once.
(Cells of the largest box side, each triangle filed once and meeting the 13 cells that follow its
own, walked ~40 times as many pairs where the mesh is fine.) The count is an integer sum, the same
in any order.
"""

import numpy as np
import taichi as ti

from taichi_cloth.physics.spatial_hash import hash_cell, power_of_two_at_least

HASH_LOAD = 2  # hash buckets per triangle (rounded up to a power of two)
FILINGS_PER_TRIANGLE = 8  # a triangle's box filed under this many cells at most, on average
MAX_DOUBLINGS = 40  # of the cell, until the filings fit (more: non-finite positions)
PLANE_TOLERANCE = 1e-12  # m: a vertex this close to the other triangle's plane lies on it
FOUND_CAPACITY = 1024  # intersecting pairs a count also lists


@ti.func
def interval_on_line(p0, p1, p2, d0, d1, d2):
    """Where the line of the two planes crosses a triangle with vertex projections p (on the
    line) and signed distances d (to the other plane): the interval (a, b), a ≤ b."""
    a, b = p0, p0
    if d0 * d1 > 0:  # vertex 2 alone on its side (or on the plane)
        a = p2 + (p0 - p2) * d2 / (d2 - d0)
        b = p2 + (p1 - p2) * d2 / (d2 - d1)
    elif d0 * d2 > 0:  # vertex 1 alone
        a = p1 + (p0 - p1) * d1 / (d1 - d0)
        b = p1 + (p2 - p1) * d1 / (d1 - d2)
    elif d1 * d2 > 0 or d0 != 0:  # vertex 0 alone
        a = p0 + (p1 - p0) * d0 / (d0 - d1)
        b = p0 + (p2 - p0) * d0 / (d0 - d2)
    elif d1 != 0:
        a = p1 + (p0 - p1) * d1 / (d1 - d0)
        b = p1 + (p2 - p1) * d1 / (d1 - d2)
    else:
        a = p2 + (p0 - p2) * d2 / (d2 - d0)
        b = p2 + (p1 - p2) * d2 / (d2 - d1)
    return ti.min(a, b), ti.max(a, b)


@ti.func
def orientation_2d(a, b, c):
    """Twice the signed area of the 2D triangle (a, b, c)."""
    return (b[0] - a[0]) * (c[1] - a[1]) - (b[1] - a[1]) * (c[0] - a[0])


@ti.func
def segments_cross_2d(p, q, r, s) -> ti.i32:
    """Whether the closed 2D segments pq and rs share a point (collinear overlaps included)."""
    o1, o2 = orientation_2d(p, q, r), orientation_2d(p, q, s)
    o3, o4 = orientation_2d(r, s, p), orientation_2d(r, s, q)
    cross = 0
    if o1 * o2 <= 0 and o3 * o4 <= 0:
        if o1 == 0 and o2 == 0:  # collinear: the boxes must overlap
            lo, hi = ti.min(p, q), ti.max(p, q)
            lo2, hi2 = ti.min(r, s), ti.max(r, s)
            cross = int(lo[0] <= hi2[0] and lo2[0] <= hi[0] and lo[1] <= hi2[1]
                        and lo2[1] <= hi[1])
        else:
            cross = 1
    return cross


@ti.func
def inside_triangle_2d(p, a, b, c) -> ti.i32:
    """Whether the 2D point p lies in the closed triangle (a, b, c)."""
    o1, o2, o3 = orientation_2d(a, b, p), orientation_2d(b, c, p), orientation_2d(c, a, p)
    return int((o1 >= 0 and o2 >= 0 and o3 >= 0) or (o1 <= 0 and o2 <= 0 and o3 <= 0))


@ti.func
def largest_axis(direction) -> ti.i32:
    """The index of the largest |component| of a 3-vector (the first among equals)."""
    n = ti.abs(direction)
    axis = 0
    if n[1] > n[0] and n[1] >= n[2]:
        axis = 1
    elif n[2] > n[0] and n[2] > n[1]:
        axis = 2
    return axis


@ti.func
def coplanar_triangles_meet(u0, u1, u2, v0, v1, v2, normal) -> ti.i32:
    """Möller's coplanar case: project on the axis plane where the triangles are largest, then
    an edge crossing or a vertex inside."""
    axis = largest_axis(normal)
    i, j = (axis + 1) % 3, (axis + 2) % 3
    a = ti.Matrix([[u0[i], u0[j]], [u1[i], u1[j]], [u2[i], u2[j]]])
    b = ti.Matrix([[v0[i], v0[j]], [v1[i], v1[j]], [v2[i], v2[j]]])
    meet = 0
    for e in ti.static(range(3)):
        for f in ti.static(range(3)):
            meet |= segments_cross_2d(ti.Vector([a[e, 0], a[e, 1]]),
                                      ti.Vector([a[(e + 1) % 3, 0], a[(e + 1) % 3, 1]]),
                                      ti.Vector([b[f, 0], b[f, 1]]),
                                      ti.Vector([b[(f + 1) % 3, 0], b[(f + 1) % 3, 1]]))
    meet |= inside_triangle_2d(ti.Vector([a[0, 0], a[0, 1]]), ti.Vector([b[0, 0], b[0, 1]]),
                               ti.Vector([b[1, 0], b[1, 1]]), ti.Vector([b[2, 0], b[2, 1]]))
    meet |= inside_triangle_2d(ti.Vector([b[0, 0], b[0, 1]]), ti.Vector([a[0, 0], a[0, 1]]),
                               ti.Vector([a[1, 0], a[1, 1]]), ti.Vector([a[2, 0], a[2, 1]]))
    return meet


@ti.func
def plane_distances(v0, v1, v2, p0, p1, p2):
    """The triangle (v0, v1, v2)'s normal N = (v1 − v0) × (v2 − v0) and N·(p − v0) for the three
    points, zeroed within ``PLANE_TOLERANCE`` · |N| of the plane."""
    normal = (v1 - v0).cross(v2 - v0)
    zero = PLANE_TOLERANCE * normal.norm()
    d = ti.Vector([normal.dot(p0 - v0), normal.dot(p1 - v0), normal.dot(p2 - v0)])
    for k in ti.static(range(3)):
        if ti.abs(d[k]) < zero:
            d[k] = 0.0
    return normal, d


@ti.func
def triangles_intersect(u0, u1, u2, v0, v1, v2) -> ti.i32:
    """Möller (1997): whether the closed triangles (u0, u1, u2) and (v0, v1, v2) meet."""
    meet = 0
    normal_v, du = plane_distances(v0, v1, v2, u0, u1, u2)
    if not (du[0] * du[1] > 0 and du[0] * du[2] > 0):
        normal_u, dv = plane_distances(u0, u1, u2, v0, v1, v2)
        if not (dv[0] * dv[1] > 0 and dv[0] * dv[2] > 0):
            if du[0] == 0 and du[1] == 0 and du[2] == 0:
                meet = coplanar_triangles_meet(u0, u1, u2, v0, v1, v2, normal_u)
            else:
                axis = largest_axis(normal_u.cross(normal_v))
                a0, a1 = interval_on_line(u0[axis], u1[axis], u2[axis], du[0], du[1], du[2])
                b0, b1 = interval_on_line(v0[axis], v1[axis], v2[axis], dv[0], dv[1], dv[2])
                meet = int(a1 >= b0 and b1 >= a0)
    return meet


vec3 = ti.types.vector(3, ti.f64)
ivec3 = ti.types.vector(3, ti.i32)
cell3 = ti.types.vector(3, ti.i64)
pair2 = ti.types.vector(2, ti.i32)


@ti.func
def cells_spanned(low, high, cell_size):
    """The first and last grid cells (per axis) of the box [low, high] on cells of
    ``cell_size`` [m]."""
    return ti.cast(ti.floor(low / cell_size), ti.i64), ti.cast(ti.floor(high / cell_size), ti.i64)


@ti.kernel
def count_intersecting_pairs(x: ti.types.ndarray(dtype=vec3, ndim=1),
                             triangles: ti.types.ndarray(dtype=ivec3, ndim=1),
                             low: ti.types.ndarray(dtype=vec3, ndim=1),
                             high: ti.types.ndarray(dtype=vec3, ndim=1),
                             bucket_start: ti.types.ndarray(dtype=ti.i32, ndim=1),
                             bucket_fill: ti.types.ndarray(dtype=ti.i32, ndim=1),
                             filed: ti.types.ndarray(dtype=ti.i32, ndim=1),
                             filed_cell: ti.types.ndarray(dtype=cell3, ndim=1),
                             first_cell: ti.types.ndarray(dtype=cell3, ndim=1),
                             found: ti.types.ndarray(dtype=pair2, ndim=1),
                             cell_size: ti.types.ndarray(dtype=ti.f64, ndim=1),
                             pairs: ti.types.ndarray(dtype=ti.i32, ndim=1)):
    """The broad phase and Möller's test (module docstring): ``pairs[0]`` = the number of
    intersecting non-adjacent pairs, the first ``found.shape[0]`` of them in ``found``. The other
    arrays are scratch: per triangle (T) its box and the first cell it spans (read by the walk
    for every pair it meets: no divisions there), per bucket (B, B + 1), per filing (F) its
    triangle and cell."""
    bucket_count = bucket_fill.shape[0]
    capacity = filed.shape[0]
    cell_size[0] = 0.0
    pairs[0] = 0
    bucket_start[0] = 0
    for b in range(bucket_count):
        bucket_fill[b] = 0
    for t in range(triangles.shape[0]):
        corner = triangles[t]
        p0, p1, p2 = x[corner[0]], x[corner[1]], x[corner[2]]
        low[t] = ti.min(ti.min(p0, p1), p2)
        high[t] = ti.max(ti.max(p0, p1), p2)
        ti.atomic_add(cell_size[0], (high[t] - low[t]).max())
    ti.loop_config(serialize=True)
    for _ in range(1):  # cells of the mean box side, doubled until the filings fit
        size = ti.max(cell_size[0] / triangles.shape[0], 1e-9)
        for _doubling in range(MAX_DOUBLINGS):
            filings = ti.f64(0.0)  # exact to 2⁵³ filings
            for t in range(triangles.shape[0]):
                span = ti.floor(high[t] / size) - ti.floor(low[t] / size) + 1
                filings += span[0] * span[1] * span[2]
            if filings <= capacity:
                break
            size *= 2
        cell_size[0] = size
    for t in range(triangles.shape[0]):
        first, last = cells_spanned(low[t], high[t], cell_size[0])
        first_cell[t] = first
        for cell in ti.grouped(ti.ndrange((first[0], last[0] + 1), (first[1], last[1] + 1),
                                          (first[2], last[2] + 1))):
            ti.atomic_add(bucket_fill[hash_cell(cell, bucket_count)], 1)
    ti.loop_config(serialize=True)
    for b in range(bucket_count):
        bucket_start[b + 1] = bucket_start[b] + bucket_fill[b]
        bucket_fill[b] = bucket_start[b]
    ti.loop_config(serialize=True)  # each bucket's triangles in ascending order, for the walk
    for t in range(triangles.shape[0]):
        first, last = cells_spanned(low[t], high[t], cell_size[0])
        for cell in ti.grouped(ti.ndrange((first[0], last[0] + 1), (first[1], last[1] + 1),
                                          (first[2], last[2] + 1))):
            slot = ti.atomic_add(bucket_fill[hash_cell(cell, bucket_count)], 1)
            if slot < capacity:  # (the doubling keeps the filings within it)
                filed[slot] = t
                filed_cell[slot] = cell
    for a in range(triangles.shape[0]):
        corner_a = triangles[a]
        first, last = cells_spanned(low[a], high[a], cell_size[0])
        for cell in ti.grouped(ti.ndrange((first[0], last[0] + 1), (first[1], last[1] + 1),
                                          (first[2], last[2] + 1))):
            bucket = hash_cell(cell, bucket_count)
            end = bucket_start[bucket + 1]
            for j in range(end - bucket_start[bucket]):  # the bucket's triangles above a, down
                k = end - 1 - j
                b = filed[k]
                if b <= a:
                    break
                # nested tests: a kernel's ``and`` evaluates both sides
                if (filed_cell[k] == cell).all():
                    if (low[a] <= high[b]).all() and (low[b] <= high[a]).all():
                        if (ti.max(first, first_cell[b]) == cell).all():  # the pair's first cell
                            corner_b = triangles[b]
                            shared = 0
                            for i, j in ti.static(ti.ndrange(3, 3)):
                                shared |= int(corner_a[i] == corner_b[j])
                            if shared == 0:
                                if triangles_intersect(
                                        x[corner_a[0]], x[corner_a[1]], x[corner_a[2]],
                                        x[corner_b[0]], x[corner_b[1]], x[corner_b[2]]):
                                    slot = ti.atomic_add(pairs[0], 1)
                                    if slot < found.shape[0]:
                                        found[slot] = ti.Vector([a, b])


class IntersectionCounter:
    """Counts the intersecting pairs of non-adjacent triangles of a mesh of ``triangles``
    (T, 3): ``count(positions)`` with positions (N, 3) [m]. The kernel takes NumPy arrays, so it
    compiles once per process whatever the mesh."""

    def __init__(self, triangles: np.ndarray, particle_count: int):
        count = len(triangles)
        self.particle_count = particle_count
        self.triangles = np.ascontiguousarray(triangles, dtype=np.int32)
        buckets = power_of_two_at_least(HASH_LOAD * count)
        filings = max(1, FILINGS_PER_TRIANGLE * count)
        self.scratch = (np.zeros((count, 3)), np.zeros((count, 3)),
                        np.zeros(buckets + 1, np.int32), np.zeros(buckets, np.int32),
                        np.zeros(filings, np.int32), np.zeros((filings, 3), np.int64),
                        np.zeros((count, 3), np.int64))
        self.found = np.zeros((FOUND_CAPACITY, 2), np.int32)
        self.cell_size = np.zeros(1)
        self.pairs = np.zeros(1, np.int32)

    def count(self, positions: np.ndarray) -> int:
        """Intersecting pairs of non-adjacent triangles at ``positions`` (N, 3) [m], which must
        be finite (the runs count only states their guard passed; a non-finite box would give
        the grid walks unbounded cell ranges)."""
        if len(self.triangles) < 2:
            return 0
        if not np.isfinite(positions).all():
            raise ValueError("IntersectionCounter.count: non-finite positions")
        count_intersecting_pairs(np.ascontiguousarray(positions, dtype=np.float64),
                                 self.triangles, *self.scratch, self.found, self.cell_size,
                                 self.pairs)
        return int(self.pairs[0])

    def pairs_at(self, positions: np.ndarray) -> np.ndarray:
        """The intersecting pairs (K, 2) of triangle indices, lower first, sorted (the first
        ``FOUND_CAPACITY`` found when there are more)."""
        found = min(self.count(positions), FOUND_CAPACITY)
        pairs = self.found[:found].copy()
        return pairs[np.lexsort((pairs[:, 1], pairs[:, 0]))]
