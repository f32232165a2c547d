"""Backward Euler, linearised once per step (Baraff & Witkin, "Large steps in cloth simulation",
SIGGRAPH 1998), the implicit integration the seed paper names as future work (§4.2).

Backward Euler asks for v₁ with M·(v₁ − v₀) = h·f(x₀ + h·v₁, v₁, t + h). Newton's method on
it, from the candidate v_c = v₀ (x_c = x₀ + h·v_c), solves at each iteration

    (M − h·D − h²·K) · δ = h·f(x_c, v_c, t + h) − M·(v_c − v₀),     v_c += δ,

with K = ∂f/∂x and D = ∂f/∂v at the candidate. One iteration is Baraff & Witkin's step (their
right-hand side h·(f₀ + h·K·v₀) is the first-order expansion of h·f(x₀ + h·v₀, v₀));
``newton_iterations`` > 1 re-linearises, which matters when contacts start or end within a large
step. Forces are taken at the step's end time t + h, so capsules, pins and wind are where they
will be: the solve pushes cloth out of a leg that moves into it during the step.

The system matrix A = M − h·D − h²·K is symmetric positive definite with the definite spring
Jacobians of ``forces.py``; it is never assembled: conjugate gradients use the gathered products
K·u and D·u. A Jacobi preconditioner uses A's diagonal. Pinned particles are filtered out of the
system as in Baraff & Witkin's modified CG (§5.3): the candidate holds them at their targets, and
the filter S zeroes their components of the residual and search directions, so δ = 0 for them.

Dot products are summed in fixed blocks, each block in order, then the blocks in order, so a
solve is bit-reproducible (no racing atomic float adds). Scratch fields are allocated once.
"""

import math

import taichi as ti

from ..model import State
from .base import Integrator

DOT_BLOCK = 256


class SolverBreakdown(ArithmeticError):
    """CG met a non-finite residual or a direction of non-positive curvature: the step cannot be
    trusted (the frame guard rolls it back and halves the step)."""  # particles per partial sum of a deterministic dot product


