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
(β: the model's ``dashpot_time``). Each particle gathers over its own stencils (a fixed order).

Warp and weft: each hinge takes the garment's ``hinge_rigidity``, B_e = B_weft·cos²ψ +
B_warp·sin²ψ for a rest edge at angle ψ to the warp (``cloth.garment.hinge_rigidity``, beside
the stretch springs' own anisotropy).
"""

from dataclasses import dataclass

import numpy as np
import taichi as ti

from taichi_cloth.effects.base import Effect, EffectContext
from taichi_cloth.gather import incidence_lists
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
        self.host_damping = (model.dashpot_time or 0.0) * self.host_rigidity
        start, item, slot = incidence_lists(stencils, model.particle_count)
        count, real = max(1, len(stencils)), model.real
        self.stencil = ti.Vector.field(4, ti.i32, count)
        self.weight = ti.Vector.field(4, real, count)
        self.rigidity = ti.field(real, count)
        self.damping = ti.field(real, count)
        self.particle_stencil_start = ti.field(ti.i32, model.particle_count + 1)
        self.particle_stencil = ti.field(ti.i32, max(1, len(item)))
        self.particle_slot = ti.field(ti.i32, max(1, len(item)))
        self._tables = (stencils, start, item, slot)

    def upload(self) -> None:
        """Fill the fields (after every allocation: one SNode tree, ``physics/control.py``)."""
        stencils, start, item, slot = self._tables
        real = self.model.numpy_real
        if len(stencils):
            self.stencil.from_numpy(stencils)
            self.weight.from_numpy(self.host_weights.astype(real))
            self.rigidity.from_numpy(self.host_rigidity.astype(real))
            self.damping.from_numpy(self.host_damping.astype(real))
            self.particle_stencil.from_numpy(item)
            self.particle_slot.from_numpy(slot)
        self.particle_stencil_start.from_numpy(start)

    @ti.func
    def _stencil_sum(self, u, s):
        """Σ_a w_a·u_a over stencil s, as Σ_a w_a·(u_a − u_0) (the same, since Σ w_a = 0): on
        positions the differences keep f32 from cancelling large coordinates."""
        origin = u[self.stencil[s][0]]
        total = ti.Vector.zero(self.model.real, 3)
        for a in ti.static(range(1, 4)):
            total += self.weight[s][a] * (u[self.stencil[s][a]] - origin)
        return total

    @ti.func
    def force(self, model, x, v, i_p, t):
        f = ti.Vector.zero(model.real, 3)
        for k in range(self.particle_stencil_start[i_p], self.particle_stencil_start[i_p + 1]):
            s = self.particle_stencil[k]
            along = self.rigidity[s] * self._stencil_sum(x, s)
            if ti.static(model.has_dashpots):
                along += self.damping[s] * self._stencil_sum(v, s)
            f -= self.weight[s][self.particle_slot[k]] * along
        return f

    @ti.func
    def coupled_products(self, model, u, i_p):
        """((∂f/∂x)·u, (∂f/∂v)·u) at particle i_p: −w_a·B_e·(w·u), −w_a·c_e·(w·u) summed over
        its stencils."""
        stiffness = ti.Vector.zero(model.real, 3)
        damping = ti.Vector.zero(model.real, 3)
        for k in range(self.particle_stencil_start[i_p], self.particle_stencil_start[i_p + 1]):
            s = self.particle_stencil[k]
            spread = self.weight[s][self.particle_slot[k]] * self._stencil_sum(u, s)
            stiffness -= self.rigidity[s] * spread
            damping -= self.damping[s] * spread
        return stiffness, damping

    @ti.func
    def coupled_diagonal(self, model, i_p):
        """The diagonal (scalar, times I) of ∂f_i/∂x_i and ∂f_i/∂v_i: −Σ w_a²·B_e, −Σ w_a²·c_e."""
        stiffness, damping = model.real(0.0), model.real(0.0)
        for k in range(self.particle_stencil_start[i_p], self.particle_stencil_start[i_p + 1]):
            s = self.particle_stencil[k]
            w_sq = self.weight[s][self.particle_slot[k]] ** 2
            stiffness -= w_sq * self.rigidity[s]
            damping -= w_sq * self.damping[s]
        return stiffness, damping

    def energy(self, x: np.ndarray) -> float:
        """E = ½ Σ_e B_e ‖Σ_a w_a x_a‖² [J] of positions x [m] (N, 3)."""
        corners = x[self.host_stencils]
        curvature = np.einsum("ha,hak->hk", self.host_weights, corners - corners[:, :1])
        return float(0.5 * np.sum(self.host_rigidity * np.einsum("hk,hk->h", curvature,
                                                                 curvature)))

    def potential_energy(self, x: np.ndarray, mass: np.ndarray) -> float:
        return self.energy(x)

    def frame_metrics(self, x: np.ndarray) -> dict:
        return {"bending_energy": self.energy(x)}

    def rest_stiffness_product(self, u: np.ndarray) -> np.ndarray:
        """K·u of the bending Hessian (−∂f/∂x, positive semi-definite) [N], for ω_max."""
        spread = self.host_rigidity[:, None] * np.einsum("ha,hak->hk", self.host_weights,
                                                         u[self.host_stencils])
        product = np.zeros_like(u)
        for a in range(4):
            np.add.at(product, self.host_stencils[:, a], self.host_weights[:, a, None] * spread)
        return product

    def stiffness_row_sums(self, particle_count: int) -> np.ndarray:
        """Σ_b |K_ab| per particle a [N/m] (a Gershgorin bound on the Hessian's rows)."""
        row = np.abs(self.host_weights) * (self.host_rigidity
                                           * np.abs(self.host_weights).sum(axis=1))[:, None]
        sums = np.zeros(particle_count)
        for a in range(4):
            np.add.at(sums, self.host_stencils[:, a], row[:, a])
        return sums
