"""The one force evaluation every integrator calls (DESIGN.md; warp's ``compute_forces``).

``Forces.particle_force`` is a ``@ti.func`` that gathers the total force on one particle:
springs (seed §2.1: stretch, shear, bend), their dashpots (seed §2.3 f_damper), and the scene's
declared effects unrolled with ``ti.static`` (gravity, drag, wind, contact). Integrators call it
from inside their own kernels, at whatever state (stage) they need, so RK4 stages and the implicit
solve see exactly the same forces. Before it, in the same kernel, ``prepare`` runs the passes
that serve every particle at once: the effects' per-time data (capsule poses) and, on a grid
cloth, the spring pass.

The grid spring pass (``model.GridStencil``) packs positions (and velocities, for dashpots) into
groups of ``SIMD_LANES`` columns and evaluates every stencil slot for a whole group with vector
arithmetic: the same formula, each particle still summing its own springs in slot order (a
gather, no atomics), but LLVM turns the lanes into AVX-512 instructions. Other spring sets gather
through the CSR lists one particle at a time.

Spring i–j with rest length L, stiffness k, damping c, d = x_j − x_i, l = |d|, n = d / l:
    f_i = k (l − L) n + c ((v_j − v_i) · n) n,      f_j = −f_i.
This is −∂E/∂x_i of E = ½ k (l − L)² plus a dashpot along the spring; internal forces sum to zero.

Jacobians for the implicit integrator (Baraff & Witkin 1998, §5), as products with a vector u,
gathered per particle like the forces. A spring's stiffness block is
    K_s = ∂f_i/∂x_j = k·[n·nᵀ + (1 − L/l)·(I − n·nᵀ)],   (K·u)_i = Σ_s K_s·(u_j − u_i),
and its dashpot's D_s = ∂f_i/∂v_j = c·n·nᵀ (its ∂/∂x, proportional to the relative velocity, is
left out). For a compressed spring (l < L) the geometric term (1 − L/l) is negative and can make
the system indefinite; ``definite=True`` clamps it at 0 (the usual fix, Choi & Ko 2002), which the
solver uses; ``definite=False`` is the exact derivative (for finite-difference tests). Effects
with ``has_local_jacobian`` add a per-particle block (contact).
"""

import numpy as np
import taichi as ti

from taichi_cloth.effects.contact import GroundContact
from taichi_cloth.effects.aerodynamics import Drag, Gravity, Wind
from taichi_cloth.physics.model import SIMD_LANES, STENCIL_REACH, Model
from taichi_cloth.config.scene import EFFECT_TYPES

PACKED_PARTICLE_MINIMUM = 1024  # below it the CSR gather is as fast and compiles in a blink

EFFECT_CLASSES = {"gravity": Gravity, "drag": Drag, "wind": Wind, "ground": GroundContact}


def make_effects(declared: dict, extra: dict | None = None) -> list:
    """Effect objects for the scene's declared effects, in declaration order.

    ``declared`` maps effect names to their settings (``Scene.effects``); ``damping`` is compiled
    into the springs, not here. ``extra`` maps further names to ready-made effect objects (contact
    effects that need the body)."""
    effects = []
    for name, config in declared.items():
        if name in EFFECT_CLASSES:
            effects.append(EFFECT_CLASSES[name](config))
        elif extra and name in extra:
            effects.append(extra[name])
    return effects


