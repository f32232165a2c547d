"""Model (what never changes during a run) and State (what the integrators write).

As in warp/newton's ``Model``/``State`` split: the model holds inverse masses, springs, rest
lengths, stiffnesses and the gather lists; ``model.state()`` makes a fresh state (positions and
velocities) and the substep loop swaps two of them. Fields are allocated once, from NumPy.

Forces are gathered, never scattered: every particle owns the list of its springs
(``particle_spring_start``/``particle_spring``/``particle_neighbor``) and of its triangles, so a
force is a sum in a fixed order and a run is bit-reproducible on the CPU (no atomic float adds).

A cloth on a regular grid (every garment ``garment.py`` builds) also gets a ``GridStencil``: its
springs are the same few neighbour offsets at every particle, with rest lengths and stiffnesses
that depend only on the row, so the force pass reads positions as a stencil over a packed copy
(``forces.py``) instead of through the gather lists.

A pinned particle has inverse mass 0 and follows its prescribed motion: slot
``pin_slot[i]`` of ``pin_track`` (a ``KinematicTrack``), held at its rest position for a static
pin and carried by the pelvis for a worn skirt.
"""

import numpy as np
import taichi as ti

from taichi_cloth.cloth.garment import Garment
from taichi_cloth.physics.control import KinematicTrack

FAMILY_ORDER = ("stretch", "shear", "bend")


def real_type(precision: str):
    """Taichi float type for the scene's ``simulation.precision``."""
    return ti.f64 if precision == "f64" else ti.f32


def gather_lists(pairs: np.ndarray, particle_count: int):
    """CSR lists of what each particle touches: (start (N+1,), item (K,), other (K,)).

    For springs: item = spring index, other = the particle at its other end. Entries of one
    particle keep the order of ``pairs`` (a stable sort), so sums over them are reproducible.
    """
    owner = np.concatenate([pairs[:, 0], pairs[:, 1]])
    item = np.concatenate([np.arange(len(pairs))] * 2)
    other = np.concatenate([pairs[:, 1], pairs[:, 0]])
    order = np.argsort(owner, kind="stable")
    start = np.searchsorted(owner[order], np.arange(particle_count + 1)).astype(np.int32)
    return start, item[order].astype(np.int32), other[order].astype(np.int32)


def triangle_gather_lists(triangles: np.ndarray, particle_count: int):
    """CSR lists of the triangles around each particle: (start (N+1,), triangle (K,))."""
    owner = triangles.ravel()
    triangle = np.repeat(np.arange(len(triangles)), 3)
    order = np.argsort(owner, kind="stable")
    start = np.searchsorted(owner[order], np.arange(particle_count + 1)).astype(np.int32)
    return start, triangle[order].astype(np.int32)


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
    (``EulerStep``: the packed state is carried from substep to substep, never re-packed).
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

    def upload(self) -> None:
        """Copy the tables into the fields (after the model has allocated all of its own)."""
        self.slot_row_step.from_numpy(np.array([step for step, _ in self.slot_offsets], np.int32))
        numpy_real = np.float64 if self.rest_length.dtype == ti.f64 else np.float32
        for table, values in zip((self.rest_length, self.stiffness, self.damping), self._tables):
            table.from_numpy(np.ascontiguousarray(values, dtype=numpy_real))

    def packed_fields(self, real) -> list:
        """Three fields (x, y, z) of SIMD_LANES-vectors indexed [buffer, row, group], so a group
        loads as one vector."""
        return [ti.Vector.field(SIMD_LANES, real, (PACKED_BUFFERS, self.rows, self.group_count))
                for _ in range(3)]


