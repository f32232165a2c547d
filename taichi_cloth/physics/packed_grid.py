"""The SIMD layout of a grid cloth's springs: a stencil, and packed copies of the state.

A cloth on a regular grid (sheets and skirts from ``cloth.garment``) has springs that are the same
few neighbour offsets at every particle, with rest lengths and stiffnesses that depend only on
the row: a ``GridStencil`` (part of the constant model). ``PackedGrid`` holds positions (and
velocities) packed in groups of ``SIMD_LANES`` columns, component by component, and evaluates
every stencil slot for a whole group with vector arithmetic (``group_pass_function``): the same
spring formula as the gather (``physics.forces``), each particle still summing its own springs in
slot order (no atomics), but LLVM turns the lanes into AVX-512 instructions.

The simulation chooses it (``packed_grid_for``) when the cloth is a grid of at least
``PACKED_PARTICLE_MINIMUM`` particles and the integrator takes one force evaluation per step;
otherwise springs are gathered through the CSR lists one particle at a time.
"""

import numpy as np
import taichi as ti


PACKED_PARTICLE_MINIMUM = 1024  # below it the CSR gather is as fast and compiles in a blink
SIMD_LANES = 16  # columns per packed group: one AVX-512 register of float32
STENCIL_REACH = 2  # the farthest neighbour offset a stencil may have, rows or columns
PACKED_BUFFERS = 2  # packed copies of a state: the one a substep reads, the one it writes


@ti.data_oriented
class GridStencil:
    """Springs of a grid cloth as a stencil: slot s of a particle in row r links it to the
    particle ``slot_offsets[s]`` = (Δrow, Δcolumn) away (columns wrap when ``periodic``; slots
    ordered by Δcolumn, then Δrow), with
    rest length ``rest_length[r, s]`` [m], stiffness ``stiffness[r, s]`` [N/m] and damping
    ``damping[r, s]`` [N·s/m]. A slot whose neighbour is off the grid has no spring.

    Positions are packed for the SIMD pass as ``rows × group_count`` groups of ``SIMD_LANES``
    columns, component by component; packed column p holds grid column p − SIMD_LANES (the first
    group and the tail are halo: copies of the wrapped columns when periodic, unused otherwise).
    There are ``PACKED_BUFFERS`` such copies, so a substep can read one while it writes the next
    (the Euler integrators carry the packed state from substep to substep).
    """

    def __init__(self, columns: int, rows: int, periodic: bool, slot_offsets: list,
                 rest_length: np.ndarray, stiffness: np.ndarray, damping: np.ndarray, real):
        self.columns, self.rows, self.periodic = columns, rows, periodic
        self.slot_offsets = slot_offsets
        self.slot_count = len(slot_offsets)
        # (column step, first slot, slot count): slots sharing a column step are contiguous
        column_steps = [offset[1] for offset in slot_offsets]
        self.column_runs = [(step, column_steps.index(step), column_steps.count(step))
                            for step in sorted(set(column_steps))]
        self.group_count = (SIMD_LANES + columns + STENCIL_REACH - 1) // SIMD_LANES + 1
        # every field first, then the copies (see Model.__init__)
        self.slot_row_step = ti.field(ti.i32, self.slot_count)
        self.rest_length = ti.field(real, (rows, self.slot_count))
        self.stiffness = ti.field(real, (rows, self.slot_count))
        self.damping = ti.field(real, (rows, self.slot_count))
        self._tables = (rest_length, stiffness, damping)

    def field_values(self) -> list:
        """(field, array) of the tables, for the model's ``uploads``."""
        numpy_real = np.float64 if self.rest_length.dtype == ti.f64 else np.float32
        return [(self.slot_row_step, np.array([step for step, _ in self.slot_offsets], np.int32)),
                *((table, np.ascontiguousarray(values, dtype=numpy_real)) for table, values in
                  zip((self.rest_length, self.stiffness, self.damping), self._tables))]

    def packed_fields(self, real) -> list:
        """Three fields (x, y, z) of SIMD_LANES-vectors indexed [buffer, row, group], so a group
        loads as one vector."""
        return [ti.Vector.field(SIMD_LANES, real, (PACKED_BUFFERS, self.rows, self.group_count))
                for _ in range(3)]


