"""A grid cloth's springs as a stencil (part of the constant model), the host-side layout of any
stencil on the grid for the SIMD lanes of ``physics.packed_grid``, and the lanes' shifted reads
(``packed_lanes``).

A cloth on a regular grid (sheets and skirts from ``cloth.garment``) has springs that are the same
few neighbour offsets at every particle, with rest lengths and stiffnesses that depend only on
the row: a ``GridStencil``. An effect whose force is a linear stencil on the grid (bending's
constant Hessian) lays its coefficients out per lane and slot the same way
(``GridStencil.lane_slots``, ``packed_table``).
"""

import numpy as np
import taichi as ti

SIMD_LANES = 16  # columns per packed group: one AVX-512 register of float32
STENCIL_REACH = 2  # the farthest neighbour offset a stencil may have, rows or columns
PACKED_BUFFERS = 2  # packed copies of a state: the one a substep reads, the one it writes


def lane_sources(column_step: int) -> tuple:
    """Where the lanes of a group shifted by ``column_step`` columns come from: (the group
    offsets read, each lane's (index among them, lane))."""
    sources = [divmod(lane + column_step, SIMD_LANES) for lane in range(SIMD_LANES)]
    offsets = sorted({offset for offset, _ in sources})
    return offsets, [(offsets.index(offset), lane) for offset, lane in sources]


@ti.func
def packed_lanes(packed_component: ti.template(), buffer, row, group,
                 column_step: ti.template(), wrap: ti.template()):
    """The SIMD_LANES values of packed columns group·SIMD_LANES + lane + column_step (reading
    only the groups they lie in): with ``wrap`` = 0 from the halo groups past either end, else
    (``GridStencil.wrapped_groups``, a periodic grid of ``wrap`` whole groups) from the own group
    they wrap to, so that no halo need be kept."""
    offsets, picks = ti.static(lane_sources(column_step))
    groups = [packed_component[buffer, row, source_group(group, offset, wrap)]
              for offset in ti.static(offsets)]
    return ti.Vector([groups[ti.static(picks[lane][0])][ti.static(picks[lane][1])]
                      for lane in ti.static(range(SIMD_LANES))])