def grid_stencil(garment: Garment, ends: np.ndarray, rest_length: np.ndarray,
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


@ti.data_oriented
class State:
    """Positions x [m] and velocities v [m/s], shape [particle_count]."""

    def __init__(self, particle_count: int, real):
        self.x = ti.Vector.field(3, real, particle_count)
        self.v = ti.Vector.field(3, real, particle_count)

    def copy_from(self, other: "State") -> None:
        self.x.copy_from(other.x)
        self.v.copy_from(other.v)


@ti.data_oriented
class Model:
    """Static cloth data in Taichi fields.

    particle_mass [kg] and particle_inv_mass [1/kg] (0 for pinned), shape [particle_count];
    spring_ends (i, j), spring_rest_length [m], spring_stiffness [N/m], spring_damping [N·s/m],
    shape [spring_count], ordered stretch, shear, bend (the first ``stretch_count`` are stretch);
    triangles, shape [triangle_count]; pin_slot, shape [particle_count]: the pinned particle's
    point in ``pin_track`` (−1 for a free particle).
    """

    def __init__(self, garment: Garment, precision: str = "f32", damping_scale: float | None = None,
                 pin_samples: int = 2):
        """damping_scale: None compiles no dashpots; else c = scale · β · k per spring.
        pin_samples: sample times per frame of the pins' prescribed motion (2 when static)."""
        self.real = real_type(precision)
        self.numpy_real = np.float64 if precision == "f64" else np.float32
        self.garment = garment
        self.particle_count = garment.particle_count
        self.has_dashpots = damping_scale is not None
        families = [f for f in FAMILY_ORDER if f in garment.springs]
        ends = np.concatenate([garment.springs[f] for f in families]).astype(np.int32)
        stiffness = np.concatenate([garment.spring_stiffness[f] for f in families])
        self.family_counts = {f: len(garment.springs[f]) for f in families}
        self.stretch_count = self.family_counts.get("stretch", 0)
        self.spring_count = len(ends)
        self.triangle_count = len(garment.triangles)
        rest_length = np.linalg.norm(garment.positions[ends[:, 1]] - garment.positions[ends[:, 0]],
                                     axis=1)
        inv_mass = np.where(garment.pinned, 0.0, 1.0 / garment.mass)

        n, real = self.particle_count, self.real
        self.particle_mass = ti.field(real, n)
        self.particle_inv_mass = ti.field(real, n)
        self.spring_ends = ti.Vector.field(2, ti.i32, self.spring_count)
        self.spring_rest_length = ti.field(real, self.spring_count)
        self.spring_stiffness = ti.field(real, self.spring_count)
        self.spring_damping = ti.field(real, self.spring_count)
        spring_start, spring_item, spring_other = gather_lists(ends, n)
        self.particle_spring_start = ti.field(ti.i32, n + 1)
        self.particle_spring = ti.field(ti.i32, len(spring_item))
        self.particle_neighbor = ti.field(ti.i32, len(spring_item))
        self.triangles = ti.Vector.field(3, ti.i32, self.triangle_count)
        triangle_start, triangle_item = triangle_gather_lists(garment.triangles, n)
        self.particle_triangle_start = ti.field(ti.i32, n + 1)
        self.particle_triangle = ti.field(ti.i32, len(triangle_item))
        self.pinned_particles = np.flatnonzero(garment.pinned)
        self.pin_slot = ti.field(ti.i32, n)
        self.pin_track = KinematicTrack(max(1, len(self.pinned_particles)), pin_samples, real)
        damping = (damping_scale or 0.0) * garment.damping_time * stiffness
        self.grid = grid_stencil(garment, ends, rest_length, stiffness, damping, real)
        # Every field is allocated before the first copy: a copy is a kernel launch, which
        # closes Taichi's current SNode tree, and a process may hold only ~500 trees.

        self.particle_mass.from_numpy(self._real(garment.mass))
        self.particle_inv_mass.from_numpy(self._real(inv_mass))
        self.spring_ends.from_numpy(ends)
        self.spring_rest_length.from_numpy(self._real(rest_length))
        self.spring_stiffness.from_numpy(self._real(stiffness))
        self.spring_damping.from_numpy(self._real(damping))
        self.particle_spring_start.from_numpy(spring_start)
        self.particle_spring.from_numpy(spring_item)
        self.particle_neighbor.from_numpy(spring_other)
        self.triangles.from_numpy(garment.triangles)
        self.particle_triangle_start.from_numpy(triangle_start)
        self.particle_triangle.from_numpy(triangle_item)
        if self.grid is not None:
            self.grid.upload()
        slot = np.full(n, -1, dtype=np.int32)
        slot[self.pinned_particles] = np.arange(len(self.pinned_particles), dtype=np.int32)
        self.pin_slot.from_numpy(slot)
        if len(self.pinned_particles):
            self.pin_track.hold(garment.positions[self.pinned_particles])

        # NumPy copies for per-frame metrics and exports (never touched in the substep loop).
        self.host_spring_ends = ends
        self.host_rest_length = rest_length
        self.host_stiffness = stiffness
        self.host_mass = garment.mass
        self.host_inv_mass = inv_mass

    def _real(self, array) -> np.ndarray:
        """``array`` in the model's float precision, for ``from_numpy``."""
        return np.ascontiguousarray(array, dtype=self.numpy_real)

    def state(self) -> State:
        """A fresh state at the rest positions, at rest."""
        return self.states(1)[0]

    def states(self, count: int) -> list[State]:
        """``count`` fresh states, allocated together (one SNode tree) before they are filled."""
        states = [State(self.particle_count, self.real) for _ in range(count)]
        for state in states:
            state.x.from_numpy(self._real(self.garment.positions))
            state.v.fill(0.0)
        return states

    @ti.func
    def pin_target(self, i_p, t):
        """Position [m] and velocity [m/s] of pinned particle i_p at time t [s]."""
        return self.pin_track.at(self.pin_slot[i_p], t)
