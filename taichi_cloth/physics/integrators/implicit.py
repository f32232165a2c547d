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

    (A·u)_i = L_i·u_i + Σ_k [a_k·(n_k·(u_i − u_j))·n_k + b_k·(u_i − u_j)]
              − Σ_coupled [h·(D·u)_i + h²·(K·u)_i]                             (A in kg),

the last sum over the effects with ``has_coupled_jacobian`` (bending: constant blocks, taken
from the effect at the stored step ``coupled_step``).

The system is solved by preconditioned conjugate gradients (``conjugate_gradient.py``).

Warm start: the first Newton iteration of a step starts CG from δ₀ = Δv₁·h/h₁, the last step's
velocity change per its step h₁ times this one's (``_start_weight``), scaled by the s that
minimises the starting r·P⁻¹r (``_guess_scale``: never further from the stopping test than
δ = 0). The stopping test stays relative to the cold start's r₀·P⁻¹r₀ = (S·rhs)·P⁻¹(S·rhs), so
a solve stops at the same residual as from 0 (a checkpoint keeps the history: ``memory``).
docs/performance.md has what the warm start saves.
"""

import numpy as np
import taichi as ti

from taichi_cloth.physics.integrators.base import Integrator, made_before
from taichi_cloth.physics.integrators.conjugate_gradient import (
    CONVERGED, SOLVE_REPORT, UNCONVERGED, BlockConjugateGradient)
from taichi_cloth.physics.integrators.gauss_seidel import GaussSeidelSweeps
from taichi_cloth.physics.model import State


@ti.data_oriented
class BackwardEuler(GaussSeidelSweeps, BlockConjugateGradient, Integrator):
    name = "implicit"
    uses_jacobian = True
    substep_batch = 1

    def __init__(self, forces, control, post_step=None, tolerance: float = 1e-3,
                 max_iterations: int = 500, newton_iterations: int = 1, warm_start: bool = True,
                 gauss_seidel: bool = True):
        """tolerance: relative preconditioned residual √(r·P⁻¹r / r₀·P⁻¹r₀) at which CG stops
        (r₀ the residual of the cold start δ = 0); warm_start: start each step's first solve from
        the last step's velocity change (module docstring); gauss_seidel: precondition by
        symmetric block Gauss–Seidel where the solve runs on one thread (``serial``), else by
        block Jacobi (``conjugate_gradient.py``)."""
        super().__init__(forces, control, post_step)
        self.gauss_seidel = gauss_seidel and self.serial
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
        # v₁ − v₀ of the last step [m/s] and its step [s] (0: no step yet)
        self.last_change = ti.Vector.field(3, real, n)
        self.last_dt = 0.0
        self._allocate_solver(n, model.particle_neighbor.shape[0], real, self.has_local_blocks)
        if self.gauss_seidel:
            self._allocate_sweeps()
        self.step_iterations = []  # CG iterations of each step since the last ``take_iterations``
        self.unconverged_steps = 0

    @property
    def steps_in_one_launch(self) -> bool:
        """Whether a step is one launch (``_serial_step``: ~0.7 ms a step less on ``hula``)."""
        return self.serial and self.newton_iterations == 1

    def memory(self) -> dict:
        """The warm start's history (the last step's velocity change and its step) and the
        count of unconverged steps so far."""
        return {"last_change": self.last_change.to_numpy(),
                "last_dt": np.array(self.last_dt, np.float64),
                "unconverged_steps": np.array(self.unconverged_steps)}

    def solver_report(self, iterations: list[int]) -> dict:
        """CG's tolerance and iteration cap, its iterations per step (mean, most) and the steps
        that did not converge, for ``stats.json`` (nothing before a step)."""
        if not iterations:
            return {}
        return {"cg": {"tolerance": self.tolerance, "max_iterations": self.max_iterations,
                       "iterations_mean": float(np.mean(iterations)),
                       "iterations_max": int(np.max(iterations)),
                       "unconverged_steps": self.unconverged_steps}}

    def restore_memory(self, memory: dict) -> None:
        """``memory``'s history back; a checkpoint written before the warm start took one step
        has no ``last_dt``: its next step starts cold."""
        self.last_change.from_numpy(memory["last_change"])
        self.last_dt = float(memory.get("last_dt", 0.0))
        self.unconverged_steps = int(memory["unconverged_steps"])

    def take_iterations(self) -> list[int]:
        """CG iterations per step since the last call."""
        taken, self.step_iterations = self.step_iterations, []
        return taken

    def launch(self, state_a: State, state_b: State, t: float, dt: float, count: int):
        """``count`` steps (``step``), each its own launches."""
        for k in range(count):
            self.step(state_a, state_b, t + k * dt, dt)
            state_a, state_b = state_b, state_a
        return state_a, state_b

    def step(self, state_in: State, state_out: State, t: float, dt: float) -> None:
        """One backward Euler step by ``newton_iterations`` Newton iterations; the CG
        iterations of the step are recorded. Where ``steps_in_one_launch``, one launch
        (``_serial_step``), else one per pass (the Newton and CG loops in Python)."""
        if self.steps_in_one_launch:
            first, second = (state_in, state_out) if made_before(state_in, state_out) \
                else (state_out, state_in)
            iterations = self._take_report(self._serial_step(
                first, second, int(first is state_out), t, dt, self._start_weight(dt),
                self.tolerance ** 2, self.max_iterations))
        else:
            self._start_candidate(state_in, t, dt)
            iterations = 0
            for newton in range(self.newton_iterations):
                self._prepare(t, dt, self._start_weight(dt) if newton == 0 else 0.0)
                iterations += self._solve()
                self._accept(state_out, dt, newton == self.newton_iterations - 1)
        self.last_dt = dt
        self.step_iterations.append(iterations)
        if self.has_post_step:
            self._post_step(state_out, t + dt)

    def _start_weight(self, dt: float) -> float:
        """w of the warm start δ₀ = w·Δv₁: the last step's acceleration Δv₁/h₁ times this step
        h, 0 before the first step (or cold). Extrapolating linearly from the last two steps
        instead took more CG iterations (docs/performance.md)."""
        if not self.warm_start or self.last_dt == 0:
            return 0.0
        return dt / self.last_dt

    @ti.kernel
    def _serial_step(self, first: ti.template(), second: ti.template(), into_first: ti.i32,
                     t: ti.f64, dt: ti.f64, start_weight: ti.f64, tolerance_sq: ti.f64,
                     max_iterations: ti.i32) -> SOLVE_REPORT:
        """One step (one Newton iteration) in one launch, on one thread: from ``first`` into
        ``second`` (into_first = 0) or from ``second`` into ``first`` (1), both holding the
        new state afterwards (one kernel, whichever way the step goes). Taichi runs the
        serial passes as one task; a parallel pass (self-collision's walks) stays a task of
        its own. Returns the solve's (outcome, iterations, p·A·p, r·z); after a solve that
        broke down, nothing is accepted."""
        if into_first == 1:  # loops under a branch run serially
            self._copy_state(second, first)
        self._take_start(first, t, dt)
        self._prepare_candidate(t, dt, start_weight)
        solve = self._solve_on_one_thread(tolerance_sq, max_iterations)
        if solve[0] == CONVERGED or solve[0] == UNCONVERGED:
            self._accept_candidate(first, dt, 1)
            self._copy_state(first, second)
        return solve

    @ti.kernel
    def _start_candidate(self, state: ti.template(), t: ti.f64, dt: ti.f64):
        """``_take_start`` in a launch of its own (compiled once per state)."""
        self._take_start(state, t, dt)

    @ti.func
    def _take_start(self, state, t, dt):
        """(x₀, v₀) = the state, kept in ``start``; v_c = v₀ and x_c = x₀ + h·v₀; pinned
        particles at their targets at t + h."""
        model = self.model
        h = ti.cast(dt, model.real)
        ti.loop_config(serialize=ti.static(self.serial))
        for i_p in range(model.particle_count):
            self.start.x[i_p], self.start.v[i_p] = state.x[i_p], state.v[i_p]
            if model.particle_inv_mass[i_p] == 0:
                self.candidate.x[i_p], self.candidate.v[i_p] = self.control.pin_target(i_p, t + dt)
            else:
                self.candidate.v[i_p] = state.v[i_p]
                self.candidate.x[i_p] = state.x[i_p] + h * state.v[i_p]

    @ti.kernel
    def _prepare(self, t: ti.f64, dt: ti.f64, start_weight: ti.f64):
        """``_prepare_candidate`` in a launch of its own."""
        self._prepare_candidate(t, dt, start_weight)

    @ti.func
    def _prepare_candidate(self, t, dt, start_weight):
        """rhs = h·f(x_c, v_c, t + h) − M·(v_c − v₀), A's blocks at the candidate, and the
        start δ₀ = w·Δv₁ on the free particles (0 elsewhere; ``_start_weight``). Where the
        solve runs on one thread (``serial``) so do the effects' passes and the particle loop:
        each parallel pass would cost a hand-off to the thread pool and back for microseconds
        of work (``Forces.prepare_serially``)."""
        model = self.model
        forces = self.forces
        candidate = self.candidate
        h = ti.cast(dt, model.real)
        time = ti.cast(t + dt, model.real)  # backward Euler: forces at the step's end time
        w = ti.cast(start_weight, model.real)
        if ti.static(self.serial):
            forces.prepare_serially(candidate.x, candidate.v, t + dt)
        else:
            forces.prepare(candidate.x, candidate.v, t + dt)
        self.coupled_step[None] = h
        ti.loop_config(serialize=ti.static(self.serial))
        for i_p in range(model.particle_count):
            force = forces.particle_force(candidate.x, candidate.v, i_p, time)
            self.rhs[i_p] = h * force \
                - model.particle_mass[i_p] * (candidate.v[i_p] - self.start.v[i_p])
            self._blocks(i_p, h, time)
            guess = ti.Vector.zero(model.real, 3)
            if self._free(i_p) and start_weight != 0:
                guess = w * self.last_change[i_p]
            self.delta_v[i_p] = guess

    @ti.func
    def _blocks(self, i_p, h, time):
        """Particle i_p's part of A at the candidate (module docstring): n, a and b of each of
        its gather entries, its own block L_i, A's diagonal block A_ii and its inverse for the
        preconditioners, and for Gauss–Seidel its row's off-diagonal blocks in the sweeps' order
        (``GaussSeidelSweeps._sweep_blocks``)."""
        model = self.model
        x, v = ti.static(self.candidate.x, self.candidate.v)
        real = model.real
        diagonal_block = ti.Matrix.zero(real, 3, 3)
        for k in range(model.particle_spring_start[i_p], model.particle_spring_start[i_p + 1]):
            _, n, stiffness_axial, stiffness_isotropic, damping = self.forces.spring_axis(
                x, i_p, k, True)
            axial = h * h * stiffness_axial + h * damping
            isotropic = h * h * stiffness_isotropic
            self.spring_block[k].direction = n
            self.spring_block[k].axial = axial
            self.spring_block[k].isotropic = isotropic
            diagonal_block += axial * n.outer_product(n) \
                + isotropic * ti.Matrix.identity(real, 3)
        own_block = model.particle_mass[i_p] * ti.Matrix.identity(real, 3)
        if ti.static(self.has_local_blocks):
            local = model.particle_mass[i_p] * ti.Matrix.identity(real, 3)
            effects = self.forces.jacobian_effects
            for e in ti.static(range(len(effects))):
                stiffness_block, damping_block = effects[e].local_jacobian(
                    model, x, v, i_p, time, True)
                local -= h * damping_block + h * h * stiffness_block
            self.local_block[i_p] = local
            own_block = local
        coupled = self.forces.coupled_effects
        for e in ti.static(range(len(coupled))):
            stiffness, damping = coupled[e].coupled_diagonal(model, i_p)
            own_block -= (h * damping + h * h * stiffness) * ti.Matrix.identity(real, 3)
        self.block[i_p] = diagonal_block + own_block
        self.inverse_block[i_p] = self.block[i_p].inverse()
        if ti.static(self.gauss_seidel):
            self._sweep_blocks(i_p, h)

    @ti.kernel
    def _accept(self, state: ti.template(), dt: ti.f64, last_newton: ti.i32):
        """``_accept_candidate`` in a launch of its own (compiled once per state)."""
        self._accept_candidate(state, dt, last_newton)

    @ti.func
    def _accept_candidate(self, state, dt, last_newton):
        """v_c += δ, x_c = x₀ + h·v_c for the free particles, the candidate into ``state``;
        after the last Newton iteration the step's change v_c − v₀ becomes Δv₁ of the warm
        start."""
        model = self.model
        h = ti.cast(dt, model.real)
        ti.loop_config(serialize=ti.static(self.serial))
        for i_p in range(model.particle_count):
            if self._free(i_p):
                self.candidate.v[i_p] += self.delta_v[i_p]
                self.candidate.x[i_p] = self.start.x[i_p] + h * self.candidate.v[i_p]
                if last_newton:
                    self.last_change[i_p] = self.candidate.v[i_p] - self.start.v[i_p]
            state.x[i_p], state.v[i_p] = self.candidate.x[i_p], self.candidate.v[i_p]

    @ti.kernel
    def _post_step(self, state: ti.template(), t: ti.f64):
        self.post_step.apply(state, t)
