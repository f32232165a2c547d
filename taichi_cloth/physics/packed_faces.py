"""The air pressure on a grid cloth's faces in SIMD lanes, for ``physics.packed_grid``.

A face effect (``Effect.lane_faces``: drag) pushes on each triangle with the pressure of a flat
plate (``effects.aerodynamics.plate_pressure``), a third to each corner. On a packed grid cloth
each quad's two triangles are computed once per force evaluation, sixteen quads at a time, from
the packed state; the SIMD spring pass then reads each particle's six faces back
(``packed_grid.group_pass_function``).
"""

import taichi as ti

from taichi_cloth.effects.aerodynamics import plate_pressure
from taichi_cloth.physics.grid_stencil import SIMD_LANES, packed_lanes


def quad_faces_function(packed):
    """A ``ti.real_func`` (buffer, row) that computes, in lanes, the pressure of each of
    ``packed``'s face effects on the two triangles of the quads of rows row, row + 1 and columns
    c, c + 1 (TL, BL, BR and TL, BR, TR, as ``cloth.topology.grid_triangles``), a group of
    columns at a time (those holding grid columns), from packed copy ``buffer``: its third into
    the effect's ``face_force`` [N] (0 for a quad off an open grid). Real, so that a launch of
    many substeps compiles it once; a row a call, not a group (a quarter of the calls on `hula`:
    its faces 5.2-5.5 µs a substep against 6.3-7.0, docs/performance.md)."""
    grid, real = packed.grid, packed.model.real
    packed_x, packed_v = packed.packed_x, packed.packed_v
    face_effects, face_force = packed.face_effects, packed.face_force
    corners = ((0, 0), (1, 0), (1, 1), (0, 1))  # TL, BL, BR, TR: (Δrow, Δcolumn)
    lane_index = ti.Vector(list(range(SIMD_LANES)))
    first_group, end_group = packed.filled_groups

    @ti.real_func
    def quad_faces(buffer: ti.i32, row: ti.i32):
        for group in range(first_group, end_group):
            x = [[packed_lanes(packed_x[c], buffer, row + corners[k][0], group, corners[k][1])
                  for c in ti.static(range(3))] for k in ti.static(range(4))]
            v = [[packed_lanes(packed_v[c], buffer, row + corners[k][0], group, corners[k][1])
                  for c in ti.static(range(3))] for k in ti.static(range(4))]
            column = (group - 1) * SIMD_LANES + lane_index
            present = column >= -SIMD_LANES  # every lane
            if ti.static(not grid.periodic):
                present = (column >= 0) & (column < grid.columns - 1)
            for e, effect in ti.static(enumerate(face_effects)):
                for kind in ti.static(range(2)):
                    a, b, c = ti.static(((0, 1, 2), (0, 2, 3))[kind])
                    face_velocity = [(v[a][k] + v[b][k] + v[c][k]) * real(1.0 / 3.0)
                                     for k in ti.static(range(3))]
                    air = effect.face_air(face_velocity)
                    pressure = plate_pressure(
                        [x[b][k] - x[a][k] for k in ti.static(range(3))],
                        [x[c][k] - x[a][k] for k in ti.static(range(3))], air)
                    for k in ti.static(range(3)):
                        face_force[e][kind][k][0, row, group] = ti.select(
                            present, real(effect.face_factor / 3.0) * pressure[k], 0.0)

    return quad_faces
