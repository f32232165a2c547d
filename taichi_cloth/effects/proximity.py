"""Closest points between cloth primitives, for self-collision (``self_collision.py``): a point
and a triangle, two segments (C. Ericson, "Real-Time Collision Detection", Morgan Kaufmann 2005,
§5.1.5 and §5.1.9); and where the two primitives of a pair are against each other, along the
normal that its side record uses (``crossing_history``)."""

import taichi as ti

VERTEX_TRIANGLE, EDGE_EDGE = 0, 1  # kinds of pairs


@ti.func
def closest_on_triangle(p, a, b, c, real: ti.template()):
    """(the barycentric weights (w_a, w_b, w_c) of the point of triangle (a, b, c) closest to p
    (Ericson §5.1.5: the Voronoi regions of its vertices, edges and face); the offset [m], p
    minus that point)."""
    ab, ac = b - a, c - a
    d1, d2 = ab.dot(p - a), ac.dot(p - a)
    d3, d4 = ab.dot(p - b), ac.dot(p - b)
    d5, d6 = ab.dot(p - c), ac.dot(p - c)
    va, vb, vc = d3 * d6 - d5 * d4, d5 * d2 - d1 * d6, d1 * d4 - d3 * d2
    weights = ti.Vector([1.0, 0.0, 0.0], real)
    if d1 <= 0 and d2 <= 0:
        weights = ti.Vector([1.0, 0.0, 0.0], real)
    elif d3 >= 0 and d4 <= d3:
        weights = ti.Vector([0.0, 1.0, 0.0], real)
    elif vc <= 0 and d1 >= 0 and d3 <= 0:
        along = d1 / (d1 - d3)
        weights = ti.Vector([1 - along, along, 0.0], real)
    elif d6 >= 0 and d5 <= d6:
        weights = ti.Vector([0.0, 0.0, 1.0], real)
    elif vb <= 0 and d2 >= 0 and d6 <= 0:
        along = d2 / (d2 - d6)
        weights = ti.Vector([1 - along, 0.0, along], real)
    elif va <= 0 and d4 - d3 >= 0 and d5 - d6 >= 0:
        along = (d4 - d3) / ((d4 - d3) + (d5 - d6))
        weights = ti.Vector([0.0, 1 - along, along], real)
    else:
        scale = 1 / (va + vb + vc)
        weights = ti.Vector([1 - (vb + vc) * scale, vb * scale, vc * scale], real)
    return weights, p - (weights[0] * a + weights[1] * b + weights[2] * c)


@ti.func
def closest_between_segments(a, b, c, d, real: ti.template()):
    """(the parameters s, u ∈ [0, 1] of the closest points a + s·(b − a) and c + u·(d − c) of
    two segments (Ericson §5.1.9; parallel segments take s = 0); the offset [m], the first
    closest point minus the second)."""
    d1, d2, r = b - a, d - c, a - c
    aa, ee, f = d1.dot(d1), d2.dot(d2), d2.dot(r)
    s, u = real(0.0), real(0.0)
    if aa > 1e-30 and ee > 1e-30:
        cc, bb = d1.dot(r), d1.dot(d2)
        denominator = aa * ee - bb * bb
        if denominator > 1e-30 * aa * ee:
            s = ti.min(ti.max((bb * f - cc * ee) / denominator, 0.0), 1.0)
        u = (bb * s + f) / ee
        if u < 0:
            u = real(0.0)
            s = ti.min(ti.max(-cc / aa, 0.0), 1.0)
        elif u > 1:
            u = real(1.0)
            s = ti.min(ti.max((bb - cc) / aa, 0.0), 1.0)
    elif ee > 1e-30:
        u = ti.min(ti.max(f / ee, 0.0), 1.0)
    elif aa > 1e-30:
        s = ti.min(ti.max(-d1.dot(r) / aa, 0.0), 1.0)
    return s, u, (a + s * d1) - (c + u * d2)


