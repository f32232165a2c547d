"""Model (what never changes during a run) and State (what the integrators write).

As in warp/newton's ``Model``/``State`` split: the model holds inverse masses, springs, rest
lengths, stiffnesses and the gather lists; ``model.state()`` makes a fresh state (positions and
velocities) and the substep loop swaps two of them. Fields are allocated once, from NumPy:
the model's ``uploads`` gathers its own copies and those of whatever is built on it (control,
effects, packed grid, integrator), and ``states`` sends them with the states' own, in one
kernel launch once every field is allocated (``uploads.UploadBatch``; a launch closes Taichi's
current SNode tree, and a process may hold only ~500 trees).

Forces are gathered, never scattered: every particle owns the list of its springs
(``particle_spring_start``/``particle_spring``/``particle_neighbor``) and of its triangles, so a
force is a sum in a fixed order and a run is bit-reproducible on the CPU (no atomic float adds).

A cloth on a regular grid whose springs depend on the row only (sheets and skirts; not a disc
specimen, whose anisotropic springs change around each ring) also gets a ``GridStencil``
(``physics.grid_stencil``): its springs as a stencil, for the SIMD spring pass
(``physics.packed_grid``).

A pinned particle has inverse mass 0; where it is comes from the prescribed motion
(``physics.control.Control``), which is not part of the model: the model never changes in a run.
"""

import numpy as np
import taichi as ti

from taichi_cloth.cloth.garment import Garment
from taichi_cloth.gather import gather_lists, triangle_gather_lists
from taichi_cloth.physics.grid_stencil import grid_stencil
from taichi_cloth.uploads import UploadBatch

FAMILY_ORDER = ("stretch", "shear", "bend")


def real_type(precision: str):
    """Taichi float type for the scene's ``simulation.precision``."""
    return ti.f64 if precision == "f64" else ti.f32


@ti.data_oriented
class State:
    """Positions x [m] and velocities v [m/s], shape [particle_count]."""

    def __init__(self, particle_count: int, real):
        self.x = ti.Vector.field(3, real, particle_count)
        self.v = ti.Vector.field(3, real, particle_count)

    def copy_from(self, other: "State") -> None:
        self.x.copy_from(other.x)
        self.v.copy_from(other.v)


HOST_VECTORS = ti.types.ndarray(dtype=ti.types.vector(3, ti.f64), ndim=1)  # (N, 3) float64


@ti.data_oriented
class StateSet:
    """States allocated together (``members``; a simulation's: the two its integrator swaps
    and the backup of a redone frame), read to the host, written from it and copied one into
    another by one kernel each, whichever member it is given. Taichi compiles its own kernel
    for each field that ``to_numpy``, ``from_numpy`` or ``copy_from`` is given (~0.1 s each on
    the 2-core machine): per field of each state, that was ~14 compiles a simulation, and such
    kernels were 1,361 of the test suite's 2,363 compiles (docs/performance.md, "Fewer kernels
    to compile")."""

    def __init__(self, members: list[State]):
        self.members = tuple(members)
        self.particle_count = members[0].x.shape[0]

    def _slot(self, state: State) -> int:
        for slot, member in enumerate(self.members):
            if member is state:
                return slot
        raise ValueError("StateSet: a state that is not one of its members")

    def read(self, state: State) -> tuple[np.ndarray, np.ndarray]:
        """Host copies of ``state``'s positions [m] and velocities [m/s], (N, 3) float64."""
        x, v = np.empty((self.particle_count, 3)), np.empty((self.particle_count, 3))
        self._read(self._slot(state), x, v)
        return x, v

    def write(self, state: State, x: np.ndarray, v: np.ndarray) -> None:
        """Set ``state`` to positions x [m] and velocities v [m/s] (N, 3), rounded to the
        fields' type to nearest (as NumPy's ``astype`` rounds)."""
        expected = (self.particle_count, 3)
        if np.shape(x) != expected or np.shape(v) != expected:
            raise ValueError(f"StateSet.write: arrays of shapes {np.shape(x)} and {np.shape(v)} "
                             f"for states of {expected}")
        self._write(self._slot(state), np.ascontiguousarray(x, dtype=np.float64),
                    np.ascontiguousarray(v, dtype=np.float64))

    def copy(self, target: State, source: State) -> None:
        """``target`` = ``source`` (two members)."""
        self._copy(self._slot(target), self._slot(source))

    @ti.kernel
    def _read(self, slot: ti.i32, x: HOST_VECTORS, v: HOST_VECTORS):
        for i in range(self.particle_count):
            for k in ti.static(range(len(self.members))):
                if slot == k:
                    x[i] = ti.cast(self.members[k].x[i], ti.f64)
                    v[i] = ti.cast(self.members[k].v[i], ti.f64)

    @ti.kernel
    def _write(self, slot: ti.i32, x: HOST_VECTORS, v: HOST_VECTORS):
        for i in range(self.particle_count):
            for k in ti.static(range(len(self.members))):
                if slot == k:
                    self.members[k].x[i] = ti.cast(x[i], self.members[k].x.dtype)
                    self.members[k].v[i] = ti.cast(v[i], self.members[k].v.dtype)

    @ti.kernel
    def _copy(self, target: ti.i32, source: ti.i32):
        for i in range(self.particle_count):
            for k, j in ti.static(ti.ndrange(len(self.members), len(self.members))):
                if ti.static(k != j):
                    if target == k and source == j:
                        self.members[k].x[i] = self.members[j].x[i]
                        self.members[k].v[i] = self.members[j].v[i]


