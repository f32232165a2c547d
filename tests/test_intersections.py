"""The self-intersection metric (physics/intersections.py, Möller's test in Taichi) against an
independent NumPy reference built on orientation predicates (two non-coplanar triangles meet if
and only if an edge of one meets the other; coplanar ones are tested in their plane), on random
pairs and on the degenerate ones: coplanar, a shared vertex, a touching edge or vertex."""

import numpy as np
import pytest

from taichi_cloth.physics.intersections import IntersectionCounter

SEPARATION = 10.0  # m between test pairs along x: far apart for the broad phase


def orient(a, b, c, d):
    """Six times the signed volume of the tetrahedron (a, b, c, d)."""
    return float(np.dot(np.cross(b - a, c - a), d - a))


def orient_2d(a, b, c):
    return float((b[0] - a[0]) * (c[1] - a[1]) - (b[1] - a[1]) * (c[0] - a[0]))


def segments_meet_2d(p, q, r, s):
    o1, o2, o3, o4 = orient_2d(p, q, r), orient_2d(p, q, s), orient_2d(r, s, p), orient_2d(r, s, q)
    if o1 == 0 and o2 == 0:
        return bool(np.all(np.minimum(p, q) <= np.maximum(r, s))
                    and np.all(np.minimum(r, s) <= np.maximum(p, q)))
    return o1 * o2 <= 0 and o3 * o4 <= 0


def inside_2d(p, a, b, c):
    o = [orient_2d(a, b, p), orient_2d(b, c, p), orient_2d(c, a, p)]
    return min(o) >= 0 or max(o) <= 0


def project(points, normal):
    drop = int(np.argmax(np.abs(normal)))
    return [np.delete(p, drop) for p in points]


def triangles_meet_2d(t, u):
    edges_t = [(t[k], t[(k + 1) % 3]) for k in range(3)]
    edges_u = [(u[k], u[(k + 1) % 3]) for k in range(3)]
    return (any(segments_meet_2d(*e, *f) for e in edges_t for f in edges_u)
            or inside_2d(t[0], *u) or inside_2d(u[0], *t))


def segment_meets_triangle(p, q, triangle):
    a, b, c = triangle
    sp, sq = orient(a, b, c, p), orient(a, b, c, q)
    if sp == 0 and sq == 0:  # the segment lies in the triangle's plane
        normal = np.cross(b - a, c - a)
        p2, q2, a2, b2, c2 = project([p, q, a, b, c], normal)
        return (inside_2d(p2, a2, b2, c2) or inside_2d(q2, a2, b2, c2)
                or any(segments_meet_2d(p2, q2, e, f) for e, f in ((a2, b2), (b2, c2), (c2, a2))))
    if sp * sq > 0:
        return False
    sides = [orient(p, q, a, b), orient(p, q, b, c), orient(p, q, c, a)]
    return min(sides) >= 0 or max(sides) <= 0


def reference_meet(t, u):
    """Whether closed triangles t and u ((3, 3) each) meet, by orientation predicates."""
    normal = np.cross(t[1] - t[0], t[2] - t[0])
    if all(orient(*t, p) == 0 for p in u):
        return triangles_meet_2d(project(t, normal), project(u, normal))
    return (any(segment_meets_triangle(t[k], t[(k + 1) % 3], u) for k in range(3))
            or any(segment_meets_triangle(u[k], u[(k + 1) % 3], t) for k in range(3)))