@ti.func
def closest_offset(kind: ti.template(), first, second, third, fourth, real: ti.template()):
    """The offset [m] between the closest points of the pair of ``kind`` with its four points at
    ``first`` … ``fourth``, the first primitive's minus the second's: the last value of
    ``vertex_triangle_geometry`` or ``edge_edge_geometry`` without their normal (no root)."""
    offset = ti.Vector.zero(real, 3)
    if ti.static(kind == VERTEX_TRIANGLE):
        _weights, offset = closest_on_triangle(first, second, third, fourth, real)
    else:
        _s, _u, offset = closest_between_segments(first, second, third, fourth, real)
    return offset


@ti.func
def vertex_triangle_geometry(p, a, b, c, real: ti.template()):
    """Point p against triangle (a, b, c) [m]: (the shares (1, −w_a, −w_b, −w_c) of the offset,
    w the barycentric weights of the triangle's point closest to p; whether that point lies
    inside the face, every weight > 0, as 1 or 0; the face's unit normal (b − a)×(c − a)/|…|,
    0 for a degenerate triangle; the offset along it [m]; the offset, p minus that point [m])."""
    weights, offset = closest_on_triangle(p, a, b, c, real)
    area_normal = (b - a).cross(c - a)
    size = area_normal.norm()
    normal = ti.Vector.zero(real, 3)
    if size > 0:
        normal = area_normal / size
    inside = 0
    if size > 0 and (weights > 0).all():
        inside = 1
    share = ti.Vector([1.0, -weights[0], -weights[1], -weights[2]], real)
    return share, inside, normal, offset.dot(normal), offset


@ti.func
def edge_edge_geometry(a, b, c, d, real: ti.template()):
    """Edge (a, b) against edge (c, d) [m], closest points a + s·(b − a) and c + u·(d − c): (the
    shares (1 − s, s, u − 1, −u) of the offset; whether both closest points lie inside their
    edges, 0 < s, u < 1, the edges not parallel, as 1 or 0; the unit normal
    (b − a)×(d − c)/|…|, 0 when parallel; the offset along it [m]; the offset, the first
    closest point minus the second [m])."""
    s, u, offset = closest_between_segments(a, b, c, d, real)
    first_axis, second_axis = b - a, d - c
    crossing = first_axis.cross(second_axis)
    size = crossing.norm()
    normal = ti.Vector.zero(real, 3)
    parallel = size <= real(1e-6) * first_axis.norm() * second_axis.norm()
    if not parallel:
        normal = crossing / size
    inside = 0
    if not parallel and 0 < s < 1 and 0 < u < 1:
        inside = 1
    return ti.Vector([1 - s, s, u - 1, -u], real), inside, normal, offset.dot(normal), offset


@ti.func
def inside_within(normal, height, offset, margin):
    """Whether a pair's closest points are inside (``vertex_triangle_geometry``,
    ``edge_edge_geometry``) or less than ``margin`` [m] from it: the ``offset`` between them,
    less its part ``height`` along the unit ``normal``, at most ``margin`` long (0 inside: the
    closest points are then the projections). 0 for a zero normal."""
    lateral = offset - height * normal
    return int(normal.norm_sqr() > 0 and lateral.norm_sqr() <= margin * margin)


@ti.func
def pair_side(x, kind, ids, real: ti.template()):
    """The pair of ``kind`` and particles ``ids`` at positions x: (its four particles' shares
    of the offset between its closest points; whether its closest points are inside; its unit
    normal; the offset along it [m]; the offset [m]: the first point minus the second)
    (``vertex_triangle_geometry``, ``edge_edge_geometry``)."""
    return pair_geometry(kind, x[ids[0]], x[ids[1]], x[ids[2]], x[ids[3]], real)


@ti.func
def pair_geometry(kind, first, second, third, fourth, real: ti.template()):
    """``pair_side`` of the pair of ``kind`` with its four points at ``first`` … ``fourth``
    [m]."""
    share, inside, normal = ti.Vector.zero(real, 4), 0, ti.Vector.zero(real, 3)
    height, offset = real(0.0), ti.Vector.zero(real, 3)
    if kind == VERTEX_TRIANGLE:
        share, inside, normal, height, offset = vertex_triangle_geometry(first, second, third,
                                                                         fourth, real)
    else:
        share, inside, normal, height, offset = edge_edge_geometry(first, second, third, fourth,
                                                                   real)
    return share, inside, normal, height, offset
