"""The SIMD pass over a packed grid cloth (``physics.packed_grid``): each spring computed once, in
lanes, then each particle's force summed from its lanes.

A substep's force evaluation is two loops over the packed groups of a ``PackedGrid``:

1. The forward pass (``forward_pass_function``), a row of groups per call: for each *forward*
   slot of the springs' stencil (Δrow > 0, or Δrow = 0 and Δcolumn > 0: every spring is the
   forward slot of exactly one of its ends) the spring's force on its owner i, with d = x_j − x_i
   and 1/l = 1/√(d·d),

       f_ij = [k·(1 − L/l) + c·((v_j − v_i)·d)/l²]·d,

   into ``PackedGrid.forward_force`` (docs/physics.md, "Springs and dashpots": the same formula
   with n = d/l; 0 for a slot off the grid or a spring of zero length); and each face effect's
   pressure on the two triangles of the row's quads (``effects.aerodynamics.plate_pressure``, a
   third of it, into ``face_force``), from the same reads of the quad's corners. Both hold a
   ring of rows per block of rows (row r in ring row r % ``PackedGrid.ring_rows``), as the group
   pass of row r reads only rows r − Δrow (Δrow ≥ 0) of the forward slots and rows r, r − 1 of
   the faces.
2. The group pass (``group_pass_function``): each lane adds its forward springs' f_ij, subtracts
   the f_ji of the springs whose forward slot is at the other end (read shifted by the slot's
   offset: the reaction f_j = −f_i of a spring), adds the linear stencils of the effects that act
   in lanes (bending) and a third of its six faces, and hands the sum to the integrator's
   ``finish``. A gather: no atomics, the same sums in any launch order.

Computing each spring once instead of from both ends halved the springs' arithmetic: symplectic
`hula`'s substep 46-51 µs → 41-43 µs in turns (docs/performance.md, "Each spring once, reads
that wrap round, and the masks' bit scan").

The two passes go row by row through a block of rows (``PackedGrid.block_rows``), each row's
forward pass then its group pass, so that the forward forces are read back while they are in the
core's first-level cache; the blocks run in parallel, each one's first row reading the forward
forces of the rows before it (``PackedGrid.rows_back``), which the block computes again for
itself.
"""

import taichi as ti

from taichi_cloth.effects.aerodynamics import plate_pressure
from taichi_cloth.physics.grid_stencil import SIMD_LANES, packed_lanes

QUAD_CORNERS = ((0, 0), (1, 0), (1, 1), (0, 1))  # TL, BL, BR, TR of a quad: (Δrow, Δcolumn)


def forward_slots(slot_offsets: list) -> list:
    """The slots (indices into ``slot_offsets``, (Δrow, Δcolumn) each) that point forward:
    Δrow > 0, or Δrow = 0 and Δcolumn > 0. A spring joining i and j is the forward slot of one of
    them and the backward slot (the negated offset) of the other."""
    return [s for s, (d_row, d_column) in enumerate(slot_offsets)
            if d_row > 0 or (d_row == 0 and d_column > 0)]