@ti.func
def packed_lanes(packed_component: ti.template(), buffer, row, group,
                 column_step: ti.template()):
    """The SIMD_LANES values of packed columns group·SIMD_LANES + lane + column_step."""
    groups = (packed_component[buffer, row, group - 1], packed_component[buffer, row, group],
              packed_component[buffer, row, group + 1])
    return ti.Vector([groups[(lane + column_step + SIMD_LANES) // SIMD_LANES]
                      [(lane + column_step) % SIMD_LANES]
                      for lane in ti.static(range(SIMD_LANES))])


def group_pass_function(model: Model, packed_x: list, packed_v: list, finish):
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
class Forces:
    """Springs, dashpots (when the model has them) and the listed effects."""

    def __init__(self, model: Model, effects: list, packed_springs: bool = False):
        """packed_springs: use the SIMD grid pass when the model is a grid of at least
        ``PACKED_PARTICLE_MINIMUM`` particles (its compile takes seconds, more for every stage
        that calls it, so the integrators with one evaluation per step ask for it)."""
        self.model = model
        self.effects = effects
        self.has_grid = packed_springs and model.grid is not None \
            and model.particle_count >= PACKED_PARTICLE_MINIMUM
        if self.has_grid:
            self.packed_x = model.grid.packed_fields(model.real)
            self.packed_v = model.grid.packed_fields(model.real)
            # [row, column] up to the last filled group's last lane (the pass stores whole groups)
            self.grid_spring_force = ti.Vector.field(
                3, model.real, (model.grid.rows, SIMD_LANES * model.grid.group_count))
            columns = model.grid.columns
            # (first, last + 1) of the packed groups that hold grid columns
            self.filled_groups = (1, (2 * SIMD_LANES + columns - 1) // SIMD_LANES)
            # groups with a wrapped column in a lane (periodic grid): the first, and from the
            # first with a lane past the last column
            self.last_own_group = columns // SIMD_LANES  # groups 1 … this hold own columns only
            self.wrapping_groups = [0] + list(range(self.last_own_group + 1,
                                                    model.grid.group_count))
            self.wrapping_group = ti.field(ti.i32, len(self.wrapping_groups))
            # per packed group: the lanes' inverse masses [1/kg] (0 for pinned and halo lanes),
            # and whether a lane is pinned
            self.packed_inv_mass = ti.Vector.field(SIMD_LANES, model.real,
                                                   (model.grid.rows, model.grid.group_count))
            self.group_has_pin = ti.field(ti.i32, (model.grid.rows, model.grid.group_count))
            self.group_springs = group_pass_function(model, self.packed_x, self.packed_v,
                                                     self._store_spring_force)
            self._upload_grid_constants()  # after every allocation: one SNode tree (model.py)

    @property
    def compiled_names(self) -> list[str]:
        """What is compiled into the force evaluation, for ``stats.json``."""
        names = [e.name for e in self.effects] + (["damping"] if self.model.has_dashpots else [])
        return sorted(names, key=list(EFFECT_TYPES).index)

    @ti.func
    def prepare_effects(self, t):
        """The effects' passes at time t [s] (capsule poses), before any particle loop."""
        for e in ti.static(range(len(self.effects))):
            if ti.static(hasattr(self.effects[e], "prepare")):
                self.effects[e].prepare(t)

    @ti.func
    def prepare(self, x, v, t):
        """Everything ``particle_force`` reads at (x, v, t) that serves all particles:
        ``prepare_effects``, then on a grid cloth the packed spring pass."""
        self.prepare_effects(t)
        self.prepare_springs(x, v)

    @ti.func
    def prepare_springs(self, x, v):
        """On a grid cloth, every particle's spring force into ``grid_spring_force``: pack
        (x, v) into packed copy 0, then the SIMD stencil pass. Nothing otherwise
        (``particle_force`` gathers)."""
        if ti.static(self.has_grid):
            self.pack(x, v, 0, self.model.has_dashpots)
            grid = self.model.grid
            for row, group in ti.ndrange(grid.rows, ti.static(self.filled_groups)):
                self.group_springs(0, row, group, 0.0)

    @ti.func
    def _store_spring_force(self, buffer, row, group, h, f_x, f_y, f_z):
        """A group's spring forces into ``grid_spring_force`` [N], lane by lane (halo lanes
        too: no branch, which a function inlined into a real function must not have in
        Taichi 1.7.4, it crashes the compiler)."""
        for lane in ti.static(range(SIMD_LANES)):
            self.grid_spring_force[row, (group - 1) * SIMD_LANES + lane] = ti.Vector(
                [f_x[lane], f_y[lane], f_z[lane]])

    def _upload_grid_constants(self) -> None:
        grid = self.model.grid
        self.wrapping_group.from_numpy(np.array(self.wrapping_groups, np.int32))
        inv_mass = self.model.host_inv_mass.reshape(grid.rows, grid.columns)
        lanes = np.zeros((grid.rows, grid.group_count * SIMD_LANES), self.model.numpy_real)
        lanes[:, SIMD_LANES:SIMD_LANES + grid.columns] = inv_mass
        self.packed_inv_mass.from_numpy(lanes.reshape(grid.rows, grid.group_count, SIMD_LANES))
        pinned = np.zeros(lanes.shape, dtype=bool)
        pinned[:, SIMD_LANES:SIMD_LANES + grid.columns] = inv_mass == 0
        self.group_has_pin.from_numpy(
            pinned.reshape(grid.rows, grid.group_count, SIMD_LANES).any(axis=2).astype(np.int32))

    @property
    def uniform_effects_only(self) -> bool:
        """Every effect is a uniform acceleration (gravity): a step can add them per lane."""
        return all(hasattr(e, "uniform_acceleration") for e in self.effects)

    @property
    def uniform_acceleration(self) -> tuple:
        """Σ of the effects' uniform accelerations [m/s²] (x, y, z)."""
        return tuple(sum(e.uniform_acceleration[c] for e in self.effects
                         if hasattr(e, "uniform_acceleration")) for c in range(3))

    @ti.func
    def pack(self, x, v, buffer, with_velocity: ti.template()):
        """x (and v, ``with_velocity``) into packed copy ``buffer`` (model.GridStencil)."""
        for row, group in ti.ndrange(self.model.grid.rows, self.model.grid.group_count):
            self.pack_group(x, v, buffer, row, group, with_velocity)

    @ti.func
    def pack_halo(self, x, v, buffer, with_velocity: ti.template()):
        """The groups of packed copy ``buffer`` that hold wrapped columns (periodic grid)."""
        for row, k in ti.ndrange(self.model.grid.rows, ti.static(len(self.wrapping_groups))):
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
        grid = self.model.grid
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
        grid = self.model.grid
        column = group * SIMD_LANES + lane - SIMD_LANES
        if ti.static(grid.periodic):
            column = (column + grid.columns) % grid.columns
        else:
            column = ti.min(ti.max(column, 0), grid.columns - 1)
        return column

    @ti.func
    def store_lane(self, buffer, i_p, x_value, v_value):
        """Particle i_p's (x, v) into its own lane of packed copy ``buffer``."""
        grid = self.model.grid
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
        grid = self.model.grid
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
        grid = self.model.grid
        for i_p in range(self.model.particle_count):
            state.x[i_p], state.v[i_p] = self.load_lane(buffer, i_p // grid.columns,
                                                        i_p % grid.columns)

    @ti.func
    def spring_force(self, x, v, i_p):
        """Σ over the springs of particle i_p of k (l − L) n (+ the dashpot term) [N]."""
        model = self.model
        f = ti.Vector.zero(model.real, 3)
        x_i = x[i_p]
        for k in range(model.particle_spring_start[i_p], model.particle_spring_start[i_p + 1]):
            i_s = model.particle_spring[k]
            j_p = model.particle_neighbor[k]
            d = x[j_p] - x_i
            length = d.norm()
            if length > 0:
                n = d / length
                magnitude = model.spring_stiffness[i_s] * (length - model.spring_rest_length[i_s])
                if ti.static(model.has_dashpots):
                    magnitude += model.spring_damping[i_s] * (v[j_p] - v[i_p]).dot(n)
                f += magnitude * n
        return f

    @ti.func
    def spring_axis(self, x, i_p, k, definite: ti.template()):
        """(j, n, k_axial, k_isotropic, c) of the k-th gather entry of particle i_p (spring to j,
        unit direction n) with K_s = k_axial·n·nᵀ + k_isotropic·I and D_s = c·n·nᵀ, i.e.
        k_axial = k·(1 − g), k_isotropic = k·g, g = 1 − L/l (clamped at 0 when ``definite``).
        A zero-length spring has n = 0 and adds nothing."""
        model = self.model
        i_s = model.particle_spring[k]
        j_p = model.particle_neighbor[k]
        d = x[j_p] - x[i_p]
        length = d.norm()
        n = ti.Vector.zero(model.real, 3)
        axial, isotropic, damping = model.real(0.0), model.real(0.0), model.real(0.0)
        if length > 0:
            n = d / length
            geometric = 1 - model.spring_rest_length[i_s] / length
            if ti.static(definite):
                geometric = ti.max(geometric, 0.0)
            axial = model.spring_stiffness[i_s] * (1 - geometric)
            isotropic = model.spring_stiffness[i_s] * geometric
            if ti.static(model.has_dashpots):
                damping = model.spring_damping[i_s]
        return j_p, n, axial, isotropic, damping

    @ti.func
    def spring_blocks(self, x, i_p, k, definite: ti.template()):
        """(neighbour j, K_s, D_s) of the k-th gather entry of particle i_p (``spring_axis``)."""
        j_p, n, axial, isotropic, damping = self.spring_axis(x, i_p, k, definite)
        outer = n.outer_product(n)
        return (j_p, axial * outer + isotropic * ti.Matrix.identity(self.model.real, 3),
                damping * outer)

    @ti.func
    def jacobian_products(self, x, v, u, i_p, t, definite: ti.template()):
        """((∂f/∂x)·u, (∂f/∂v)·u) at particle i_p [N/m·u, N·s/m·u]."""
        model = self.model
        stiffness_product = ti.Vector.zero(model.real, 3)
        damping_product = ti.Vector.zero(model.real, 3)
        for k in range(model.particle_spring_start[i_p], model.particle_spring_start[i_p + 1]):
            j_p, stiffness_block, damping_block = self.spring_blocks(x, i_p, k, definite)
            relative = u[j_p] - u[i_p]
            stiffness_product += stiffness_block @ relative
            damping_product += damping_block @ relative
        for e in ti.static(range(len(self.effects))):
            if ti.static(getattr(self.effects[e], "has_local_jacobian", False)):
                stiffness_block, damping_block = self.effects[e].local_jacobian(
                    model, x, v, i_p, t, definite)
                stiffness_product += stiffness_block @ u[i_p]
                damping_product += damping_block @ u[i_p]
        return stiffness_product, damping_product

    @ti.kernel
    def evaluate_jacobian_products(self, x: ti.template(), v: ti.template(), u: ti.template(),
                                   t: ti.f64, definite: ti.template(),
                                   stiffness_out: ti.template(), damping_out: ti.template()):
        """(∂f/∂x)·u and (∂f/∂v)·u for every particle (for tests and diagnostics)."""
        self.prepare_effects(t)
        for i_p in x:
            stiffness_out[i_p], damping_out[i_p] = self.jacobian_products(
                x, v, u, i_p, ti.cast(t, self.model.real), definite)

    @ti.func
    def particle_force(self, x, v, i_p, t):
        """Total force on particle i_p [N] at positions x, velocities v, time t [s], after
        ``prepare`` at the same (x, v, t) in the same kernel."""
        f = ti.Vector.zero(self.model.real, 3)
        if ti.static(self.has_grid):
            f = self.grid_spring_force[i_p // self.model.grid.columns,
                                       i_p % self.model.grid.columns]
        else:
            f = self.spring_force(x, v, i_p)
        for k in ti.static(range(len(self.effects))):
            f += self.effects[k].force(self.model, x, v, i_p, t)
        return f

    @ti.kernel
    def evaluate(self, x: ti.template(), v: ti.template(), t: ti.f64, out: ti.template()):
        """Every particle's total force into ``out`` [N] (for tests and diagnostics)."""
        self.prepare(x, v, t)
        for i_p in x:
            out[i_p] = self.particle_force(x, v, i_p, ti.cast(t, self.model.real))


def spring_energy(model: Model, positions: np.ndarray) -> float:
    """Elastic energy Σ ½ k (l − L)² [J] (NumPy, per frame)."""
    ends = model.host_spring_ends
    length = np.linalg.norm(positions[ends[:, 1]] - positions[ends[:, 0]], axis=1)
    return float(0.5 * np.sum(model.host_stiffness * (length - model.host_rest_length) ** 2))


def stretch_strain(model: Model, positions: np.ndarray) -> np.ndarray:
    """(l − L) / L of every stretch spring."""
    ends = model.host_spring_ends[:model.stretch_count]
    rest = model.host_rest_length[:model.stretch_count]
    length = np.linalg.norm(positions[ends[:, 1]] - positions[ends[:, 0]], axis=1)
    return (length - rest) / rest
