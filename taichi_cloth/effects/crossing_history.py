"""Which side of each other a self-collision pair's two primitives belong on, remembered from step
to step, so that a pair that has passed through itself is pushed back, not further through
(history-based self-collision: Bridson, Fedkiw & Anderson 2002, §7 keep the cloth free of
intersections by never letting a step cross; Selle, Su, Irving & Fedkiw 2009, "Robust
high-resolution cloth using parallelism, history-based collisions, and accurate friction", use
the last collision-free state to decide which way a contact pushes).

A pair's *side* is measured along a normal that turns with the pair: for a vertex and a triangle
the face's normal, h = (p − c)·n; for two edges the normal of both, n ∝ (b − a)×(d − c),
h = (P − Q)·n. The pair can only pass through itself where its closest points are *inside* (the
vertex above the face; both closest points within their edges): elsewhere the sign of h changes
by going round, which is no crossing. After every committed step (``commit``) each listed pair
records, as one integer,

    0          not yet seen at a committed step
    ±1         outside, on side σ = ±1 (σ then follows the sign of h)
    ±2         inside, on its side σ
    ±3         inside on the other side than σ: it has crossed within a step

so that σ changes only outside. While the pair was inside at the last commit and is inside at an
evaluation, its penalty uses the signed distance σ·h along σ·n (``oriented``): the same force as
the unsigned one on its own side, continuous through h = 0, and growing with the depth on the
wrong side, back towards σ. A pair that enters inside from outside takes the side it is on.
The records' commits (``self_collision``) count as inside a pair within a thickness of it
(``proximity.inside_within``): a vertex that passes a corner or an edge of a face closer than
the cloth's thickness, where every vertex–triangle and edge–edge pair around is at its border,
is then seen crossing by one of them; one that went round instead has no crossing to witness
it, and its record gives way. The penalty keeps the exact inside, where it is continuous.
"""

import taichi as ti

UNKNOWN, OUTSIDE, INSIDE, CROSSED = 0, 1, 2, 3  # magnitudes of the record (module docstring)


@ti.func
def commit(record, inside, height):
    """The record after a committed step where the pair is ``inside`` with offset ``height``
    [m] along its normal (module docstring)."""
    sign = 0
    if height > 0:
        sign = 1
    elif height < 0:
        sign = -1
    side = 1 if record >= 0 else -1
    state = ti.abs(record)
    if state == UNKNOWN or state == OUTSIDE or not inside:
        if sign != 0:
            side = sign
        state = INSIDE if inside else OUTSIDE
        if record == UNKNOWN and sign == 0:
            state = UNKNOWN
    elif sign != 0:
        state = INSIDE if sign == side else CROSSED
    return side * state


@ti.func
def record_from_here(inside, height):
    """The record of a pair with no history, taken from the side it is on now (``commit`` from
    ``UNKNOWN``): a new pair's, or one whose record nothing witnesses."""
    return commit(UNKNOWN, inside, height)


@ti.func
def is_crossed(record):
    return ti.abs(record) == CROSSED


@ti.func
def is_inside(record):
    """Whether the pair was inside at the last commit (crossed or not)."""
    return ti.abs(record) == INSIDE or ti.abs(record) == CROSSED


@ti.func
def oriented(record, inside, normal, height, offset, real: ti.template()):
    """(unit normal, distance [m]) that the pair's penalty acts on: σ·n and σ·h when the pair was
    inside at the last commit and is inside now, else the unsigned |offset| along it (0 normal
    for a zero offset)."""
    distance = offset.norm()
    direction = ti.Vector.zero(real, 3)
    if distance > 0:
        direction = offset / distance
    if inside and is_inside(record):
        side = real(1.0) if record > 0 else real(-1.0)
        direction = side * normal
        distance = side * height
    return direction, distance