def grid_stencil(garment, ends: np.ndarray, rest_length: np.ndarray,
                 stiffness: np.ndarray, damping: np.ndarray, real) -> GridStencil | None:
    """The garment's springs as a ``GridStencil``, or None when they are not one: every spring
    must join grid neighbours at most ``STENCIL_REACH`` apart, every in-grid slot must hold
    exactly one spring, and rest length, stiffness and damping may depend on the row only
    (relative spread ≤ 1e-9; the table keeps the row's first value)."""
    columns, rows = garment.columns, garment.rows
    if columns * rows != garment.particle_count or not len(ends) or columns < 2 * STENCIL_REACH + 1:
        return None
    row, column = np.divmod(ends, columns)
    row_step = row[:, 1] - row[:, 0]
    column_step = column[:, 1] - column[:, 0]
    if garment.periodic:
        column_step = (column_step + columns // 2) % columns - columns // 2
    if np.max(np.abs(row_step)) > STENCIL_REACH or np.max(np.abs(column_step)) > STENCIL_REACH:
        return None
    # Both ends see the spring: from i at offset (Δr, Δc), from j at (−Δr, −Δc).
    owner = np.concatenate([ends[:, 0], ends[:, 1]])
    steps = np.concatenate([np.stack([row_step, column_step], 1),
                            np.stack([-row_step, -column_step], 1)])
    width = 2 * STENCIL_REACH + 1
    code = (steps[:, 1] + STENCIL_REACH) * width + steps[:, 0] + STENCIL_REACH
    codes, slot = np.unique(code, return_inverse=True)  # slots by column step, then row step
    slot_offsets = [(int(c) % width - STENCIL_REACH, int(c) // width - STENCIL_REACH)
                    for c in codes]
    owner_row = owner // columns
    if len(np.unique(owner * len(slot_offsets) + slot)) != len(owner):
        return None  # two springs in one slot
    expected = 0
    for d_row, d_column in slot_offsets:
        in_rows = np.count_nonzero((np.arange(rows) + d_row >= 0) & (np.arange(rows) + d_row < rows))
        in_columns = columns if garment.periodic else np.count_nonzero(
            (np.arange(columns) + d_column >= 0) & (np.arange(columns) + d_column < columns))
        expected += in_rows * in_columns
    if expected != len(owner):
        return None  # an in-grid slot without its spring
    key = owner_row * len(slot_offsets) + slot
    present, first, entry = np.unique(key, return_index=True, return_inverse=True)
    tables = []
    for values in (rest_length, stiffness, damping):
        both = np.concatenate([values, values])
        if not np.allclose(both, both[first][entry], rtol=1e-9, atol=0.0):
            return None
        table = np.zeros(rows * len(slot_offsets))
        table[present] = both[first]
        tables.append(table.reshape(rows, len(slot_offsets)))
    return GridStencil(columns, rows, garment.periodic, slot_offsets, *tables, real)


@ti.func
def packed_lanes(packed_component: ti.template(), buffer, row, group,
                 column_step: ti.template()):
    """The SIMD_LANES values of packed columns group·SIMD_LANES + lane + column_step."""
    groups = (packed_component[buffer, row, group - 1], packed_component[buffer, row, group],
              packed_component[buffer, row, group + 1])
    return ti.Vector([groups[(lane + column_step + SIMD_LANES) // SIMD_LANES]
                      [(lane + column_step) % SIMD_LANES]
                      for lane in ti.static(range(SIMD_LANES))])


def group_pass_function(model, packed_x: list, packed_v: list, finish):
    """A ``ti.real_func`` (buffer, row, group, h) that computes the spring (and dashpot) force on
    the SIMD_LANES particles of one packed group of packed copy ``buffer`` as three
    SIMD_LANES-vectors (x, y, z) and hands them to ``finish(buffer, row, group, h, f_x, f_y,
    f_z)``, a ``ti.func`` (``Forces`` stores them per particle, ``EulerStep`` steps the lanes
    with step h [s]). Per slot, with d = x_j − x_i and 1/l = 1/√(d·d):

        f += [k·(1 − L/l) + c·((v_j − v_i)·d)/l²]·d,

    the module docstring's formula with n = d/l; a slot off the grid (or a zero-length spring)
    adds nothing. Each lane sums its own slots in slot order (a gather). A real function is
    compiled once per kernel however many substeps call it (inlined, its thousands of lane
    operations made compiles take seconds per call)."""
    grid, real = model.grid, model.real
    has_dashpots = model.has_dashpots
    lane_index = ti.Vector(list(range(SIMD_LANES)))

    @ti.real_func
    def group_pass(buffer: ti.i32, row: ti.i32, group: ti.i32, h: real):
        column = (group - 1) * SIMD_LANES + lane_index
        x_i = [packed_lanes(packed_x[c], buffer, row, group, 0) for c in ti.static(range(3))]
        force = [ti.Vector.zero(real, SIMD_LANES) for _ in ti.static(range(3))]
        for run in ti.static(grid.column_runs):
            column_step, first_slot, slot_count = ti.static(run)
            present_column = column >= 0  # every lane
            if ti.static(not grid.periodic):
                present_column = (column + column_step >= 0) & (column + column_step < grid.columns)
            for s in range(first_slot, first_slot + slot_count):
                neighbor_row = row + grid.slot_row_step[s]
                if 0 <= neighbor_row < grid.rows:
                    d = [packed_lanes(packed_x[c], buffer, neighbor_row, group, column_step)
                         - x_i[c]
                         for c in ti.static(range(3))]
                    length_sq = d[0] * d[0] + d[1] * d[1] + d[2] * d[2]
                    inv_length = 1.0 / ti.sqrt(length_sq)
                    magnitude = grid.stiffness[row, s] * (1.0 - grid.rest_length[row, s]
                                                          * inv_length)
                    if ti.static(has_dashpots):
                        along = ti.Vector.zero(real, SIMD_LANES)
                        for c in ti.static(range(3)):
                            along += (packed_lanes(packed_v[c], buffer, neighbor_row, group,
                                                   column_step)
                                      - packed_lanes(packed_v[c], buffer, row, group, 0)) * d[c]
                        magnitude += grid.damping[row, s] * along * inv_length * inv_length
                    magnitude = ti.select(present_column & (length_sq > 0), magnitude, 0.0)
                    for c in ti.static(range(3)):
                        force[c] += magnitude * d[c]
        finish(buffer, row, group, h, force[0], force[1], force[2])

    return group_pass


@ti.data_oriented
class PackedGrid:
    """Packed copies of a grid cloth's state and the SIMD spring pass over them.

    ``packed_x``/``packed_v``: three fields (x, y, z) of SIMD_LANES-vectors indexed [buffer, row,
    group] (``GridStencil.packed_fields``); ``grid_spring_force`` [N]: the spring pass's result per
    [row, column]; ``packed_inv_mass`` [1/kg] per lane (0 for pinned and halo lanes) and
    ``group_has_pin`` per group, for the integrators that step in the lanes.
    """

    def __init__(self, model):
        self.model = model
        self.grid = model.grid
        grid = model.grid
        self.packed_x = grid.packed_fields(model.real)
        self.packed_v = grid.packed_fields(model.real)
        # [row, column] up to the last filled group's last lane (the pass stores whole groups)
        self.grid_spring_force = ti.Vector.field(
            3, model.real, (grid.rows, SIMD_LANES * grid.group_count))
        columns = grid.columns
        # (first, last + 1) of the packed groups that hold grid columns
        self.filled_groups = (1, (2 * SIMD_LANES + columns - 1) // SIMD_LANES)
        # groups with a wrapped column in a lane (periodic grid): the first, and from the
        # first with a lane past the last column
        self.last_own_group = columns // SIMD_LANES  # groups 1 … this hold own columns only
        self.wrapping_groups = [0] + list(range(self.last_own_group + 1, grid.group_count))
        self.wrapping_group = ti.field(ti.i32, len(self.wrapping_groups))
        # per packed group: the lanes' inverse masses [1/kg] (0 for pinned and halo lanes),
        # and whether a lane is pinned
        self.packed_inv_mass = ti.Vector.field(SIMD_LANES, model.real,
                                               (grid.rows, grid.group_count))
        self.group_has_pin = ti.field(ti.i32, (grid.rows, grid.group_count))
        self.group_springs = group_pass_function(model, self.packed_x, self.packed_v,
                                                 self._store_spring_force)
        self._upload_constants()

    @ti.func
    def spring_pass(self, x, v):
        """Every particle's spring force into ``grid_spring_force``: pack (x, v) into packed copy
        0, then the SIMD stencil pass."""
        self.pack(x, v, 0, self.model.has_dashpots)
        for row, group in ti.ndrange(self.grid.rows, ti.static(self.filled_groups)):
            self.group_springs(0, row, group, 0.0)

    @ti.func
    def spring_force(self, i_p):
        """Particle i_p's spring force [N] from the last ``spring_pass``."""
        return self.grid_spring_force[i_p // self.grid.columns, i_p % self.grid.columns]

    @ti.func
    def group_particles(self, row, group):
        """The particles of packed group ``group`` of row ``row``: (first, last + 1)."""
        first_column = (group - 1) * SIMD_LANES
        return (row * self.grid.columns + first_column,
                row * self.grid.columns + ti.min(first_column + SIMD_LANES, self.grid.columns))

    @ti.func
    def _store_spring_force(self, buffer, row, group, h, f_x, f_y, f_z):
        """A group's spring forces into ``grid_spring_force`` [N], lane by lane (halo lanes
        too: no branch, which a function inlined into a real function must not have in
        Taichi 1.7.4, it crashes the compiler)."""
        for lane in ti.static(range(SIMD_LANES)):
            self.grid_spring_force[row, (group - 1) * SIMD_LANES + lane] = ti.Vector(
                [f_x[lane], f_y[lane], f_z[lane]])

    def _upload_constants(self) -> None:
        """The lanes' inverse masses and pins, for the model's ``uploads``."""
        grid = self.grid
        inv_mass = self.model.host_inv_mass.reshape(grid.rows, grid.columns)
        lanes = np.zeros((grid.rows, grid.group_count * SIMD_LANES), self.model.numpy_real)
        lanes[:, SIMD_LANES:SIMD_LANES + grid.columns] = inv_mass
        pinned = np.zeros(lanes.shape, dtype=bool)
        pinned[:, SIMD_LANES:SIMD_LANES + grid.columns] = inv_mass == 0
        self.model.uploads.add([
            (self.wrapping_group, np.array(self.wrapping_groups, np.int32)),
            (self.packed_inv_mass, lanes.reshape(grid.rows, grid.group_count, SIMD_LANES)),
            (self.group_has_pin, pinned.reshape(grid.rows, grid.group_count, SIMD_LANES)
             .any(axis=2).astype(np.int32))])

    @ti.func
    def pack(self, x, v, buffer, with_velocity: ti.template()):
        """x (and v, ``with_velocity``) into packed copy ``buffer`` (model.GridStencil)."""
        for row, group in ti.ndrange(self.grid.rows, self.grid.group_count):
            self.pack_group(x, v, buffer, row, group, with_velocity)

    @ti.func
    def pack_halo(self, x, v, buffer, with_velocity: ti.template()):
        """The groups of packed copy ``buffer`` that hold wrapped columns (periodic grid)."""
        for row, k in ti.ndrange(self.grid.rows, ti.static(len(self.wrapping_groups))):
            self.pack_group(x, v, buffer, row, self.wrapping_group[k], with_velocity)

    @ti.func
    def pack_group(self, x, v, buffer, row, group, with_velocity: ti.template()):
        """One group of packed copy ``buffer`` from x (and v). Halo lanes hold the wrapped
        columns of a periodic grid, else the nearest edge column (finite values that the spring
        pass masks out)."""
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
        """Particle i_p's (x, v) into its own lane of packed copy ``buffer``."""
        grid = self.grid
        column = i_p % grid.columns
        self._write_lane(buffer, i_p // grid.columns, column // SIMD_LANES + 1,
                         column % SIMD_LANES, x_value, v_value)

    @ti.func
    def _write_lane(self, buffer, row, group, lane, x_value, v_value):
        for c in ti.static(range(3)):
            self.packed_x[c][buffer, row, group][lane] = x_value[c]
            self.packed_v[c][buffer, row, group][lane] = v_value[c]

    @ti.func
    def load_lane(self, buffer, row, column):
        """(x, v) of grid column ``column`` of row ``row`` from its own lane of packed copy
        ``buffer``."""
        group, lane = column // SIMD_LANES + 1, column % SIMD_LANES
        return (ti.Vector([self.packed_x[c][buffer, row, group][lane]
                           for c in ti.static(range(3))]),
                ti.Vector([self.packed_v[c][buffer, row, group][lane]
                           for c in ti.static(range(3))]))

    @ti.func
    def refresh_halo(self, buffer):
        """The halo lanes of packed copy ``buffer`` from the own lanes of the columns they copy
        (periodic grid), after a step that updated the packed state in place."""
        grid = self.grid
        for row, k in ti.ndrange(grid.rows, ti.static(len(self.wrapping_groups))):
            group = self.wrapping_group[k]
            for lane in range(SIMD_LANES):
                own_column = group * SIMD_LANES + lane - SIMD_LANES
                if not 0 <= own_column < grid.columns:
                    x_value, v_value = self.load_lane(buffer, row,
                                                      self._packed_source_column(group, lane))
                    self._write_lane(buffer, row, group, lane, x_value, v_value)

    @ti.func
    def unpack(self, buffer, state):
        """Packed copy ``buffer`` into ``state`` (x and v)."""
        grid = self.grid
        for i_p in range(self.model.particle_count):
            state.x[i_p], state.v[i_p] = self.load_lane(buffer, i_p // grid.columns,
                                                        i_p % grid.columns)


def packed_grid_for(model, wanted: bool) -> PackedGrid | None:
    """A ``PackedGrid`` when ``wanted`` (an integrator with one force evaluation per step) and the
    cloth is a grid of at least ``PACKED_PARTICLE_MINIMUM`` particles; None otherwise."""
    if wanted and model.grid is not None and model.particle_count >= PACKED_PARTICLE_MINIMUM:
        return PackedGrid(model)
    return None
