"""Curvature bending: the isometric quadratic bending model of Bergou, Wardetzky, Harmon, Zorin &
Grinspun, "A Quadratic Bending Model for Inextensible Surfaces" (SGP 2006), from the fabric's
measured bending rigidity B [N·m].

Every interior edge e of the mesh is a hinge stencil (x0, x1; x2, x3): the edge and the two
vertices opposite it (``Garment.hinges``, from ``cloth.topology.hinge_stencils``). With the edge vectors of the rest shape
e0 = x1 − x0, e1 = x2 − x0, e2 = x3 − x0, e3 = x2 − x1, e4 = x3 − x1, the cotangents c01 = cot∠(e0,
e1), c02 = cot∠(e0, e2), c03 = cot∠(−e0, e3), c04 = cot∠(−e0, e4), and the areas A0, A1 of the
two triangles, the stencil's weights are

    w = (c03 + c04, c01 + c02, −c01 − c03, −c02 − c04) / √(A0 + A1)        [1/m],

and the bending energy is E = ½ Σ_e B_e ‖Σ_a w_a x_a‖² [J]. Σ_a w_a x_a is the cotangent
discretisation of the Laplacian Δx = (κ1 + κ2)·n integrated over the stencil's third of the
two triangles (Bergou et al. §4): on a sheet bent isometrically to curvature κ the sum converges
to ½·B·κ²·area as the mesh is refined (docs/physics.md, "Bending"; our 1/√(A0 + A1) puts their
factor 3 into the measured B). The weights sum to zero and vanish on a plane, so a flat or
rigidly moved mesh stores nothing, and the weights depend only on the rest shape's intrinsic
geometry, so a developable garment (a cone skirt cut from flat fabric) is measured from its flat
pattern. E is quadratic in x: its force and Hessian are exact and constant,

    f_a = −w_a·[B_e·(w·x) + c_e·(w·v)],      ∂f_a/∂x_b = −B_e·w_a·w_b·I,     ∂f_a/∂v_b = −c_e·w_a·w_b·I,

with the Rayleigh dashpot c_e = β·B_e of the springs when the scene declares ``damping``
(β: the model's ``dashpot_time``). H = Σ_e B_e·w_e·w_eᵀ is assembled once, on the host, into
CSR rows (``hessian_rows``: each particle's 2-ring, about 18 entries on a regular grid), and
force, products and diagonal gather over a particle's own row in a fixed order: one read per
neighbour instead of four per stencil around it (12 stencils on a regular grid).

Warp and weft: each hinge takes the garment's ``hinge_rigidity``, B_e = B_weft·cos²ψ +
B_warp·sin²ψ for a rest edge at angle ψ to the warp (``cloth.garment.hinge_rigidity``, beside
the stretch springs' own anisotropy).
"""

from dataclasses import dataclass

import numpy as np
import taichi as ti

from taichi_cloth.effects.base import Effect, EffectContext
from taichi_cloth.gather import scatter_sum
from taichi_cloth.settings import setting


@dataclass(frozen=True)
class BendingSettings:
    scale: float = setting(1.0, "float", low=0.0,
                           doc="multiplies the fabric's bending rigidity B (warp and weft)")


