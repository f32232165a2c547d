"""The one force evaluation every integrator calls (as warp's ``compute_forces``).

``Forces.particle_force`` is a ``@ti.func`` that gathers the total force on one particle:
springs (seed §2.1: stretch, shear, bend), their dashpots (seed §2.3 f_damper, when the scene
declares ``damping``), and the scene's effects (``effects/``) unrolled with ``ti.static``.
Integrators call it from inside their own kernels, at whatever state (stage) they need, so RK4
stages and the implicit solve see exactly the same forces. Before it, in the same kernel,
``prepare`` runs the passes that serve every particle at once: the effects' per-time data
(capsule poses) and, on a packed grid cloth (``physics.packed_grid``), the SIMD spring pass.
Other spring sets gather through the CSR lists one particle at a time.

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
with ``has_jacobian`` add a per-particle block (contact, drag, wind), effects with
``has_coupled_jacobian`` their products over the particles they couple (bending).
"""

import taichi as ti

from taichi_cloth.physics.model import Model
from taichi_cloth.physics.packed_grid import PackedGrid


@ti.data_oriented
class Forces:
    """Springs, dashpots (when the model has them) and the scene's effects."""

    def __init__(self, model: Model, effects: list, packed: PackedGrid | None = None):
        """effects: ``effects.Effect`` objects in ``EFFECTS`` order; packed: the SIMD layout of a
        grid cloth's springs (``packed_grid.packed_grid_for``), or None to gather them."""
        self.model = model
        self.effects = effects
        self.force_effects = [e for e in effects if e.has_force]
        # the effects that particles gather, and whose passes ``prepare`` runs: all but those
        # acting in the packed pass (which need no pass of their own)
        in_lanes = packed.lane_effects if packed is not None else []
        self.gathered_effects = [e for e in self.force_effects if e not in in_lanes]
        # of those, the ones that are not a uniform acceleration (contact, wind, the ground...)
        self.pointwise_effects = [e for e in self.gathered_effects
                                  if e.uniform_acceleration is None]
        # whether each of those lists the particles it acts on (``Effect.touched_particles``)
        self.pointwise_listed = all(e.touched_particles is not None
                                    for e in self.pointwise_effects)
        self.prepared_effects = [e for e in effects if e not in in_lanes]
        self.jacobian_effects = [e for e in effects if e.has_jacobian]
        self.coupled_effects = [e for e in effects if e.has_coupled_jacobian]
        self.packed = packed
        self.has_packed = packed is not None

    @property
    def compiled_names(self) -> list[str]:
        """What is compiled into the force evaluation, for ``stats.json``."""
        return [e.name for e in self.effects]

    @property
    def uniform_acceleration(self) -> tuple:
        """Σ of the uniform accelerations [m/s²] (x, y, z) of the gathered force effects that
        are one (gravity), which a step can add per SIMD lane (the packed pass has the effects
        acting in it, ``pointwise_force`` the others)."""
        return tuple(sum(e.uniform_acceleration[c] for e in self.gathered_effects
                         if e.uniform_acceleration is not None) for c in range(3))

    @ti.func
    def prepare_effects(self, x, v, t):
        """The effects' passes at (x, v) and time t [s] (capsule poses, contact of the surface
        samples), before any particle loop (but those of effects acting in the packed pass)."""
        for e in ti.static(range(len(self.prepared_effects))):
            self.prepared_effects[e].prepare(x, v, t)

    @ti.func
    def prepare_serially(self, x, v, t):
        """``prepare`` with each effect's passes inside a serial loop of their own (no hand-off
        to the thread pool; each effect one task, compiled apart), but an effect that
        ``arranges_own_passes``."""
        for e in ti.static(range(len(self.prepared_effects))):
            if ti.static(self.prepared_effects[e].arranges_own_passes):
                self.prepared_effects[e].prepare(x, v, t)
            else:
                ti.loop_config(serialize=True)
                for _ in range(1):
                    self.prepared_effects[e].prepare(x, v, t)
        if ti.static(self.has_packed):
            self.packed.spring_pass(x, v)

    @ti.func
    def prepare(self, x, v, t):
        """Everything ``particle_force`` reads at (x, v, t) that serves all particles:
        ``prepare_effects``, then on a packed grid the SIMD spring pass."""
        self.prepare_effects(x, v, t)
        if ti.static(self.has_packed):
            self.packed.spring_pass(x, v)

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
        for e in ti.static(range(len(self.jacobian_effects))):
            stiffness_block, damping_block = self.jacobian_effects[e].local_jacobian(
                model, x, v, i_p, t, definite)
            stiffness_product += stiffness_block @ u[i_p]
            damping_product += damping_block @ u[i_p]
        for e in ti.static(range(len(self.coupled_effects))):
            stiffness, damping = self.coupled_effects[e].coupled_products(model, u, i_p)
            stiffness_product += stiffness
            damping_product += damping
        return stiffness_product, damping_product

    @ti.kernel
    def evaluate_jacobian_products(self, x: ti.template(), v: ti.template(), u: ti.template(),
                                   t: ti.f64, definite: ti.template(),
                                   stiffness_out: ti.template(), damping_out: ti.template()):
        """(∂f/∂x)·u and (∂f/∂v)·u for every particle (for tests and diagnostics)."""
        self.prepare_effects(x, v, t)
        for i_p in x:
            stiffness_out[i_p], damping_out[i_p] = self.jacobian_products(
                x, v, u, i_p, ti.cast(t, self.model.real), definite)

    @ti.func
    def particle_force(self, x, v, i_p, t):
        """Total force on particle i_p [N] at positions x, velocities v, time t [s], after
        ``prepare`` at the same (x, v, t) in the same kernel."""
        f = ti.Vector.zero(self.model.real, 3)
        if ti.static(self.has_packed):
            f = self.packed.spring_force(i_p)
        else:
            f = self.spring_force(x, v, i_p)
        return f + self.gathered_force(x, v, i_p, t)

    @ti.func
    def gathered_force(self, x, v, i_p, t):
        """The force on particle i_p [N] of the effects it gathers (``gathered_effects``: all
        but the springs and the effects acting in the packed pass), after ``prepare_effects``."""
        f = ti.Vector.zero(self.model.real, 3)
        for e in ti.static(range(len(self.gathered_effects))):
            f += self.gathered_effects[e].force(self.model, x, v, i_p, t)
        return f

    @ti.func
    def pointwise_force(self, x, v, i_p, t):
        """The force on particle i_p [N] of ``pointwise_effects`` (the gathered effects but the
        uniform accelerations), after ``prepare_effects``."""
        f = ti.Vector.zero(self.model.real, 3)
        for e in ti.static(range(len(self.pointwise_effects))):
            f += self.pointwise_effects[e].force(self.model, x, v, i_p, t)
        return f

    @ti.kernel
    def evaluate(self, x: ti.template(), v: ti.template(), t: ti.f64, out: ti.template()):
        """Every particle's total force into ``out`` [N] (for tests and diagnostics)."""
        self.prepare(x, v, t)
        for i_p in x:
            out[i_p] = self.particle_force(x, v, i_p, ti.cast(t, self.model.real))

