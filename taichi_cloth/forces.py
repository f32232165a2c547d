"""The one force evaluation every integrator calls (DESIGN.md; warp's ``compute_forces``).

``Forces.particle_force`` is a ``@ti.func`` that gathers the total force on one particle:
springs (seed §2.1: stretch, shear, bend), their dashpots (seed §2.3 f_damper), and the scene's
declared effects unrolled with ``ti.static`` (gravity, drag, wind, contact). Integrators call it
from inside their own kernels, at whatever state (stage) they need, so RK4 stages and the implicit
solve see exactly the same forces.

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

from .contact import GroundContact
from .effects import Drag, Gravity, Wind
from .model import Model
from .scene import EFFECT_TYPES

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


@ti.data_oriented
class Forces:
    """Springs, dashpots (when the model has them) and the listed effects."""

    def __init__(self, model: Model, effects: list):
        self.model = model
        self.effects = effects

    @property
    def compiled_names(self) -> list[str]:
        """What is compiled into the force evaluation, for ``stats.json``."""
        names = [e.name for e in self.effects] + (["damping"] if self.model.has_dashpots else [])
        return sorted(names, key=list(EFFECT_TYPES).index)

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
    def spring_blocks(self, x, i_p, k, definite: ti.template()):
        """(neighbour j, K_s, D_s) of the k-th gather entry of particle i_p."""
        model = self.model
        i_s = model.particle_spring[k]
        j_p = model.particle_neighbor[k]
        d = x[j_p] - x[i_p]
        length = d.norm()
        stiffness_block = ti.Matrix.zero(model.real, 3, 3)
        damping_block = ti.Matrix.zero(model.real, 3, 3)
        if length > 0:
            n = d / length
            outer = n.outer_product(n)
            geometric = 1 - model.spring_rest_length[i_s] / length
            if ti.static(definite):
                geometric = ti.max(geometric, 0.0)
            identity = ti.Matrix.identity(model.real, 3)
            stiffness_block = model.spring_stiffness[i_s] * (outer + geometric * (identity - outer))
            if ti.static(model.has_dashpots):
                damping_block = model.spring_damping[i_s] * outer
        return j_p, stiffness_block, damping_block

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

    @ti.func
    def jacobian_diagonal(self, x, v, i_p, t):
        """Diagonals of −∂f_i/∂x_i and −∂f_i/∂v_i (definite version), for a Jacobi
        preconditioner."""
        model = self.model
        stiffness_diagonal = ti.Vector.zero(model.real, 3)
        damping_diagonal = ti.Vector.zero(model.real, 3)
        for k in range(model.particle_spring_start[i_p], model.particle_spring_start[i_p + 1]):
            _, stiffness_block, damping_block = self.spring_blocks(x, i_p, k, True)
            for c in ti.static(range(3)):
                stiffness_diagonal[c] += stiffness_block[c, c]
                damping_diagonal[c] += damping_block[c, c]
        for e in ti.static(range(len(self.effects))):
            if ti.static(getattr(self.effects[e], "has_local_jacobian", False)):
                stiffness_block, damping_block = self.effects[e].local_jacobian(
                    model, x, v, i_p, t, True)
                for c in ti.static(range(3)):
                    stiffness_diagonal[c] -= stiffness_block[c, c]
                    damping_diagonal[c] -= damping_block[c, c]
        return stiffness_diagonal, damping_diagonal

    @ti.kernel
    def evaluate_jacobian_products(self, x: ti.template(), v: ti.template(), u: ti.template(),
                                   t: ti.f64, definite: ti.template(),
                                   stiffness_out: ti.template(), damping_out: ti.template()):
        """(∂f/∂x)·u and (∂f/∂v)·u for every particle (for tests and diagnostics)."""
        for i_p in x:
            stiffness_out[i_p], damping_out[i_p] = self.jacobian_products(
                x, v, u, i_p, ti.cast(t, self.model.real), definite)

    @ti.func
    def particle_force(self, x, v, i_p, t):
        """Total force on particle i_p [N] at positions x, velocities v, time t [s]."""
        f = self.spring_force(x, v, i_p)
        for k in ti.static(range(len(self.effects))):
            f += self.effects[k].force(self.model, x, v, i_p, t)
        return f

    @ti.kernel
    def evaluate(self, x: ti.template(), v: ti.template(), t: ti.f64, out: ti.template()):
        """Every particle's total force into ``out`` [N] (for tests and diagnostics)."""
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