def counted_pairs(pairs):
    """The metric on a mesh of the given triangle pairs ((P, 2, 3, 3), no shared vertices),
    laid out SEPARATION apart: the indices of the pairs it finds intersecting."""
    offsets = SEPARATION * np.arange(len(pairs))[:, None, None, None] * np.array([1.0, 0, 0])
    points = (pairs + offsets).reshape(-1, 3)
    triangles = np.arange(len(points)).reshape(-1, 3)
    found = IntersectionCounter(triangles, len(points)).pairs_at(points)
    assert np.all(found[:, 1] == found[:, 0] + 1) and np.all(found[:, 0] % 2 == 0)
    return sorted(found[:, 0] // 2)


def test_random_pairs_agree_with_the_reference():
    rng = np.random.default_rng(7)
    pairs = rng.uniform(-1.0, 1.0, (300, 2, 3, 3))
    pairs[:, 1] *= rng.uniform(0.3, 1.0, (300, 1, 1))
    expected = [k for k, (t, u) in enumerate(pairs) if reference_meet(t, u)]
    assert 60 < len(expected) < 240  # both outcomes well represented
    assert counted_pairs(pairs) == expected


DEGENERATE = {
    # coplanar (z = 0), overlapping / apart / one inside the other / touching at a vertex
    "coplanar overlap": ([[0, 0, 0], [2, 0, 0], [0, 2, 0]], [[1, 1, 0], [3, 1, 0], [1, 3, 0]], True),
    "coplanar apart": ([[0, 0, 0], [1, 0, 0], [0, 1, 0]], [[2, 2, 0], [3, 2, 0], [2, 3, 0]], False),
    "coplanar inside": ([[0, 0, 0], [4, 0, 0], [0, 4, 0]], [[1, 1, 0], [2, 1, 0], [1, 2, 0]], True),
    "coplanar vertex touch": ([[0, 0, 0], [1, 0, 0], [0, 1, 0]], [[1, 0, 0], [2, 0, 0], [2, 1, 0]],
                              True),
    # a vertex of one exactly on the other's edge, the rest above
    "touching edge": ([[0, 0, 0], [2, 0, 0], [0, 2, 0]], [[1, 0, 0], [1, 0, 1], [2, 1, 1]], True),
    # an edge of one lying on the other's face
    "edge on face": ([[0, 0, 0], [4, 0, 0], [0, 4, 0]], [[1, 1, 0], [2, 1, 0], [1, 1, 1]], True),
    # just above the face: apart
    "hovering": ([[0, 0, 0], [4, 0, 0], [0, 4, 0]], [[1, 1, 0.25], [2, 1, 0.25], [1, 1, 1]],
                 False),
    # piercing through the middle
    "pierce": ([[0, 0, 0], [4, 0, 0], [0, 4, 0]], [[1, 1, -1], [1, 1, 1], [2, 2, 1]], True),
    # crossing the plane outside the triangle
    "beside": ([[0, 0, 0], [1, 0, 0], [0, 1, 0]], [[2, 2, -1], [2, 2, 1], [3, 3, 1]], False),
}


@pytest.mark.parametrize("name", DEGENERATE)
def test_degenerate_pairs(name):
    t, u, meet = DEGENERATE[name]
    pair = np.array([[t, u]], dtype=float)
    assert reference_meet(pair[0, 0], pair[0, 1]) == meet
    assert counted_pairs(pair) == ([0] if meet else [])


def test_adjacent_triangles_do_not_count_and_a_fold_through_does():
    """A flat strip of two triangles sharing an edge: no pair counts (adjacent). A third
    triangle, sharing no vertex, pushed through the strip's face counts once per face it
    pierces."""
    points = np.array([[0, 0, 0], [2, 0, 0], [0, 2, 0], [2, 2, 0],
                       [0.4, 0.4, -1], [0.6, 0.6, 1], [2.6, 2.5, 1]], dtype=float)
    strip = np.array([[0, 1, 2], [1, 3, 2]])
    assert IntersectionCounter(strip, 4).count(points[:4]) == 0
    counter = IntersectionCounter(np.vstack([strip, [[4, 5, 6]]]), 7)
    assert counter.count(points) == 2
    assert counter.pairs_at(points).tolist() == [[0, 2], [1, 2]]


def test_non_finite_positions_are_refused_not_walked():
    counter = IntersectionCounter(np.array([[0, 1, 2], [3, 4, 5]]), 6)
    positions = np.zeros((6, 3))
    positions[[1, 4], 0] = 1.0
    positions[[2, 5], 2] = 1.0
    positions[3:, 1] = 0.5
    assert counter.count(positions) == 0
    positions[4, 0] = np.nan
    with pytest.raises(ValueError, match="non-finite"):
        counter.count(positions)