@ti.data_oriented
class BackwardEuler(Integrator):
    name = "implicit"
    substep_batch = 1

    def __init__(self, forces, post_step=None, tolerance: float = 1e-3,
                 max_iterations: int = 500, newton_iterations: int = 1):
        """tolerance: relative preconditioned residual √(r·P⁻¹r / r₀·P⁻¹r₀) at which CG stops."""
        super().__init__(forces, post_step)
        n, real = self.model.particle_count, self.model.real
        self.tolerance = tolerance
        self.max_iterations = max_iterations
        self.newton_iterations = newton_iterations
        self.candidate = State(n, real)
        self.delta_v = ti.Vector.field(3, real, n)
        self.rhs = ti.Vector.field(3, real, n)
        self.residual = ti.Vector.field(3, real, n)
        self.preconditioned = ti.Vector.field(3, real, n)
        self.direction = ti.Vector.field(3, real, n)
        self.product = ti.Vector.field(3, real, n)
        self.diagonal = ti.Vector.field(3, real, n)
        self.block_count = math.ceil(n / DOT_BLOCK)
        self.partial = ti.field(ti.f64, self.block_count)
        self.step_iterations = []  # CG iterations of each step since the last ``take_iterations``
        self.unconverged_steps = 0

    def take_iterations(self) -> list[int]:
        """CG iterations per step since the last call."""
        taken, self.step_iterations = self.step_iterations, []
        return taken

    def advance(self, state_a: State, state_b: State, t: float, dt: float, count: int):
        for k in range(count):
            self.step(state_a, state_b, t + k * dt, dt)
            state_a, state_b = state_b, state_a
        return state_a, state_b

    def step(self, state_in: State, state_out: State, t: float, dt: float) -> None:
        """One backward Euler step by ``newton_iterations`` Newton iterations; the CG
        iterations of the step are recorded."""
        self._start_candidate(state_in, t, dt)
        iterations = 0
        for _ in range(self.newton_iterations):
            self._prepare(state_in, t, dt)
            iterations += self._solve(t, dt)
            self._accept(state_in, dt)
        self.step_iterations.append(iterations)
        state_out.copy_from(self.candidate)
        if self.has_post_step:
            self._post_step(state_out, t + dt)

    def _solve(self, t: float, dt: float) -> int:
        """Preconditioned CG for A·δ = rhs on the free particles; returns its iterations."""
        rz = self._start_residual()
        if not math.isfinite(rz):
            raise SolverBreakdown(f"the right-hand side is not finite (r·z = {rz})")
        threshold = self.tolerance ** 2 * rz
        iterations = 0
        while rz > threshold and rz > 0 and iterations < self.max_iterations:
            self._apply(self.candidate, self.direction, t, dt)
            curvature = self._dot(self.direction, self.product)
            if not (math.isfinite(curvature) and curvature > 0 and math.isfinite(rz)):
                raise SolverBreakdown(f"conjugate gradients broke down at iteration {iterations} "
                                      f"(p·Ap = {curvature:.3g}, r·z = {rz:.3g})")
            alpha = rz / curvature
            rz_new = self._update(alpha)
            self._new_direction(rz_new / rz)
            rz = rz_new
            iterations += 1
        if rz > threshold:
            self.unconverged_steps += 1
        return iterations

    @ti.func
    def _block_sums(self, a, b):
        for block in range(self.block_count):
            total = ti.f64(0.0)
            for i_p in range(block * DOT_BLOCK, ti.min((block + 1) * DOT_BLOCK, a.shape[0])):
                total += ti.cast(a[i_p].dot(b[i_p]), ti.f64)
            self.partial[block] = total

    @ti.func
    def _total(self) -> ti.f64:
        total = ti.f64(0.0)
        ti.loop_config(serialize=True)
        for block in range(self.block_count):
            total += self.partial[block]
        return total

    @ti.kernel
    def _dot(self, a: ti.template(), b: ti.template()) -> ti.f64:
        self._block_sums(a, b)
        return self._total()

    @ti.kernel
    def _start_candidate(self, state: ti.template(), t: ti.f64, dt: ti.f64):
        """v_c = v₀ and x_c = x₀ + h·v₀; pinned particles at their targets at t + h."""
        model = self.model
        h = ti.cast(dt, model.real)
        for i_p in state.x:
            if model.particle_inv_mass[i_p] == 0:
                self.candidate.x[i_p], self.candidate.v[i_p] = model.pin_target(i_p, t + dt)
            else:
                self.candidate.v[i_p] = state.v[i_p]
                self.candidate.x[i_p] = state.x[i_p] + h * state.v[i_p]

    @ti.kernel
    def _prepare(self, state: ti.template(), t: ti.f64, dt: ti.f64):
        """rhs = h·f(x_c, v_c, t + h) − M·(v_c − v₀), and A's diagonal at the candidate."""
        model = self.model
        forces = self.forces
        candidate = self.candidate
        h = ti.cast(dt, model.real)
        time = ti.cast(t + dt, model.real)  # backward Euler: forces at the step's end time
        forces.prepare(candidate.x, candidate.v, t + dt)
        for i_p in state.x:
            force = forces.particle_force(candidate.x, candidate.v, i_p, time)
            self.rhs[i_p] = h * force - model.particle_mass[i_p] * (candidate.v[i_p] - state.v[i_p])
            stiffness_diagonal, damping_diagonal = forces.jacobian_diagonal(
                candidate.x, candidate.v, i_p, time)
            self.diagonal[i_p] = model.particle_mass[i_p] + h * damping_diagonal \
                + h * h * stiffness_diagonal
            self.delta_v[i_p] = ti.Vector.zero(model.real, 3)

    @ti.kernel
    def _accept(self, state: ti.template(), dt: ti.f64):
        """v_c += δ, x_c = x₀ + h·v_c for the free particles."""
        model = self.model
        h = ti.cast(dt, model.real)
        for i_p in state.x:
            if model.particle_inv_mass[i_p] > 0:
                self.candidate.v[i_p] += self.delta_v[i_p]
                self.candidate.x[i_p] = state.x[i_p] + h * self.candidate.v[i_p]

    @ti.kernel
    def _apply(self, state: ti.template(), u: ti.template(), t: ti.f64, dt: ti.f64):
        """product = A·u = M·u − h·D·u − h²·K·u (unfiltered)."""
        model = self.model
        forces = self.forces
        h = ti.cast(dt, model.real)
        time = ti.cast(t + dt, model.real)  # backward Euler: forces at the step's end time
        forces.prepare_effects(t + dt)
        for i_p in state.x:
            stiffness_u, damping_u = forces.jacobian_products(state.x, state.v, u, i_p, time, True)
            self.product[i_p] = model.particle_mass[i_p] * u[i_p] - h * damping_u \
                - h * h * stiffness_u

    @ti.func
    def _free(self, i_p):
        return self.model.particle_inv_mass[i_p] > 0

    @ti.kernel
    def _start_residual(self) -> ti.f64:
        """r = S·rhs (δ starts at 0), z_pre = P⁻¹·r, p = z_pre; returns r·z_pre."""
        for i_p in self.residual:
            r = ti.Vector.zero(self.model.real, 3)
            if self._free(i_p):
                r = self.rhs[i_p]
            self.residual[i_p] = r
            self.preconditioned[i_p] = r / self.diagonal[i_p]
            self.direction[i_p] = self.preconditioned[i_p]
        self._block_sums(self.residual, self.preconditioned)
        return self._total()

    @ti.kernel
    def _update(self, alpha: ti.f64) -> ti.f64:
        """Δv += α·p, r −= α·S·A·p, z_pre = P⁻¹·r; returns r·z_pre."""
        a = ti.cast(alpha, self.model.real)
        for i_p in self.residual:
            if self._free(i_p):
                self.delta_v[i_p] += a * self.direction[i_p]
                self.residual[i_p] -= a * self.product[i_p]
            self.preconditioned[i_p] = self.residual[i_p] / self.diagonal[i_p]
        self._block_sums(self.residual, self.preconditioned)
        return self._total()

    @ti.kernel
    def _new_direction(self, beta: ti.f64):
        b = ti.cast(beta, self.model.real)
        for i_p in self.direction:
            p = ti.Vector.zero(self.model.real, 3)
            if self._free(i_p):
                p = self.preconditioned[i_p] + b * self.direction[i_p]
            self.direction[i_p] = p

    @ti.kernel
    def _post_step(self, state: ti.template(), t: ti.f64):
        self.post_step.apply(state, t)
