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
Jacobians of ``forces.py``; it is never assembled. Once per Newton iteration ``_blocks`` stores
what a product needs: for every gather entry k (spring s of particle i, other end j) the unit
direction n = (x_j − x_i)/|x_j − x_i| and the two scalars of the spring's block of A,

    A_s = a_s·n·nᵀ + b_s·I,   a_s = h·c + h²·k·(1 − g),   b_s = h²·k·g,   g = max(1 − L/l, 0)

(``forces.Forces.spring_axis`` with the definite clamp: h·D_s + h²·K_s), and for every particle
its own block L_i = m_i·I − h·D_loc − h²·K_loc from the effects with ``has_jacobian``
(contact, drag, wind; just m_i·I without them). A product then gathers in the fixed CSR order:

    (A·u)_i = L_i·u_i + Σ_k [a_k·(n_k·(u_i − u_j))·n_k + b_k·(u_i − u_j)]      (A in kg).

A Jacobi preconditioner P uses A's diagonal. Pinned particles are filtered out of the system as
in Baraff & Witkin's modified CG (§5.3): the candidate holds them at their targets, and the
filter S zeroes their residual, preconditioned residual and direction, so δ = 0 for them.

Each CG iteration is three passes over fixed blocks of ``DOT_BLOCK`` particles: the direction
p = z + β·p; A·p with the block's part of p·A·p; δ += α·p, r −= α·A·p and z = P⁻¹·r with the
block's part of r·z. Dot products sum each block in order, then the blocks in order, so a solve
is bit-reproducible whatever the thread count (no racing atomic float adds). Small cloth
(``self.serial``) runs the whole solve, convergence test included, in one kernel launch on one
thread; larger cloth launches one kernel per iteration, each pass a parallel loop over the
blocks. Both run the same block functions and take the same steps. Scratch fields are allocated
once; only ``_start_candidate`` (and the copy out) is compiled once per state.

