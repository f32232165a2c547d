"""Preconditioned conjugate gradients on the implicit step's system A·δ = rhs, matrix-free,
over the blocks of A that ``BackwardEuler._blocks`` stores (``implicit.py`` has the system).

Two preconditioners P, both from A's 3×3 blocks. Where the solve runs on one thread (``serial``,
every CPU run) it is symmetric block Gauss–Seidel in Eisenstat's form (``gauss_seidel.py``: its
sweeps visit the rows in order, so they need the one thread); elsewhere (and for comparison) it
is block Jacobi, A's diagonal blocks (each particle's own block), which the Gauss–Seidel sweeps
also invert. The blocks matter: the springs of a sheet all lie in its plane, so a particle's
block is stiff in the plane and soft across it, a difference the scalar diagonal (in world
axes, which the cloth's normal rarely follows) cannot undo; on the 64 × 28 cotton hula at h =
1/120 s the blocks took CG from 191 to 84 iterations a step on average, and Gauss–Seidel halves
Jacobi's count again. Pinned particles are filtered out of the system as in Baraff & Witkin's
modified CG (§5.3): the candidate holds them at their targets, and the filter S zeroes their
residual, preconditioned residual and direction, so δ = 0 for them.

With block Jacobi each CG iteration is three passes over fixed blocks of ``DOT_BLOCK``
particles: the direction p = z + β·p; A·p with the block's part of p·A·p; δ += α·p, r −= α·A·p
and z = P⁻¹·r with the block's part of r·z. Dot products sum each block in order, then the
blocks in order, so a solve is bit-reproducible whatever the thread count (no racing atomic
float adds). Small cloth (``self.serial``) runs the whole solve, convergence test included, on
one thread within the step's launch (``BackwardEuler._serial_step``); larger cloth launches one
kernel per iteration, each pass a parallel loop over the blocks. With Jacobi both run the same
block functions and take the same steps. Scratch fields are allocated once; ``_serial_step`` is
compiled once per pair of states, ``_start_candidate``, ``_accept`` and ``_post_step`` once per
state.
"""

import math

import taichi as ti

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
class BlockConjugateGradient:
    """The solver half of ``BackwardEuler``: its scratch fields (``_allocate_solver``), the solve
    (``_solve``) and the product with A (``_operator``). The integrator fills ``rhs``,
    ``delta_v`` (the start), ``block`` and ``inverse_block`` (A_ii and its inverse, the Jacobi
    P⁻¹), ``spring_block``, ``local_block`` and
    ``coupled_step`` (the coupled effects' products are taken at it)."""

    def _allocate_solver(self, particle_count: int, gather_count: int, real,
                         has_local_blocks: bool) -> None:
        n = particle_count
        self.rhs = ti.Vector.field(3, real, n)
        self.residual = ti.Vector.field(3, real, n)
        self.preconditioned = ti.Vector.field(3, real, n)
        self.direction = ti.Vector.field(3, real, n)
        self.product = ti.Vector.field(3, real, n)
        self.block = ti.Matrix.field(3, 3, real, n)  # A_ii [kg]
        self.inverse_block = ti.Matrix.field(3, 3, real, n)  # A_ii⁻¹ [1/kg]
        self.backward = ti.Vector.field(3, real, n)  # the Gauss–Seidel backward sweep's t
        self.spring_block = ti.Struct.field({"direction": ti.types.vector(3, real),
                                             "axial": real, "isotropic": real},
                                            shape=gather_count)
        if has_local_blocks:
            self.local_block = ti.Matrix.field(3, 3, real, n)
        self.coupled_step = ti.field(real, ())  # h [s] of the coupled effects' blocks
        self.block_count = math.ceil(n / DOT_BLOCK)
        self.curvature_partial = ti.field(ti.f64, self.block_count)
        self.residual_partial = ti.field(ti.f64, self.block_count)
        self.cold_partial = ti.field(ti.f64, self.block_count)
        self.guess_partial = ti.field(ti.f64, self.block_count)
        self.guess_length_partial = ti.field(ti.f64, self.block_count)

    def _solve(self) -> int:
        """Preconditioned CG for A·δ = rhs on the free particles; returns its iterations."""
        tolerance_sq = self.tolerance ** 2
        if self.serial:
            return self._take_report(self._solve_serial(tolerance_sq, self.max_iterations))
        return self._take_report(self._solve_parallel(tolerance_sq))

    def _take_report(self, report) -> int:
        """The iterations of a solve that ended as ``report`` (outcome, iterations, p·A·p, r·z)
        says, an unconverged one counted in ``unconverged_steps``; ``SolverBreakdown`` for one
        that ended ``NOT_FINITE`` or in ``BREAKDOWN``."""
        outcome, iterations, curvature, rz = report
        iterations = int(iterations)
        if outcome == NOT_FINITE:
            raise SolverBreakdown(f"the right-hand side is not finite (r·z = {rz})")
        if outcome == BREAKDOWN:
            raise SolverBreakdown(f"conjugate gradients broke down at iteration {iterations} "
                                  f"(p·Ap = {curvature:.3g}, r·z = {rz:.3g})")
        self.unconverged_steps += int(outcome == UNCONVERGED)
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
        """``_solve_on_one_thread`` in a launch of its own."""
        return self._solve_on_one_thread(tolerance_sq, max_iterations)

    @ti.func
    def _solve_on_one_thread(self, tolerance_sq, max_iterations):
        """The whole solve, on one thread: returns (outcome, iterations, p·A·p, r·z), the last
        two where it stopped. Stops when r·z ≤ tolerance²·r₀·P⁻¹r₀ (converged), after
        ``max_iterations`` (unconverged), or at a non-finite r·z or a p·A·p that is not
        positive (breakdown)."""
        sums = ti.Vector([0.0, 0.0], ti.f64)
        if ti.static(self.gauss_seidel):
            sums = self._gauss_seidel_start()
        else:
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
                result = ti.Vector([0.0, 0.0], ti.f64)
                if ti.static(self.gauss_seidel):
                    result = self._gauss_seidel_iteration(rz, beta)
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
        coupled = self.forces.coupled_effects
        for e in ti.static(range(len(coupled))):
            h = self.coupled_step[None]
            stiffness, damping = coupled[e].coupled_products(model, u, i_p)
            result -= h * damping + h * h * stiffness
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
                preconditioned_rhs = self.inverse_block[i_p] @ self.rhs[i_p]
                product = self._operator(self.delta_v, i_p)
                self.product[i_p] = product
                cold += ti.cast(self.rhs[i_p].dot(preconditioned_rhs), ti.f64)
                along += ti.cast(product.dot(preconditioned_rhs), ti.f64)
                length_sq += ti.cast(product.dot(self.inverse_block[i_p] @ product), ti.f64)
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
                z = self.inverse_block[i_p] @ r
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
                z = self.inverse_block[i_p] @ r
                self.residual[i_p] = r
                self.preconditioned[i_p] = z
                total += ti.cast(r.dot(z), ti.f64)
        self.residual_partial[block] = total

    @ti.kernel
    def evaluate_operator(self, u: ti.template(), out: ti.template()):
        """A·u for every particle, from the blocks of the last ``_prepare`` (for tests and
        diagnostics)."""
        for i_p in u:
            out[i_p] = self._operator(u, i_p)