@ti.data_oriented
class Model:
    """Static cloth data in Taichi fields.

    particle_mass [kg] and particle_inv_mass [1/kg] (0 for pinned), shape [particle_count];
    spring_ends (i, j), spring_rest_length [m], spring_stiffness [N/m], spring_damping [N·s/m],
    shape [spring_count], ordered stretch, shear, bend (the first ``stretch_count`` are stretch);
    triangles, shape [triangle_count]; dashpot_time: β·scale [s] of the dashpots (None without).
    """

    def __init__(self, garment: Garment, precision: str = "f32", damping_scale: float | None = None):
        """damping_scale: None compiles no dashpots; else c = scale · β · k per spring (the
        ``damping`` effect's ``model_options``)."""
        self.real = real_type(precision)
        self.numpy_real = np.float64 if precision == "f64" else np.float32
        self.garment = garment
        self.particle_count = garment.particle_count
        self.has_dashpots = damping_scale is not None
        self.dashpot_time = garment.damping_time * damping_scale if self.has_dashpots else None
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
        damping = (damping_scale or 0.0) * garment.damping_time * stiffness
        self.grid = grid_stencil(garment, ends, rest_length, stiffness, damping, real)
        self.uploads = UploadBatch()  # sent by ``states`` (module docstring)
        self.uploads.add([
            (self.particle_mass, self._real(garment.mass)),
            (self.particle_inv_mass, self._real(inv_mass)), (self.spring_ends, ends),
            (self.spring_rest_length, self._real(rest_length)),
            (self.spring_stiffness, self._real(stiffness)),
            (self.spring_damping, self._real(damping)),
            (self.particle_spring_start, spring_start), (self.particle_spring, spring_item),
            (self.particle_neighbor, spring_other), (self.triangles, garment.triangles),
            (self.particle_triangle_start, triangle_start),
            (self.particle_triangle, triangle_item)])
        if self.grid is not None:
            self.uploads.add(self.grid.field_values())

        # NumPy copies for per-frame metrics and exports (never touched in the substep loop).
        self.host_spring_ends = ends
        self.host_spring_start, self.host_neighbor = spring_start, spring_other
        self.host_rest_length = rest_length
        self.host_stiffness = stiffness
        self.host_mass = garment.mass
        self.host_inv_mass = inv_mass

    def _real(self, array) -> np.ndarray:
        """``array`` in the model's float precision, for ``from_numpy``."""
        return np.ascontiguousarray(array, dtype=self.numpy_real)

    def state(self) -> State:
        """A fresh state at the start positions, at rest."""
        return self.states(1).members[0]

    def states(self, count: int) -> StateSet:
        """``count`` fresh states, allocated together, then filled with every copy ``uploads``
        holds (module docstring)."""
        states = [State(self.particle_count, self.real) for _ in range(count)]
        start, rest = self._real(self.garment.start_positions), np.zeros((self.particle_count, 3))
        self.uploads.add([pair for state in states for pair in ((state.x, start), (state.v, rest))])
        self.uploads.send()
        return StateSet(states)