def forward_pass_function(packed):
    """A ``ti.real_func`` (buffer, row, block): for each group of row ``row`` that holds grid
    columns, from packed copy ``buffer`` of ``packed`` (a ``PackedGrid``), the forward springs'
    forces (the module docstring's step 1) into ``packed.forward_force`` [N] and the face
    effects' pressures on the quads of rows row, row + 1 (TL, BL, BR and TL, BR, TR, as
    ``cloth.topology.grid_triangles``; none in the last row) into ``packed.face_force`` [N], both
    at [block, ring row of ``row``, group].
    Each corner's x and v is read once for both (a read past the last row reads the last row: its
    springs and faces are not stored). Real, so that a launch of many substeps compiles it once;
    a row a call (on `hula` the faces took 5.2-5.5 µs a substep this way against 6.3-7.0 at a
    group a call). An integrator that compiles its kernels apart (``runtime.without_taichi_passes``)
    makes its own: a real function is compiled by the first kernel that calls it."""
    model, grid = packed.model, packed.grid
    real = model.real
    packed_x, packed_v = packed.packed_x, packed.packed_v
    forward_force, face_force, face_effects = packed.forward_force, packed.face_force, \
        packed.face_effects
    springs = [grid.slot_offsets[s] for s in packed.forward_slots]
    # the offsets read: the forward springs' and, with face effects, the quads' corners
    offsets = sorted({(0, 0), *springs, *(QUAD_CORNERS if face_effects else ())})
    lane_index = ti.Vector(list(range(SIMD_LANES)))
    first_group, end_group = packed.filled_groups
    wrap = grid.wrapped_groups

    @ti.real_func
    def forward_pass(buffer: ti.i32, row: ti.i32, block: ti.i32):
        ring = ring_row(packed, row)
        for group in range(first_group, end_group):
            x = [[packed_lanes(packed_x[c], buffer, ti.min(row + offset[0], grid.rows - 1),
                               group, offset[1], wrap) for c in ti.static(range(3))]
                 for offset in ti.static(offsets)]
            # (read whether or not the springs have dashpots: LLVM drops the unused loads)
            v = [[packed_lanes(packed_v[c], buffer, ti.min(row + offset[0], grid.rows - 1),
                               group, offset[1], wrap) for c in ti.static(range(3))]
                 for offset in ti.static(offsets)]
            column = (group - 1) * SIMD_LANES + lane_index
            own = ti.static(offsets.index((0, 0)))
            for k, offset in ti.static(enumerate(springs)):
                if row + offset[0] < grid.rows:
                    j = ti.static(offsets.index(offset))
                    present = column >= -SIMD_LANES  # every lane
                    if ti.static(not grid.periodic):
                        present = (column < grid.columns) & (column + offset[1] >= 0) \
                            & (column + offset[1] < grid.columns)
                    force = spring_lanes(grid, row, packed.forward_slots[k], x[own], x[j],
                                         v[own], v[j], model.has_dashpots)
                    for c in ti.static(range(3)):
                        forward_force[k][c][block, ring, group] = ti.select(present, force[c],
                                                                            0.0)
            if ti.static(face_effects):
                if row < grid.rows - 1:
                    present = column >= -SIMD_LANES
                    if ti.static(not grid.periodic):
                        present = (column >= 0) & (column < grid.columns - 1)
                    corner = [x[ti.static(offsets.index(q))] for q in ti.static(QUAD_CORNERS)]
                    corner_v = [v[ti.static(offsets.index(q))] for q in ti.static(QUAD_CORNERS)]
                    for e, effect in ti.static(enumerate(face_effects)):
                        for kind in ti.static(range(2)):
                            a, b, c = ti.static(((0, 1, 2), (0, 2, 3))[kind])
                            face_velocity = [(corner_v[a][k] + corner_v[b][k] + corner_v[c][k])
                                             * real(1.0 / 3.0) for k in ti.static(range(3))]
                            pressure = plate_pressure(
                                [corner[b][k] - corner[a][k] for k in ti.static(range(3))],
                                [corner[c][k] - corner[a][k] for k in ti.static(range(3))],
                                effect.face_air(face_velocity))
                            for k in ti.static(range(3)):
                                face_force[e][kind][k][block, ring, group] = ti.select(
                                    present, real(effect.face_factor / 3.0) * pressure[k], 0.0)

    return forward_pass


@ti.func
def ring_row(packed: ti.template(), row):
    """Where row ``row``'s forward forces and faces are kept in its block's ring of rows
    (``PackedGrid.ring_rows`` of them)."""
    return row % packed.ring_rows


@ti.func
def spring_lanes(grid: ti.template(), row, slot: ti.template(), x_i: ti.template(),
                 x_j: ti.template(), v_i: ti.template(), v_j: ti.template(),
                 has_dashpots: ti.template()):
    """The force [N] on the lanes' particles i (positions x_i [m], velocities v_i [m/s], each three
    SIMD_LANES-vectors) of the springs of stencil slot ``slot`` of row ``row`` of ``grid`` (a
    ``GridStencil``) to their neighbours j (x_j, v_j): [k·(1 − L/l) + c·((v_j − v_i)·d)/l²]·d
    with d = x_j − x_i (the dashpot term only ``has_dashpots``), 0 where l = 0."""
    d = [x_j[c] - x_i[c] for c in ti.static(range(3))]
    length_sq = d[0] * d[0] + d[1] * d[1] + d[2] * d[2]
    inv_length = 1.0 / ti.sqrt(length_sq)
    magnitude = grid.stiffness[row, slot] * (1.0 - grid.rest_length[row, slot] * inv_length)
    if ti.static(has_dashpots):
        along = (v_j[0] - v_i[0]) * d[0] + (v_j[1] - v_i[1]) * d[1] + (v_j[2] - v_i[2]) * d[2]
        magnitude += grid.damping[row, slot] * along * inv_length * inv_length
    magnitude = ti.select(length_sq > 0, magnitude, 0.0)
    return [magnitude * d[c] for c in ti.static(range(3))]