def cotangent(u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """cot of the angle between rows of u and v: (u·v)/|u × v|."""
    return np.einsum("hk,hk->h", u, v) / np.linalg.norm(np.cross(u, v), axis=1)


def hinge_weights(positions: np.ndarray, stencils: np.ndarray) -> np.ndarray:
    """The stencils' weights w (H, 4) [1/m] in the rest shape ``positions`` (module docstring)."""
    x0, x1, x2, x3 = (positions[stencils[:, k]] for k in range(4))
    e0, e1, e2, e3, e4 = x1 - x0, x2 - x0, x3 - x0, x2 - x1, x3 - x1
    c01, c02 = cotangent(e0, e1), cotangent(e0, e2)
    c03, c04 = cotangent(-e0, e3), cotangent(-e0, e4)
    areas = 0.5 * (np.linalg.norm(np.cross(e0, e1), axis=1)
                   + np.linalg.norm(np.cross(e0, e2), axis=1))
    weights = np.stack([c03 + c04, c01 + c02, -c01 - c03, -c02 - c04], axis=1)
    return weights / np.sqrt(areas)[:, None]


def hessian_rows(stencils: np.ndarray, weights: np.ndarray, rigidity: np.ndarray,
                 particle_count: int):
    """The constant bending Hessian H = Σ_e B_e·w_e·w_eᵀ (times I₃) [N/m] as CSR rows: (start
    (N+1,), neighbour (K,), coefficient H_ij (K,)) of each row's off-diagonal entries, neighbours
    ascending, and the diagonal H_ii (N,). Summed in float64 in a fixed order."""
    rows = np.repeat(stencils, 4, axis=1).ravel()
    columns = np.tile(stencils, (1, 4)).ravel()
    values = (rigidity[:, None, None] * weights[:, :, None] * weights[:, None, :]).ravel()
    keys, inverse = np.unique(rows.astype(np.int64) * particle_count + columns,
                              return_inverse=True)
    summed = np.bincount(inverse.ravel(), values, minlength=len(keys))
    row, column = keys // particle_count, keys % particle_count
    on_diagonal = row == column
    diagonal = np.zeros(particle_count)
    diagonal[row[on_diagonal]] = summed[on_diagonal]
    off = ~on_diagonal
    start = np.searchsorted(row[off], np.arange(particle_count + 1)).astype(np.int32)
    return start, column[off].astype(np.int32), summed[off], diagonal


@ti.data_oriented
class Bending(Effect):
    """Curvature bending of the garment (module docstring)."""

    name = "bending"
    Settings = BendingSettings
    has_coupled_jacobian = True

    def __init__(self, settings: BendingSettings, context: EffectContext):
        super().__init__(settings, context)
        model = context.model
        garment = model.garment
        self.model = model
        stencils = garment.hinges
        self.host_stencils = stencils
        self.host_weights = hinge_weights(garment.positions, stencils)
        self.host_rigidity = settings.scale * garment.hinge_rigidity
        self.host_row_start, self.host_row_neighbor, self.host_row_coefficient, \
            self.host_diagonal = hessian_rows(stencils, self.host_weights, self.host_rigidity,
                                              model.particle_count)
        # the particle whose row each entry is in (the host products for dt = "auto")
        self.host_row_owner = np.repeat(np.arange(model.particle_count),
                                        np.diff(self.host_row_start))
        real = model.real
        entries = max(1, len(self.host_row_neighbor))
        self.row_start = ti.field(ti.i32, model.particle_count + 1)
        self.row_neighbor = ti.field(ti.i32, entries)
        self.row_coefficient = ti.field(real, entries)
        self.diagonal = ti.field(real, model.particle_count)
        self.dashpot_time = model.dashpot_time or 0.0  # β [s]: c_e = β·B_e

    def upload(self) -> None:
        """Its fields' copies, into the model's ``uploads``."""
        real = self.model.numpy_real
        rows = [(self.row_neighbor, self.host_row_neighbor),
                (self.row_coefficient, self.host_row_coefficient.astype(real))] \
            if len(self.host_row_neighbor) else []
        self.model.uploads.add([*rows, (self.row_start, self.host_row_start),
                                (self.diagonal, self.host_diagonal.astype(real))])

    def allocate_lanes(self, grid) -> bool:
        """H's rows as a linear stencil of the grid cloth ``grid`` (``GridStencil.lane_slots``):
        H_ij per lane and slot (``lane_coefficient``, 0 where a lane has no such neighbour),
        each slot's row step, and β for the dashpot term (f_i = −(H·x)_i − β·(H·v)_i); False
        when a row reaches beyond the stencil."""
        slots = grid.lane_slots(self.host_row_owner, self.host_row_neighbor)
        if slots is None:
            return False
        slot_offsets, self.lane_column_runs, slot = slots
        table = grid.packed_table(self.host_row_owner, slot, self.host_row_coefficient,
                                  len(slot_offsets))
        self.lane_damping = self.dashpot_time
        self.lane_row_step = ti.field(ti.i32, len(slot_offsets))
        self.lane_coefficient = ti.Vector.field(table.shape[-1], self.model.real,
                                                table.shape[:-1])
        self.model.uploads.add([
            (self.lane_row_step, np.array([step for step, _ in slot_offsets], np.int32)),
            (self.lane_coefficient, table.astype(self.model.numpy_real))])
        return True

    @ti.func
    def _row_product(self, u, i_p):
        """(H·u)_i = Σ_j H_ij·(u_j − u_i) over the row's off-diagonal entries (the same as
        Σ_j H_ij·u_j, since each row of H sums to zero): on positions the differences keep f32
        from cancelling large coordinates."""
        total = ti.Vector.zero(self.model.real, 3)
        u_i = u[i_p]
        for k in range(self.row_start[i_p], self.row_start[i_p + 1]):
            total += self.row_coefficient[k] * (u[self.row_neighbor[k]] - u_i)
        return total

    @ti.func
    def force(self, model, x, v, i_p, t):
        """f_i = −(H·x)_i − β·(H·v)_i [N]."""
        f = -self._row_product(x, i_p)
        if ti.static(model.has_dashpots):
            f -= self.dashpot_time * self._row_product(v, i_p)
        return f

    @ti.func
    def coupled_products(self, model, u, i_p):
        """((∂f/∂x)·u, (∂f/∂v)·u) at particle i_p: −(H·u)_i and −β·(H·u)_i."""
        stiffness = -self._row_product(u, i_p)
        return stiffness, self.dashpot_time * stiffness

    def coupled_rows(self):
        """H's off-diagonal rows for the Gauss–Seidel sweeps (``gather.sweep_rows``): (start,
        neighbour, H_ij [N/m], β [s]), ∂f_i/∂x_j = −H_ij·I and ∂f_i/∂v_j = −β·H_ij·I."""
        return (self.host_row_start, self.host_row_neighbor, self.host_row_coefficient,
                self.dashpot_time)

    @ti.func
    def coupled_diagonal(self, model, i_p):
        """The diagonal (scalar, times I) of ∂f_i/∂x_i and ∂f_i/∂v_i: −H_ii and −β·H_ii."""
        stiffness = -self.diagonal[i_p]
        return stiffness, self.dashpot_time * stiffness

    def energy(self, x: np.ndarray) -> float:
        """E = ½ Σ_e B_e ‖Σ_a w_a x_a‖² [J] of positions x [m] (N, 3)."""
        corners = x[self.host_stencils]
        curvature = np.einsum("ha,hak->hk", self.host_weights, corners - corners[:, :1])
        return float(0.5 * np.sum(self.host_rigidity * np.einsum("hk,hk->h", curvature,
                                                                 curvature)))

    def potential_energy(self, x: np.ndarray, mass: np.ndarray) -> float:
        return self.energy(x)

    def frame_metrics(self, x: np.ndarray, potential: float) -> dict:
        return {"bending_energy": potential}

    def rest_stiffness_product(self, u: np.ndarray) -> np.ndarray:
        """K·u = H·u of the bending Hessian (−∂f/∂x, positive semi-definite) [N], for ω_max."""
        return self.host_diagonal[:, None] * u + scatter_sum(
            self.host_row_owner, self.host_row_coefficient[:, None] * u[self.host_row_neighbor],
            len(u))

    def stiffness_row_sums(self, particle_count: int) -> np.ndarray:
        """Σ_b |H_ab| per particle a [N/m] (a Gershgorin bound on the Hessian's rows)."""
        return np.abs(self.host_diagonal) + np.bincount(
            self.host_row_owner, np.abs(self.host_row_coefficient), minlength=particle_count)
