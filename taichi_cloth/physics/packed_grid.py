"""Packed copies of a grid cloth's state, and the SIMD pass of its springs over them.

A cloth on a regular grid has springs that are the same few neighbour offsets at every
particle, with rest lengths and stiffnesses that depend only on the row: a ``GridStencil``
(``physics.grid_stencil``, part of the constant model). ``PackedGrid`` holds positions (and
velocities) packed in groups of ``SIMD_LANES`` columns, component by component, and evaluates
the springs for a whole group with vector arithmetic (``physics.packed_pass``): the same spring
formula as the gather (``physics.forces``), each spring computed once and each particle summing
its own (no atomics), but LLVM turns the lanes into AVX-512 instructions. An effect whose
force is a linear stencil on the grid (bending's constant Hessian) can act in the same pass
(``Effect.allocate_lanes``: its coefficients per lane and slot in a packed table,
``GridStencil.packed_table``) instead of being gathered particle by particle afterwards.

The simulation chooses it (``packed_grid_for``) on the CPU when the cloth is a grid of at least
``PACKED_PARTICLE_MINIMUM`` particles and the integrator takes one force evaluation per step;
otherwise (and on every GPU arch) springs are gathered through the CSR lists one particle at a
time.
"""

import numpy as np
import taichi as ti

from taichi_cloth.cloth.topology import grid_triangles
from taichi_cloth.physics.grid_stencil import SIMD_LANES
from taichi_cloth.physics.packed_pass import forward_pass_function, forward_slots, \
    group_pass_function, ring_row
from taichi_cloth.runtime import runs_on_cpu

PACKED_PARTICLE_MINIMUM = 1024  # below it the CSR gather is as fast and compiles in a blink
# rows per block of a parallel launch (``PackedGrid.block_rows``): each block computes the
# forward pass of the rows before its first that its first reads again (one on `hula`'s
# stencil), 1/ROWS_PER_BLOCK more of it
ROWS_PER_BLOCK = 32
# Taichi 1.7.4's CPU backend gives each thread a run of at least this many iterations of a
# parallel loop: a loop over a few blocks would run on one thread (``PackedGrid.block_loop``)
CPU_LOOP_GRAIN = 512