@ti.func
def source_group(group, offset: ti.template(), wrap: ti.template()):
    """The packed group ``offset`` groups from own group ``group`` (1 … ``wrap``), wrapped round
    the ``wrap`` own groups of a periodic grid (``wrap`` = 0: not wrapped, a halo group at
    either end)."""
    source = group + offset
    if ti.static(wrap and offset < 0):
        source = ti.select(source < 1, source + wrap, source)
    if ti.static(wrap and offset > 0):
        source = ti.select(source > wrap, source - wrap, source)
    return source


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
        # a periodic grid of whole groups of lanes: a read past either end wraps round to the
        # own groups (``packed_lanes``), so the halo groups need no copies (0: it has a halo)
        self.wrapped_groups = columns // SIMD_LANES \
            if periodic and columns % SIMD_LANES == 0 else 0
        # a halo group before the columns' groups and one after: a group's vector reads reach
        # into its neighbours (``packed_lanes``, up to STENCIL_REACH ≤ SIMD_LANES)
        self.group_count = (columns + SIMD_LANES - 1) // SIMD_LANES + 2
        # every field first, then the copies (see Model.__init__)
        self.rest_length = ti.field(real, (rows, self.slot_count))
        self.stiffness = ti.field(real, (rows, self.slot_count))
        self.damping = ti.field(real, (rows, self.slot_count))
        self._tables = (rest_length, stiffness, damping)

    def field_values(self) -> list:
        """(field, array) of the tables, for the model's ``uploads``."""
        numpy_real = np.float64 if self.rest_length.dtype == ti.f64 else np.float32
        return [(table, np.ascontiguousarray(values, dtype=numpy_real)) for table, values in
                zip((self.rest_length, self.stiffness, self.damping), self._tables)]

    def lane_slots(self, owner: np.ndarray, other: np.ndarray):
        """The slots of entries owner → other (particle indices) as a stencil like the springs':
        (slot offsets (Δrow, Δcolumn) ordered by Δcolumn, then Δrow; their ``column_runs``;
        each entry's slot), or None when there are no entries, when an entry reaches farther than
        ``STENCIL_REACH`` or when two entries of a particle share a slot. For an effect that acts
        in the SIMD pass (``Effect.allocate_lanes``)."""
        row_step, column_step = grid_steps(self.columns, self.periodic, owner, other)
        if not len(owner) \
                or max(np.abs(row_step).max(), np.abs(column_step).max()) > STENCIL_REACH:
            return None
        slot_offsets, slot = stencil_slots(row_step, column_step)
        if len(np.unique(owner.astype(np.int64) * len(slot_offsets) + slot)) != len(owner):
            return None
        return slot_offsets, column_runs(slot_offsets), slot

    def packed_table(self, owner: np.ndarray, slot: np.ndarray, values: np.ndarray,
                     slot_count: int) -> np.ndarray:
        """``values`` of entries (owner particle, slot) laid out as the SIMD pass reads them:
        (rows, group_count, slot_count, SIMD_LANES), 0 where a lane has no such entry (halo lanes
        too)."""
        table = np.zeros((self.rows, self.group_count * SIMD_LANES, slot_count))
        row, column = np.divmod(owner, self.columns)
        table[row, SIMD_LANES + column, slot] = values
        return np.ascontiguousarray(
            table.reshape(self.rows, self.group_count, SIMD_LANES, slot_count)
            .transpose(0, 1, 3, 2))

    def packed_fields(self, real, copies: int = PACKED_BUFFERS, rows: int | None = None) -> list:
        """Three fields (x, y, z) of SIMD_LANES-vectors indexed [copy, row, group], so a group
        loads as one vector; ``rows``: fewer rows than the grid's (a ring of rows)."""
        return [ti.Vector.field(SIMD_LANES, real, (copies, rows or self.rows, self.group_count))
                for _ in range(3)]

    def lane_fields(self, real) -> list:
        """Three fields (x, y, z) of SIMD_LANES-vectors indexed [row, group]: a value per lane."""
        return [ti.Vector.field(SIMD_LANES, real, (self.rows, self.group_count)) for _ in range(3)]

    def halo_sources(self, group: int) -> tuple:
        """Where each lane of packed group ``group`` of a periodic grid takes its value from:
        (the groups read, each lane's (index among them, lane)): a wrapped column's own lane,
        or the lane itself where it holds its own column."""
        sources = []
        for lane in range(SIMD_LANES):
            own = ((group - 1) * SIMD_LANES + lane) % self.columns
            sources.append((own // SIMD_LANES + 1, own % SIMD_LANES))
        groups = sorted({source_group for source_group, _ in sources})
        return groups, [(groups.index(source_group), lane) for source_group, lane in sources]


def column_runs(slot_offsets: list) -> list:
    """(column step, first slot, slot count) of each column step of ``slot_offsets``
    ((Δrow, Δcolumn), ordered by Δcolumn): slots sharing a column step are contiguous."""
    column_steps = [offset[1] for offset in slot_offsets]
    return [(step, column_steps.index(step), column_steps.count(step))
            for step in sorted(set(column_steps))]


def grid_steps(columns: int, periodic: bool, first: np.ndarray, second: np.ndarray):
    """(Δrow, Δcolumn) from grid particles ``first`` to ``second`` (columns wrapped to the
    nearest way round when ``periodic``)."""
    row, column = np.divmod(first, columns)
    other_row, other_column = np.divmod(second, columns)
    column_step = other_column - column
    if periodic:
        column_step = (column_step + columns // 2) % columns - columns // 2
    return other_row - row, column_step


def stencil_slots(row_step: np.ndarray, column_step: np.ndarray):
    """(slot offsets (Δrow, Δcolumn) ordered by Δcolumn, then Δrow; each step's slot)."""
    width = 2 * STENCIL_REACH + 1
    code = (column_step + STENCIL_REACH) * width + row_step + STENCIL_REACH
    codes, slot = np.unique(code, return_inverse=True)
    return [(int(c) % width - STENCIL_REACH, int(c) // width - STENCIL_REACH)
            for c in codes], slot.ravel()


def grid_stencil(garment, ends: np.ndarray, rest_length: np.ndarray,
                 stiffness: np.ndarray, damping: np.ndarray, real) -> GridStencil | None:
    """The garment's springs as a ``GridStencil``, or None when they are not one: every spring
    must join grid neighbours at most ``STENCIL_REACH`` apart, every in-grid slot must hold
    exactly one spring, and rest length, stiffness and damping may depend on the row only
    (relative spread ≤ 1e-9; the table keeps the row's first value)."""
    columns, rows = garment.columns, garment.rows
    if columns * rows != garment.particle_count or not len(ends) or columns < 2 * STENCIL_REACH + 1:
        return None
    row_step, column_step = grid_steps(columns, garment.periodic, ends[:, 0], ends[:, 1])
    if np.max(np.abs(row_step)) > STENCIL_REACH or np.max(np.abs(column_step)) > STENCIL_REACH:
        return None
    # Both ends see the spring: from i at offset (Δr, Δc), from j at (−Δr, −Δc).
    owner = np.concatenate([ends[:, 0], ends[:, 1]])
    slot_offsets, slot = stencil_slots(np.concatenate([row_step, -row_step]),
                                       np.concatenate([column_step, -column_step]))
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
