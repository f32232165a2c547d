"""Whether a cloth's triangles pass through each other around one self-collision pair: the
witness that ``self_collision`` asks for before it puts a pair back (docs/physics.md, "Two
bounds on putting pairs back"). Two triangles that are not coplanar meet if and only if an edge
of one pierces the other (the criterion behind Möller 1997's test, which
``physics/intersections.py`` runs over the whole mesh as a metric; this local count inlines a
much smaller test into every step's post step)."""

import taichi as ti


@ti.func
def segment_pierces_triangle(p, q, a, b, c) -> ti.i32:
    """Whether segment p–q passes through triangle (a, b, c): its ends strictly on either side of
    the plane, the crossing point within the closed triangle (two triangles that are not
    coplanar meet if and only if an edge of one pierces the other)."""
    normal = (b - a).cross(c - a)
    d_p, d_q = (p - a).dot(normal), (q - a).dot(normal)
    pierces = 0
    if d_p * d_q < 0:
        r = p + d_p / (d_p - d_q) * (q - p)
        pierces = int((b - a).cross(r - a).dot(normal) >= 0
                      and (c - b).cross(r - b).dot(normal) >= 0
                      and (a - c).cross(r - c).dot(normal) >= 0)
    return pierces


@ti.func
def intersections_around(model, x, ids, first_slots):
    """How the triangles around a self-collision pair's two primitives pass through each other
    at positions x [m] (in float64): each triangle at one of particles ``ids[:first_slots]``
    against each at one of the others, non-adjacent pairs only, the edges of either that pierce
    the other (``segment_pierces_triangle``), counted once per two of the pair's particles
    (the same multiplicity at any positions, so counts compare). Coplanar contact is not
    counted. One inlined piercing test serves all (a run-time loop)."""
    meet = 0
    for a_slot in range(first_slots):
        a_p = ids[a_slot]
        for a_k in range(model.particle_triangle_start[a_p],
                         model.particle_triangle_start[a_p + 1]):
            corner_a = model.triangles[model.particle_triangle[a_k]]
            for b_slot in range(first_slots, 4):
                b_p = ids[b_slot]
                for b_k in range(model.particle_triangle_start[b_p],
                                 model.particle_triangle_start[b_p + 1]):
                    corner_b = model.triangles[model.particle_triangle[b_k]]
                    shared = 0
                    for i, j in ti.static(ti.ndrange(3, 3)):
                        shared |= int(corner_a[i] == corner_b[j])
                    if shared == 0:
                        for e in range(6):  # the edges of a through b, then b's through a
                            edge = corner_a if e < 3 else corner_b
                            face = corner_b if e < 3 else corner_a
                            first, second = edge[e % 3], edge[(e + 1) % 3]
                            meet += segment_pierces_triangle(
                                ti.cast(x[first], ti.f64), ti.cast(x[second], ti.f64),
                                ti.cast(x[face[0]], ti.f64), ti.cast(x[face[1]], ti.f64),
                                ti.cast(x[face[2]], ti.f64))
    return meet