@ti.data_oriented
class PackedGrid:
    """Packed copies of a grid cloth's state and the SIMD spring pass over them.

    ``packed_x``/``packed_v``: three fields (x, y, z) of SIMD_LANES-vectors indexed [buffer, row,
    group] (``GridStencil.packed_fields``); ``packed_force`` [N]: the pass's result, three
    fields of SIMD_LANES-vectors indexed [row, group]; ``packed_inv_mass`` [1/kg] per lane (0
    for pinned and halo lanes) and ``group_has_pin`` per group, for the integrators that step in
    the lanes; ``forward_force`` [N]: per forward slot of the springs (``forward_slots``), the
    spring's force on its owner lane, (x, y, z) fields indexed [block, ring row, group] as
    packed copies (``packed_lanes`` reads them shifted): per block of rows a ring of
    ``ring_rows`` rows (``packed_pass.ring_row``); ``lane_effects``: the effects whose forces
    the pass adds (``packed_pass``): ``stencil_effects`` (``Effect.allocate_lanes``) and
    ``face_effects`` (``Effect.lane_faces``, each with its ``face_force``).
    """

    def __init__(self, model, effects=(), rows_per_block: int = ROWS_PER_BLOCK):
        """effects: the scene's effects; those with a force that can act in the SIMD pass
        become its ``lane_effects``; ``rows_per_block``: of a parallel launch (``block_rows``)."""
        self.model = model
        self.rows_per_block = rows_per_block
        self.grid = model.grid
        grid = model.grid
        self.stencil_effects = [e for e in effects if e.has_force and e.allocate_lanes(grid)]
        self.face_effects = [e for e in effects if e.has_force and e.lane_faces] \
            if self._triangles_are_the_grids() else []
        self.lane_effects = self.stencil_effects + self.face_effects
        # the pass reads velocities for dashpots and faces
        self.needs_velocity = model.has_dashpots or bool(self.face_effects)
        self.packed_x = grid.packed_fields(model.real)
        self.packed_v = grid.packed_fields(model.real)
        # each spring once, from the end whose slot points forward (``packed_pass``)
        self.forward_slots = forward_slots(grid.slot_offsets)
        # blocks of rows that a parallel launch runs apart (``block_rows``), and the rows before
        # its own that a row's group pass reads: the forward slots' Δrow, the faces' 1
        self.block_count = -(-grid.rows // rows_per_block)
        self.rows_back = max([grid.slot_offsets[s][0] for s in self.forward_slots]
                             + [1 if self.face_effects else 0])
        self.ring_rows = self.rows_back + 1  # per block: a row and those its pass reads back
        # by whether the launch is serial, the extents (blocks, spread) of the loop over the
        # blocks, each block's work at spread 0: in parallel, ``CPU_LOOP_GRAIN`` iterations a
        # block, so that the threads take different blocks; serially one block of one
        self.block_loop = {True: (1, 1), False: (self.block_count, CPU_LOOP_GRAIN)}
        # per face effect, its pressure's third on the (TL, BL, BR) and (TL, BR, TR) triangles
        # of each quad [N], (x, y, z) fields of SIMD_LANES-vectors indexed [block, ring row,
        # group] (as packed copies, so ``packed_lanes`` reads them shifted); never written for
        # the last row
        self.face_force = [[grid.packed_fields(model.real, self.block_count, self.ring_rows)
                            for _ in range(2)] for _ in self.face_effects]
        self.face_triples = [triple for faces in self.face_force for triple in faces]
        # each spring's force on its forward end per forward slot [N], [block, ring row, group]
        # as the faces: 0 in lanes whose neighbour is off the grid's columns (the halo's too);
        # not written for a row whose neighbour row is off the grid (the group pass skips it)
        self.forward_force = [grid.packed_fields(model.real, self.block_count, self.ring_rows)
                              for _ in self.forward_slots]
        # per stencil effect with a dashpot (β ≠ 0 and the scene declares damping): y = x + β·v
        # of each packed copy of the state, made with it (``make_damped``; the lanes' step as
        # it steps them: ``store_damped``); None without
        self.damped_x = [grid.packed_fields(model.real)
                         if model.has_dashpots and effect.lane_damping != 0.0 else None
                         for effect in self.stencil_effects]
        # (fields, β [s]) of each damped stencil effect
        self.damped_stencils = [(damped, effect.lane_damping)
                                for damped, effect in zip(self.damped_x, self.stencil_effects)
                                if damped]
        self.damped_triples = [damped for damped, _ in self.damped_stencils]
        # whole vectors, as the pass computes them: stored lane by lane into [row, column]
        # (x, y, z side by side) LLVM left the whole pass unvectorised (~3x slower)
        self.packed_force = grid.lane_fields(model.real)
        columns = grid.columns
        # (first, last + 1) of the packed groups that hold grid columns
        self.filled_groups = (1, (2 * SIMD_LANES + columns - 1) // SIMD_LANES)
        # groups with a wrapped column in a lane (periodic grid): the first, and from the
        # first with a lane past the last column
        last_own_group = columns // SIMD_LANES  # groups 1 … this hold own columns only
        self.wrapping_groups = [0] + list(range(last_own_group + 1, grid.group_count))
        # whether those groups are copies to keep (a periodic grid whose reads do not wrap round
        # its own groups: ``GridStencil.wrapped_groups``)
        self.copies_halo = grid.periodic and not grid.wrapped_groups
        # per forward slot, the wrapping groups whose forces the group pass reads (shifted back
        # by the slot's Δcolumn: group 0's last lane for Δcolumn > 0, the first lanes after the
        # own columns for Δcolumn < 0)
        self.forward_halo = [[0] if d_column > 0 else self.wrapping_groups[1:] if d_column < 0
                             else [] for d_column in
                             (grid.slot_offsets[s][1] for s in self.forward_slots)]
        # per packed group: the lanes' inverse masses [1/kg] (0 for pinned and halo lanes),
        # and whether a lane is pinned
        self.packed_inv_mass = ti.Vector.field(SIMD_LANES, model.real,
                                               (grid.rows, grid.group_count))
        self.group_has_pin = ti.field(ti.i32, (grid.rows, grid.group_count))
        self.forward_pass = forward_pass_function(self)
        self.group_springs = group_pass_function(self, self._store_spring_force)
        self._upload_constants()

    @ti.func
    def spring_pass(self, x, v):
        """Every particle's spring force (and its lane effects') into ``packed_force``: pack
        (x, v) into packed copy 0, then the SIMD stencil pass, blocks of rows in parallel."""
        self.pack(x, v, 0, self.needs_velocity)
        self.make_damped(0)
        self.each_group(0, False, self.forward_pass, self._spring_group, (), 0.0, 0.0)

    @ti.func
    def _spring_group(self, buffer, row, block, group, states: ti.template(), t, dt):
        """``spring_pass``'s work on a group: its sum into ``packed_force``."""
        self.group_springs(buffer, row, block, group, 0.0)

    @ti.func
    def each_group(self, buffer, serial: ti.template(), forward_pass: ti.template(),
                   group_work: ti.template(), states: ti.template(), t, dt):
        """Row by row in blocks of rows (``block_rows``: in parallel, or, ``serial``, all rows
        in one block), each row's forward pass from packed copy ``buffer`` (``forward_row``,
        with the caller's own ``forward_pass``; first, in each block, that of the ``rows_back``
        rows before its first that are in the grid, which its first row's groups read), then
        ``group_work(buffer, row, block, group, states, t, dt)`` for each of its groups
        (``states``: what the work reads and writes besides the lanes, t [s] and dt [s] its
        time and step)."""
        for block, spread in ti.ndrange(*self.block_loop[serial]):
            if spread == 0:
                first, end = self.block_rows(block, serial)
                for back in range(ti.max(first - self.rows_back, 0), first):
                    self.forward_row(buffer, back, block, forward_pass)
                for row in range(first, end):
                    self.forward_row(buffer, row, block, forward_pass)
                    for group in range(self.filled_groups[0], self.filled_groups[1]):
                        group_work(buffer, row, block, group, states, t, dt)

    def _triangles_are_the_grids(self) -> bool:
        """Whether the cloth's triangles are the grid's (``cloth.topology.grid_triangles``: each
        quad (r, c) split into (r, c), (r + 1, c), (r + 1, c + 1) and (r, c), (r + 1, c + 1),
        (r, c + 1)), as the forward pass's faces assume."""
        grid = self.grid
        expected = grid_triangles(grid.columns, grid.rows, grid.periodic)
        triangles = self.model.garment.triangles
        return triangles.shape == expected.shape and np.array_equal(
            np.unique(np.sort(triangles, axis=1), axis=0),
            np.unique(np.sort(expected, axis=1), axis=0))

    @ti.func
    def block_rows(self, block, serial: ti.template()):
        """The rows (first, last + 1) of block ``block``: ``rows_per_block`` of them, or in a
        serial launch (``serial``, block 0 only) every row."""
        first, end = 0, self.grid.rows
        if ti.static(not serial):
            first = block * self.rows_per_block
            end = ti.min(first + self.rows_per_block, self.grid.rows)
        return first, end

    @ti.func
    def forward_row(self, buffer, row, block, forward_pass: ti.template()):
        """What the group passes read of row ``row`` (into block ``block``'s ring) besides
        packed copy ``buffer`` of the state and its damped stencils' y (``make_damped``), from
        ``forward_pass`` (``packed_pass.forward_pass_function``: the caller's own): the forward
        springs' forces and the face effects' pressures of the row, then their halo
        (``copy_forward_halo``)."""
        forward_pass(buffer, row, block)
        self.copy_forward_halo(row, block)

    @ti.func
    def copy_forward_halo(self, row, block):
        """On a periodic grid with a halo (``copies_halo``), the lanes of row ``row``'s forward
        forces and faces (in block ``block``'s ring) that the group pass reads outside the own
        columns copied from the lanes they wrap (``forward_halo``; the faces: the last lane of
        group 0). On an open grid those lanes hold 0, never written; on a periodic grid of whole
        groups the reads wrap round instead."""
        if ti.static(self.copies_halo):
            ring = ring_row(self, row)
            for k in ti.static(range(len(self.forward_slots))):
                self._copy_halo_row([self.forward_force[k]], block, ring, self.forward_halo[k])
            if ti.static(self.face_effects):
                self._copy_halo_row(self.face_triples, block, ring, [0])

    @ti.func
    def make_damped(self, buffer):
        """Each damped stencil effect's y = x + β·v of packed copy ``buffer`` (``damped_x``),
        every group, the halo's too (nothing without one)."""
        if ti.static(self.damped_triples):
            for row, group in ti.ndrange(self.grid.rows, self.grid.group_count):
                for c in ti.static(range(3)):
                    self.store_damped(buffer, row, group, c, self.packed_x[c][buffer, row, group],
                                      self.packed_v[c][buffer, row, group])

    @ti.func
    def store_damped(self, buffer, row, group, c: ti.template(), x, v):
        """Component c of each damped stencil effect's y = x + β·v [m] (``damped_x``) of the
        lanes of group ``group`` of row ``row`` in packed copy ``buffer`` at positions x [m] and
        velocities v [m/s] (SIMD_LANES-vectors)."""
        for damped, beta in ti.static(self.damped_stencils):
            damped[c][buffer, row, group] = self._damped(x, v, beta)

    @ti.func
    def _damped(self, x, v, beta: ti.template()):
        """y = x + β·v [m] of positions x [m] and velocities v [m/s] with the dashpot's β [s]."""
        return x + self.model.real(beta) * v

    @ti.func
    def spring_force(self, i_p):
        """Particle i_p's spring force (and its lane effects') [N] from the last
        ``spring_pass``."""
        row, group, lane = self.particle_lane(i_p)
        return ti.Vector([self.packed_force[c][row, group][lane] for c in ti.static(range(3))])

    @ti.func
    def particle_lane(self, i_p):
        """(row, group, lane) of particle i_p's own lane."""
        row, column = i_p // self.grid.columns, i_p % self.grid.columns
        return row, column // SIMD_LANES + 1, column % SIMD_LANES

    @ti.func
    def lane_value(self, fields: ti.template(), copy, i_p):
        """Particle i_p's 3-vector in its lane of packed copy ``copy`` of the (x, y, z)
        ``fields`` of SIMD_LANES-vectors [copy, row, group]."""
        row, group, lane = self.particle_lane(i_p)
        return ti.Vector([fields[c][copy, row, group][lane] for c in ti.static(range(3))])

    @ti.func
    def store_lane_value(self, fields: ti.template(), i_p, value):
        """``value`` (3-vector) into particle i_p's lane of the (x, y, z) ``fields`` of
        SIMD_LANES-vectors [row, group]."""
        row, group, lane = self.particle_lane(i_p)
        for c in ti.static(range(3)):
            fields[c][row, group][lane] = value[c]

    @ti.func
    def group_particles(self, row, group):
        """The particles of packed group ``group`` of row ``row``: (first, last + 1)."""
        first_column = (group - 1) * SIMD_LANES
        return (row * self.grid.columns + first_column,
                row * self.grid.columns + ti.min(first_column + SIMD_LANES, self.grid.columns))

    @ti.func
    def _store_spring_force(self, buffer, row, group, h, f_x, f_y, f_z):
        """A group's spring forces into ``packed_force`` [N], whole vectors (halo lanes too)."""
        for c, f_c in ti.static(enumerate((f_x, f_y, f_z))):
            self.packed_force[c][row, group] = f_c

    def _upload_constants(self) -> None:
        """The lanes' inverse masses and pins, for the model's ``uploads``."""
        grid = self.grid
        inv_mass = self.model.host_inv_mass.reshape(grid.rows, grid.columns)
        lanes = np.zeros((grid.rows, grid.group_count * SIMD_LANES), self.model.numpy_real)
        lanes[:, SIMD_LANES:SIMD_LANES + grid.columns] = inv_mass
        pinned = np.zeros(lanes.shape, dtype=bool)
        pinned[:, SIMD_LANES:SIMD_LANES + grid.columns] = inv_mass == 0
        self.model.uploads.add([
            (self.packed_inv_mass, lanes.reshape(grid.rows, grid.group_count, SIMD_LANES)),
            (self.group_has_pin, pinned.reshape(grid.rows, grid.group_count, SIMD_LANES)
             .any(axis=2).astype(np.int32))])

    @ti.func
    def pack(self, x, v, buffer, with_velocity: ti.template()):
        """x (and v, ``with_velocity``) into packed copy ``buffer`` (model.GridStencil). Halo
        lanes hold the wrapped columns of a periodic grid, else the nearest edge column (finite
        values that the spring pass masks out)."""
        for row, group in ti.ndrange(self.grid.rows, self.grid.group_count):
            self._pack_group(x, self.packed_x, buffer, row, group)
            if ti.static(with_velocity):
                self._pack_group(v, self.packed_v, buffer, row, group)

    @ti.func
    def _pack_group(self, source, packed: ti.template(), buffer, row, group):
        grid = self.grid
        values = [ti.Vector.zero(self.model.real, SIMD_LANES) for _ in ti.static(range(3))]
        for lane in range(SIMD_LANES):  # a loop, not unrolled: each unrolled copy compiled slowly
            position = source[row * grid.columns + self._packed_source_column(group, lane)]
            for c in ti.static(range(3)):
                values[c][lane] = position[c]
        for c in ti.static(range(3)):
            packed[c][buffer, row, group] = values[c]

    @ti.func
    def _packed_source_column(self, group, lane):
        """The grid column that lane ``lane`` of packed group ``group`` holds."""
        grid = self.grid
        column = group * SIMD_LANES + lane - SIMD_LANES
        if ti.static(grid.periodic):
            column = (column + grid.columns) % grid.columns
        else:
            column = ti.min(ti.max(column, 0), grid.columns - 1)
        return column

    @ti.func
    def store_lane(self, buffer, i_p, x_value, v_value):
        """Particle i_p's (x, v) into its own lane of packed copy ``buffer``, and its damped
        stencils' y = x + β·v."""
        row, group, lane = self.particle_lane(i_p)
        for c in ti.static(range(3)):
            self.packed_x[c][buffer, row, group][lane] = x_value[c]
            self.packed_v[c][buffer, row, group][lane] = v_value[c]
            for damped, beta in ti.static(self.damped_stencils):
                damped[c][buffer, row, group][lane] = self._damped(x_value[c], v_value[c], beta)

    @ti.func
    def refresh_halo(self, buffer):
        """The halo lanes of packed copy ``buffer`` (and of its damped stencils' y) from the own
        lanes of the columns they copy (a periodic grid with a halo, ``copies_halo``), after a
        step that updated the packed state in place: each group that holds a wrapped column made
        again whole from the groups its lanes come from (``GridStencil.halo_sources``; lane by
        lane, each store waiting on the last: ~8x longer)."""
        if ti.static(self.copies_halo):
            self._copy_halo([self.packed_x, self.packed_v] + self.damped_triples, buffer,
                            self.grid.rows, self.wrapping_groups)

    @ti.func
    def _copy_halo(self, fields: ti.template(), copy, rows: ti.template(),
                   groups: ti.template()):
        """Packed copy ``copy`` of each (x, y, z) field triple in ``fields``: the ``groups``
        (wrapping groups of a periodic grid) of its first ``rows`` rows made again whole from the
        own lanes their lanes copy (``GridStencil.halo_sources``)."""
        for row in range(rows):
            self._copy_halo_row(fields, copy, row, groups)

    @ti.func
    def _copy_halo_row(self, fields: ti.template(), copy, row, groups: ti.template()):
        """``_copy_halo`` of row ``row`` alone."""
        for group in ti.static(groups):
            sources, picks = ti.static(self.grid.halo_sources(group))
            for triple in ti.static(fields):
                for c in ti.static(range(3)):
                    loaded = [triple[c][copy, row, source] for source in ti.static(sources)]
                    triple[c][copy, row, group] = ti.Vector(
                        [loaded[ti.static(picks[lane][0])][ti.static(picks[lane][1])]
                         for lane in ti.static(range(SIMD_LANES))])

    @ti.func
    def unpack(self, buffer, state, with_velocity: ti.template()):
        """Packed copy ``buffer`` into ``state`` (x, and v ``with_velocity``), a group at a
        time: its vectors loaded whole, then each lane's values stored."""
        for row, group in ti.ndrange(self.grid.rows, ti.static(self.filled_groups)):
            first, end = self.group_particles(row, group)
            x = [self.packed_x[c][buffer, row, group] for c in ti.static(range(3))]
            v = [self.packed_v[c][buffer, row, group] for c in ti.static(range(3))]
            for i_p in range(first, end):
                lane = i_p - first
                state.x[i_p] = ti.Vector([x[c][lane] for c in ti.static(range(3))])
                if ti.static(with_velocity):
                    state.v[i_p] = ti.Vector([v[c][lane] for c in ti.static(range(3))])


@ti.data_oriented
class PackedParticles:
    """Packed copy ``copy`` of a ``PackedGrid``'s (x, y, z) field triple (``packed_x`` or
    ``packed_v``) read by particle, ``view[i_p]`` a 3-vector, as the effects read x and v: the
    lanes' state handed to the effects' passes without unpacking it."""

    def __init__(self, packed: PackedGrid, fields, copy):
        self.packed, self.fields, self.copy = packed, fields, copy

    @ti.func
    def __getitem__(self, i_p):
        return self.packed.lane_value(self.fields, self.copy, i_p)


def packed_grid_for(model, wanted: bool, effects=(),
                    rows_per_block: int = ROWS_PER_BLOCK) -> PackedGrid | None:
    """A ``PackedGrid`` (with ``effects`` that can act in its lanes) when ``wanted`` (an
    integrator with one force evaluation per step), the runtime is on the CPU and the cloth is
    a grid of at least ``PACKED_PARTICLE_MINIMUM`` particles; None otherwise. The lanes are the
    CPU's SIMD registers: on a GPU each thread would step a group of 16 particles (16 times
    fewer threads than particles), and CUDA compiled the pass with bending, drag and contact
    for over 5.5 minutes on an H100 (docs/performance.md), where the gather's one thread per
    particle is what the GPU runs well."""
    if wanted and runs_on_cpu() and model.grid is not None \
            and model.particle_count >= PACKED_PARTICLE_MINIMUM:
        return PackedGrid(model, effects, rows_per_block)
    return None