Warm start: the first Newton iteration of a step starts CG from δ₀ extrapolated from the last two
steps' velocity changes (``_start_weights``), scaled by the s that minimises the starting
r·P⁻¹r (``_guess_scale``: never further from the stopping test than δ = 0). The stopping test
stays relative to the cold start's r₀·P⁻¹r₀ = (S·rhs)·P⁻¹(S·rhs), so a solve stops at the same
residual as from 0 (a checkpoint keeps the history: ``memory``). Mean CG iterations per step, cold → warm, at h = 1/60 s: bench reference
sheet (30 steps after 2) 100.4 → 77.4 at 32×32, 118.3 → 93.3 at 64×64, 137.7 → 103.0 at
128×128; scenes (45–60 frames) hula 36.4 → 34.5, sheet 70.9 → 66.1, flag 281 → 177, drape
229 → 240. The error left is of the same size: against a solve at tolerance 10⁻⁶, the 64×64
sheet's velocities are off by at most 0.0017 m/s warm, 0.0024 m/s cold (top speed 4.5 m/s).
"""

import math

import numpy as np
import taichi as ti

from taichi_cloth.physics.model import State
from taichi_cloth.physics.integrators.base import Integrator

DOT_BLOCK = 256  # particles per partial sum of a deterministic dot product

# How a solve ended: the first entry of (outcome, iterations, p·A·p, r·z).
CONVERGED, UNCONVERGED, BREAKDOWN, NOT_FINITE = 0, 1, 2, 3
SOLVE_REPORT = ti.types.vector(4, ti.f64)
SUMS = ti.types.vector(2, ti.f64)


class SolverBreakdown(ArithmeticError):
    """CG met a non-finite residual or a direction of non-positive curvature: the step cannot be
    trusted (the frame guard rolls it back and halves the step)."""


@ti.func
def finite(value):
    """Neither NaN nor ±∞ (explicit tests: fast math must not fold them away)."""
    return not (ti.math.isnan(value) or ti.math.isinf(value))


@ti.data_oriented
class BackwardEuler(Integrator):
    name = "implicit"
    substep_batch = 1

    def __init__(self, forces, control, post_step=None, tolerance: float = 1e-3,
                 max_iterations: int = 500, newton_iterations: int = 1, warm_start: bool = True):
        """tolerance: relative preconditioned residual √(r·P⁻¹r / r₀·P⁻¹r₀) at which CG stops
        (r₀ the residual of the cold start δ = 0); warm_start: start each step's first solve from
        the last step's velocity change (module docstring)."""
        super().__init__(forces, control, post_step)
        model = self.model
        n, real = model.particle_count, model.real
        self.tolerance = tolerance
        self.max_iterations = max_iterations
        self.newton_iterations = newton_iterations
        self.warm_start = warm_start
        self.has_local_blocks = bool(forces.jacobian_effects)
        self.start = State(n, real)  # the step's (x₀, v₀)
        self.candidate = State(n, real)
        self.delta_v = ti.Vector.field(3, real, n)
        # v₁ − v₀ of the last two steps [m/s] and their steps [s] (0: no such step yet)
        self.last_change = ti.Vector.field(3, real, n)
        self.older_change = ti.Vector.field(3, real, n)
        self.change_dts = (0.0, 0.0)
        self.rhs = ti.Vector.field(3, real, n)
        self.residual = ti.Vector.field(3, real, n)
        self.preconditioned = ti.Vector.field(3, real, n)
        self.direction = ti.Vector.field(3, real, n)
        self.product = ti.Vector.field(3, real, n)
        self.inverse_diagonal = ti.Vector.field(3, real, n)
        self.spring_block = ti.Struct.field({"direction": ti.types.vector(3, real),
                                             "axial": real, "isotropic": real},
                                            shape=model.particle_neighbor.shape[0])
        if self.has_local_blocks:
            self.local_block = ti.Matrix.field(3, 3, real, n)
        self.block_count = math.ceil(n / DOT_BLOCK)
        self.curvature_partial = ti.field(ti.f64, self.block_count)
        self.residual_partial = ti.field(ti.f64, self.block_count)
        self.cold_partial = ti.field(ti.f64, self.block_count)
        self.guess_partial = ti.field(ti.f64, self.block_count)
        self.guess_length_partial = ti.field(ti.f64, self.block_count)
        self.step_iterations = []  # CG iterations of each step since the last ``take_iterations``
        self.unconverged_steps = 0

    def memory(self) -> dict:
        """The warm start's history (the last two steps' velocity changes and their steps) and
        the count of unconverged steps so far."""
        return {"last_change": self.last_change.to_numpy(),
                "older_change": self.older_change.to_numpy(),
                "change_dts": np.array(self.change_dts, np.float64),
                "unconverged_steps": np.array(self.unconverged_steps)}

    def restore_memory(self, memory: dict) -> None:
        self.last_change.from_numpy(memory["last_change"])
        self.older_change.from_numpy(memory["older_change"])
        self.change_dts = tuple(float(dt) for dt in memory["change_dts"])
        self.unconverged_steps = int(memory["unconverged_steps"])

    def take_iterations(self) -> list[int]:
        """CG iterations per step since the last call."""
        taken, self.step_iterations = self.step_iterations, []
        return taken

    def launch(self, state_a: State, state_b: State, t: float, dt: float, count: int):
        """``count`` steps, each its own launches (the Newton and CG loops run in Python)."""
        for k in range(count):
            self.step(state_a, state_b, t + k * dt, dt)
            state_a, state_b = state_b, state_a
        return state_a, state_b

    def step(self, state_in: State, state_out: State, t: float, dt: float) -> None:
        """One backward Euler step by ``newton_iterations`` Newton iterations; the CG
        iterations of the step are recorded."""
        self._start_candidate(state_in, t, dt)
        iterations = 0
        for newton in range(self.newton_iterations):
            self._prepare(t, dt, *(self._start_weights(dt) if newton == 0 else (0.0, 0.0)))
            iterations += self._solve()
            self._accept(dt, newton == self.newton_iterations - 1)
        self.change_dts = (dt, self.change_dts[0])
        self.step_iterations.append(iterations)
        state_out.copy_from(self.candidate)
        if self.has_post_step:
            self._post_step(state_out, t + dt)

    def _start_weights(self, dt: float) -> tuple[float, float]:
        """(w₁, w₂) of the warm start δ₀ = w₁·Δv₁ + w₂·Δv₂ from the last two steps' velocity
        changes: the accelerations Δv/h, taken at the steps' midpoints, extrapolated linearly
        to this step's midpoint, times h; Δv₁·h/h₁ after one step, 0 before (or cold)."""
        last_dt, older_dt = self.change_dts
        if not self.warm_start or last_dt == 0:
            return 0.0, 0.0
        if older_dt == 0:
            return dt / last_dt, 0.0
        slope = (last_dt + dt) / (last_dt + older_dt)
        return dt * (1 + slope) / last_dt, -dt * slope / older_dt

    def _solve(self) -> int:
        """Preconditioned CG for A·δ = rhs on the free particles; returns its iterations."""
        tolerance_sq = self.tolerance ** 2
        if self.serial:
            outcome, iterations, curvature, rz = self._solve_serial(tolerance_sq,
                                                                    self.max_iterations)
        else:
            outcome, iterations, curvature, rz = self._solve_parallel(tolerance_sq)
        iterations = int(iterations)
        if outcome == NOT_FINITE:
            raise SolverBreakdown(f"the right-hand side is not finite (r·z = {rz})")
        if outcome == BREAKDOWN:
            raise SolverBreakdown(f"conjugate gradients broke down at iteration {iterations} "
                                  f"(p·Ap = {curvature:.3g}, r·z = {rz:.3g})")
        if outcome == UNCONVERGED:
            self.unconverged_steps += 1
        return iterations

    def _solve_parallel(self, tolerance_sq: float):
        """``_solve_serial``'s solve with the same tests, one kernel launch per iteration."""
        cold_rz, rz = self._start()
        if not math.isfinite(cold_rz):
            return NOT_FINITE, 0, 0.0, cold_rz
        threshold = tolerance_sq * cold_rz
        iterations, curvature, beta = 0, 0.0, 0.0
        while True:
            if not math.isfinite(rz):
                return BREAKDOWN, iterations, curvature, rz
            if not (rz > threshold and rz > 0):
                return CONVERGED, iterations, curvature, rz
            if iterations == self.max_iterations:
                return UNCONVERGED, iterations, curvature, rz
            curvature, rz_new = self._iterate(rz, beta)
            if not (math.isfinite(curvature) and curvature > 0):
                return BREAKDOWN, iterations, curvature, rz
            beta = rz_new / rz
            rz = rz_new
            iterations += 1

    @ti.kernel
    def _solve_serial(self, tolerance_sq: ti.f64, max_iterations: ti.i32) -> SOLVE_REPORT:
        """The whole solve in this launch, on one thread: returns (outcome, iterations, p·A·p,
        r·z), the last two where it stopped. Stops when r·z ≤ tolerance²·r₀·P⁻¹r₀ (converged),
        after ``max_iterations`` (unconverged), or at a non-finite r·z or a p·A·p that is not
        positive (breakdown)."""
        sums = self._start_passes(True)
        cold_rz, rz = sums[0], sums[1]
        threshold = tolerance_sq * cold_rz
        outcome = -1  # running
        iterations = 0
        curvature = ti.f64(0.0)
        beta = ti.f64(0.0)
        if not finite(cold_rz):
            outcome = NOT_FINITE
        while outcome < 0:
            if not finite(rz):
                outcome = BREAKDOWN
            elif not (rz > threshold and rz > 0):
                outcome = CONVERGED
            elif iterations == max_iterations:
                outcome = UNCONVERGED
            else:
                result = self._iteration_passes(rz, beta)
                curvature = result[0]
                if not (finite(curvature) and curvature > 0):
                    outcome = BREAKDOWN
                else:
                    beta = result[1] / rz
                    rz = result[1]
                    iterations += 1
        return ti.Vector([outcome, iterations, curvature, rz], ti.f64)

    @ti.kernel
    def _start(self) -> SUMS:
        """``_start_passes`` of a parallel solve."""
        return self._start_passes(False)

    @ti.kernel
    def _iterate(self, rz: ti.f64, beta: ti.f64) -> SUMS:
        """``_iteration_passes`` of a parallel solve."""
        return self._iteration_passes(rz, beta)

    @ti.func
    def _start_passes(self, serial: ti.template()):
        """The start δ = s·δ₀ and its residual, pass by pass over the blocks (each pass one loop,
        serialised when ``serial``): returns (r₀·P⁻¹r₀ of the cold start, r·z of the start
        taken)."""
        ti.loop_config(serialize=serial)
        for block in range(self.block_count):
            self._guess_block(block)
        scale = self._guess_scale()
        ti.loop_config(serialize=serial)
        for block in range(self.block_count):
            self._start_block(block, scale)
        return ti.Vector([self._sum(self.cold_partial), self._sum(self.residual_partial)])

    @ti.func
    def _iteration_passes(self, rz, beta):
        """One CG iteration, pass by pass over the blocks: returns (p·A·p, the new r·z). With
        p·A·p not positive the update is garbage, and the caller reports a breakdown."""
        for block in range(self.block_count):
            self._direction_block(block, beta)
        for block in range(self.block_count):
            self._apply_block(block)
        curvature = self._sum(self.curvature_partial)
        alpha = rz / curvature
        for block in range(self.block_count):
            self._update_block(block, alpha)
        return ti.Vector([curvature, self._sum(self.residual_partial)])

    @ti.func
    def _sum(self, partial: ti.template()) -> ti.f64:
        """The blocks' partial sums, in block order."""
        total = ti.f64(0.0)
        ti.loop_config(serialize=True)
        for block in range(self.block_count):
            total += partial[block]
        return total

    @ti.func
    def _free(self, i_p):
        return self.model.particle_inv_mass[i_p] > 0

    @ti.func
    def _operator(self, u: ti.template(), i_p):
        """(A·u)_i: the module docstring's product from the stored blocks, springs in gather
        order."""
        model = self.model
        u_i = u[i_p]
        result = model.particle_mass[i_p] * u_i
        if ti.static(self.has_local_blocks):
            result = self.local_block[i_p] @ u_i
        for k in range(model.particle_spring_start[i_p], model.particle_spring_start[i_p + 1]):
            relative = u_i - u[model.particle_neighbor[k]]
            n = self.spring_block[k].direction
            result += self.spring_block[k].axial * n.dot(relative) * n \
                + self.spring_block[k].isotropic * relative
        return result

    @ti.func
    def _block_range(self, block):
        return block * DOT_BLOCK, ti.min((block + 1) * DOT_BLOCK, self.model.particle_count)

    @ti.func
    def _guess_block(self, block):
        """A·δ₀ into ``product`` for the block's free particles (δ₀ in ``delta_v``); the block's
        parts of the cold start's r₀·P⁻¹r₀ (r₀ = S·rhs), of (A·δ₀)·P⁻¹r₀ and of
        (A·δ₀)·P⁻¹(A·δ₀)."""
        cold, along, length_sq = ti.f64(0.0), ti.f64(0.0), ti.f64(0.0)
        first, last = self._block_range(block)
        for i_p in range(first, last):
            if self._free(i_p):
                preconditioned_rhs = self.rhs[i_p] * self.inverse_diagonal[i_p]
                product = self._operator(self.delta_v, i_p)
                self.product[i_p] = product
                cold += ti.cast(self.rhs[i_p].dot(preconditioned_rhs), ti.f64)
                along += ti.cast(product.dot(preconditioned_rhs), ti.f64)
                length_sq += ti.cast(product.dot(product * self.inverse_diagonal[i_p]), ti.f64)
        self.cold_partial[block] = cold
        self.guess_partial[block] = along
        self.guess_length_partial[block] = length_sq

    @ti.func
    def _guess_scale(self) -> ti.f64:
        """s = (A·δ₀)·P⁻¹r₀ / (A·δ₀)·P⁻¹(A·δ₀): the start δ = s·δ₀ with the least r·P⁻¹r, the
        norm of the stopping test, so it never starts further from stopping than δ = 0 does;
        0 without a usable δ₀ (none, or not finite)."""
        along = self._sum(self.guess_partial)
        length_sq = self._sum(self.guess_length_partial)
        scale = ti.f64(0.0)
        if finite(along) and finite(length_sq) and length_sq > 0:
            scale = along / length_sq
        return scale

    @ti.func
    def _start_block(self, block, scale):
        """For the block's particles: δ = s·δ₀, r = S·(rhs − s·A·δ₀), z = P⁻¹·r and p = 0 (the
        first direction is then z); the block's part of r·z."""
        real = self.model.real
        s = ti.cast(scale, real)
        total = ti.f64(0.0)
        first, last = self._block_range(block)
        for i_p in range(first, last):
            r = ti.Vector.zero(real, 3)
            z = ti.Vector.zero(real, 3)
            if self._free(i_p):
                initial = ti.Vector.zero(real, 3)
                r = self.rhs[i_p]
                if scale != 0:
                    initial = s * self.delta_v[i_p]
                    r -= s * self.product[i_p]
                self.delta_v[i_p] = initial
                z = r * self.inverse_diagonal[i_p]
                total += ti.cast(r.dot(z), ti.f64)
            self.residual[i_p] = r
            self.preconditioned[i_p] = z
            self.direction[i_p] = ti.Vector.zero(real, 3)
        self.residual_partial[block] = total

    @ti.func
    def _direction_block(self, block, beta):
        """p = S·(z + β·p) for the block's particles (z and p stay 0 on pinned ones)."""
        b = ti.cast(beta, self.model.real)
        first, last = self._block_range(block)
        for i_p in range(first, last):
            if self._free(i_p):
                self.direction[i_p] = self.preconditioned[i_p] + b * self.direction[i_p]

    @ti.func
    def _apply_block(self, block):
        """A·p into ``product`` for the block's free particles; the block's part of p·A·p."""
        total = ti.f64(0.0)
        first, last = self._block_range(block)
        for i_p in range(first, last):
            if self._free(i_p):
                product = self._operator(self.direction, i_p)
                self.product[i_p] = product
                total += ti.cast(self.direction[i_p].dot(product), ti.f64)
        self.curvature_partial[block] = total

    @ti.func
    def _update_block(self, block, alpha):
        """δ += α·p, r −= α·A·p, z = P⁻¹·r for the block's free particles; the block's part of
        r·z."""
        a = ti.cast(alpha, self.model.real)
        total = ti.f64(0.0)
        first, last = self._block_range(block)
        for i_p in range(first, last):
            if self._free(i_p):
                self.delta_v[i_p] += a * self.direction[i_p]
                r = self.residual[i_p] - a * self.product[i_p]
                z = r * self.inverse_diagonal[i_p]
                self.residual[i_p] = r
                self.preconditioned[i_p] = z
                total += ti.cast(r.dot(z), ti.f64)
        self.residual_partial[block] = total

    @ti.kernel
    def _start_candidate(self, state: ti.template(), t: ti.f64, dt: ti.f64):
        """(x₀, v₀) = the state, kept in ``start`` (so that only this kernel is compiled once per
        state); v_c = v₀ and x_c = x₀ + h·v₀; pinned particles at their targets at t + h."""
        model = self.model
        h = ti.cast(dt, model.real)
        for i_p in state.x:
            self.start.x[i_p], self.start.v[i_p] = state.x[i_p], state.v[i_p]
            if model.particle_inv_mass[i_p] == 0:
                self.candidate.x[i_p], self.candidate.v[i_p] = self.control.pin_target(i_p, t + dt)
            else:
                self.candidate.v[i_p] = state.v[i_p]
                self.candidate.x[i_p] = state.x[i_p] + h * state.v[i_p]

    @ti.kernel
    def _prepare(self, t: ti.f64, dt: ti.f64, last_weight: ti.f64, older_weight: ti.f64):
        """rhs = h·f(x_c, v_c, t + h) − M·(v_c − v₀), A's blocks at the candidate, and the
        start δ₀ = w₁·Δv₁ + w₂·Δv₂ on the free particles (0 elsewhere; ``_start_weights``)."""
        model = self.model
        forces = self.forces
        candidate = self.candidate
        h = ti.cast(dt, model.real)
        time = ti.cast(t + dt, model.real)  # backward Euler: forces at the step's end time
        w_last, w_older = ti.cast(last_weight, model.real), ti.cast(older_weight, model.real)
        forces.prepare(candidate.x, candidate.v, t + dt)
        for i_p in candidate.x:
            force = forces.particle_force(candidate.x, candidate.v, i_p, time)
            self.rhs[i_p] = h * force \
                - model.particle_mass[i_p] * (candidate.v[i_p] - self.start.v[i_p])
            self._blocks(i_p, h, time)
            guess = ti.Vector.zero(model.real, 3)
            if self._free(i_p) and last_weight != 0:
                guess = w_last * self.last_change[i_p]
                if older_weight != 0:
                    guess += w_older * self.older_change[i_p]
            self.delta_v[i_p] = guess

    @ti.func
    def _blocks(self, i_p, h, time):
        """Particle i_p's part of A at the candidate (module docstring): n, a and b of each of
        its gather entries, its own block L_i, and 1/diag(A)_i for the preconditioner."""
        model = self.model
        x, v = ti.static(self.candidate.x, self.candidate.v)
        real = model.real
        spring_diagonal = ti.Vector.zero(real, 3)
        for k in range(model.particle_spring_start[i_p], model.particle_spring_start[i_p + 1]):
            _, n, stiffness_axial, stiffness_isotropic, damping = self.forces.spring_axis(
                x, i_p, k, True)
            axial = h * h * stiffness_axial + h * damping
            isotropic = h * h * stiffness_isotropic
            self.spring_block[k].direction = n
            self.spring_block[k].axial = axial
            self.spring_block[k].isotropic = isotropic
            spring_diagonal += axial * n * n + isotropic
        own_diagonal = ti.Vector.zero(real, 3) + model.particle_mass[i_p]
        if ti.static(self.has_local_blocks):
            local = model.particle_mass[i_p] * ti.Matrix.identity(real, 3)
            effects = self.forces.jacobian_effects
            for e in ti.static(range(len(effects))):
                stiffness_block, damping_block = effects[e].local_jacobian(
                    model, x, v, i_p, time, True)
                local -= h * damping_block + h * h * stiffness_block
            self.local_block[i_p] = local
            own_diagonal = ti.Vector([local[c, c] for c in ti.static(range(3))])
        self.inverse_diagonal[i_p] = 1.0 / (spring_diagonal + own_diagonal)

    @ti.kernel
    def _accept(self, dt: ti.f64, last_newton: ti.i32):
        """v_c += δ, x_c = x₀ + h·v_c for the free particles; after the last Newton iteration the
        step's change v_c − v₀ becomes Δv₁ of the warm start (and Δv₁ becomes Δv₂)."""
        model = self.model
        h = ti.cast(dt, model.real)
        for i_p in self.candidate.x:
            if self._free(i_p):
                self.candidate.v[i_p] += self.delta_v[i_p]
                self.candidate.x[i_p] = self.start.x[i_p] + h * self.candidate.v[i_p]
                if last_newton:
                    self.older_change[i_p] = self.last_change[i_p]
                    self.last_change[i_p] = self.candidate.v[i_p] - self.start.v[i_p]

    @ti.kernel
    def evaluate_operator(self, u: ti.template(), out: ti.template()):
        """A·u for every particle, from the blocks of the last ``_prepare`` (for tests and
        diagnostics)."""
        for i_p in u:
            out[i_p] = self._operator(u, i_p)

    @ti.kernel
    def _post_step(self, state: ti.template(), t: ti.f64):
        self.post_step.apply(state, t)