def group_pass_function(packed, finish):
    """A ``ti.real_func`` (buffer, row, block, group, h) that sums the force on the SIMD_LANES
    particles of one group of ``packed`` (a ``PackedGrid``, packed copy ``buffer``, after the
    forward pass of row ``row`` and the ``rows_back`` rows before it in block ``block``:
    ``PackedGrid.each_group``) as three
    SIMD_LANES-vectors (x, y, z) and hands them to
    ``finish(buffer, row, group, h, f_x, f_y, f_z)``, a ``ti.func`` (``PackedGrid`` stores them
    per particle, ``EulerStep`` steps the lanes with step h [s]). The sum (the module docstring's
    step 2): the springs' forward forces of the lane and, negated, those of the springs whose
    forward slot is at the neighbour (``forward_force`` read shifted back by the slot's offset);
    then the stencil effects' (``Effect.allocate_lanes``), linear stencils: f −= C_s·(y_j − y_i)
    with the effect's coefficient C_s of the lane and slot (0 where there is none) and
    y = x + β·v with its dashpot's β [s] (``PackedGrid.damped_x``, copy ``buffer``: one shifted
    read a slot instead of two), or y = x without dashpots, in this loop, not in an inlined
    function of the effect's (a run-time loop in a function inlined into a real function crashed
    Taichi 1.7.4); then a third of the particle's six faces (``face_force``). A real function is
    compiled once per kernel however many substeps call it (inlined, its thousands of lane
    operations made compiles take seconds per call). The slots are unrolled (``ti.static``): as
    a run-time loop of 2-4 slots, LLVM's loop vectorizer vectorised it across the slots,
    fetching every lane of every slot with a gather, and the pass ran 26-40 % slower on an Intel
    AVX-512 host (docs/performance.md, "The slots unrolled")."""
    model = packed.model
    stencil_effects, face_force, forward_force = packed.stencil_effects, packed.face_force, \
        packed.forward_force
    # what each stencil effect reads: y = x + β·v where it has a dashpot (``damped_x``), else x
    stencil_sources = [damped or packed.packed_x for damped in packed.damped_x]
    grid, real = model.grid, model.real
    springs = [grid.slot_offsets[s] for s in packed.forward_slots]
    wrap = grid.wrapped_groups

    @ti.real_func
    def group_pass(buffer: ti.i32, row: ti.i32, block: ti.i32, group: ti.i32, h: real):
        force = [ti.Vector.zero(real, SIMD_LANES) for _ in ti.static(range(3))]
        ring = ring_row(packed, row)
        for k, offset in ti.static(enumerate(springs)):
            d_row, d_column = ti.static(offset)
            if row + d_row < grid.rows:  # (the ring holds another row's otherwise)
                for c in ti.static(range(3)):
                    force[c] += forward_force[k][c][block, ring, group]
            if row >= d_row:  # the spring from (row − Δrow, column − Δcolumn) to this lane
                source = ring_row(packed, row - d_row)
                for c in ti.static(range(3)):
                    force[c] -= packed_lanes(forward_force[k][c], block, source, group,
                                             -d_column, wrap)
        for e, effect in ti.static(enumerate(stencil_effects)):  # linear stencils
            source = ti.static(stencil_sources[e])
            y_i = [packed_lanes(source[c], buffer, row, group, 0, wrap)
                   for c in ti.static(range(3))]
            for run in ti.static(effect.lane_column_runs):
                column_step, first_slot, slot_count = ti.static(run)
                for s in ti.static(range(first_slot, first_slot + slot_count)):
                    neighbor_row = row + effect.lane_row_step[s]
                    if 0 <= neighbor_row < grid.rows:
                        coefficient = effect.lane_coefficient[row, group, s]
                        for c in ti.static(range(3)):
                            force[c] -= coefficient * (packed_lanes(
                                source[c], buffer, neighbor_row, group, column_step, wrap)
                                - y_i[c])
        for faces in ti.static(face_force):  # the thirds of the particle's six faces
            for c in ti.static(range(3)):
                # quad (row, column): both faces; (row, column − 1): the second; (row − 1,
                # column): the first; (row − 1, column − 1): both
                total = ti.Vector.zero(real, SIMD_LANES)
                if row < grid.rows - 1:
                    total += faces[0][c][block, ring, group] + faces[1][c][block, ring, group] \
                        + packed_lanes(faces[1][c], block, ring, group, -1, wrap)
                if row > 0:
                    before = ring_row(packed, row - 1)
                    total += packed_lanes(faces[0][c], block, before, group, 0, wrap) \
                        + packed_lanes(faces[0][c], block, before, group, -1, wrap) \
                        + packed_lanes(faces[1][c], block, before, group, -1, wrap)
                force[c] += total
        finish(buffer, row, group, h, force[0], force[1], force[2])

    return group_pass
