"""Conjugate gradients preconditioned by symmetric block Gauss–Seidel, in Eisenstat's form: the
serial solve of ``conjugate_gradient.BlockConjugateGradient`` (one thread runs every row in
order, so the sweeps cost no more than a product with A).

Split the free particles' system matrix into its 3×3 blocks, A = L + D + Lᵀ (D the diagonal
blocks, L the blocks A_ij with j < i) and let W = D + L. Symmetric Gauss–Seidel is the
preconditioner M = W·D⁻¹·Wᵀ (Saad, "Iterative Methods for Sparse Linear Systems", 2nd ed.,
§4.1.2 and §10.2: SSOR at ω = 1). CG with M on A·e = r is CG on the congruent system

    Â·ê = W⁻¹·r,   Â = W⁻¹·A·W⁻ᵀ,   e = W⁻ᵀ·ê,

preconditioned by D⁻¹ (z = D·r̂ for its residual r̂). Eisenstat's trick (S. C. Eisenstat,
"Efficient implementation of a class of preconditioned conjugate gradient methods", SIAM J.
Sci. Stat. Comput. 2(1), 1981) takes the product with Â without A: since A = W + Wᵀ − D,

    Â·p = t + W⁻¹·(p − D·t),   t = W⁻ᵀ·p,

one backward sweep (rows i descending: t_i = D_i⁻¹·(p_i − Σ_{j>i} A_ij·t_j)) and one forward
sweep (rows ascending), which together read each off-diagonal block once, as a product with A
does. The solution is accumulated in the original variables, δ += α·t. On the 64 × 28 cotton
hula at h = 1/60 s the sweeps take CG from 118 to 63 iterations at the same tolerance of 3·10⁻³,
with a smaller error in the energy norm (0.027 against 0.033 of the cold start's;
docs/performance.md).

The sweeps read A's off-diagonal blocks from rows of their own (``gather.sweep_rows``), filled
once per Newton iteration (``_sweep_blocks``): one entry per spring of row i, −(a·n·nᵀ + b·I),
in which the coupled effects' scalar blocks (bending's +(h·β + h²)·H_ij in A) are folded into
the first spring to the same neighbour (b − (h·β + h²)·H_ij), and one entry −b·I for each
neighbour that only a coupled effect reaches (bending's 2-ring). A row's sum then reads each
neighbour once instead of once per list (on ``hula``: 11.6 entries a row instead of 7.8 springs
and 11.6 bending entries).

The stopping test is the base solver's: r̂·z = r·M⁻¹·r, relative to the cold start's
rhs·M⁻¹·rhs. The warm start δ₀ is scaled as there, by the s that minimises the start's r·M⁻¹·r.
Pinned particles are outside the system: their rows are skipped and their entries of every
swept vector stay 0, so their blocks A_ij add nothing to their neighbours' rows.
"""

import taichi as ti

from taichi_cloth.gather import sweep_rows
from taichi_cloth.physics.integrators.conjugate_gradient import finite


@ti.data_oriented
class GaussSeidelSweeps:
    """The sweeps and passes of the Gauss–Seidel solve, for ``BlockConjugateGradient`` (which
    holds the fields: ``block`` (A_ii), ``inverse_block``, ``spring_block``, ``backward`` (t) and
    the base solver's vectors; ``product`` holds the forward sweep's W⁻¹·(p − D·t)), with A's
    off-diagonal blocks of its own in the sweeps' order (``_allocate_sweeps``)."""

    def _allocate_sweeps(self) -> None:
        """The rows of ``gather.sweep_rows`` (the springs with the coupled effects' entries
        folded in) in fields: ``sweep_start``, ``sweep_bounds``, ``sweep_neighbor``,
        ``sweep_spring``, ``sweep_coupled`` (Σ H_ij, Σ β·H_ij), and each entry's block
        ``sweep_block`` = −(a·n·nᵀ + b·I), filled with A's other blocks (``_sweep_blocks``)."""
        model = self.model
        coupled = [effect.coupled_rows() for effect in self.forces.coupled_effects]
        start, bounds, neighbor, spring, sums = sweep_rows(
            model.host_spring_start, model.host_neighbor, coupled, model.particle_count)
        entries = max(1, len(neighbor))
        real = model.real
        self.sweep_start = ti.field(ti.i32, model.particle_count + 1)
        self.sweep_bounds = ti.Vector.field(3, ti.i32, model.particle_count)
        self.sweep_neighbor = ti.field(ti.i32, entries)
        self.sweep_spring = ti.field(ti.i32, entries)
        self.sweep_coupled = ti.Vector.field(2, real, entries)
        self.sweep_block = ti.Struct.field({"direction": ti.types.vector(3, real),
                                            "axial": real, "isotropic": real}, shape=entries)
        rows = [(self.sweep_neighbor, neighbor), (self.sweep_spring, spring),
                (self.sweep_coupled, sums.astype(model.numpy_real))] if len(neighbor) else []
        model.uploads.add([(self.sweep_start, start), (self.sweep_bounds, bounds), *rows])

    @ti.func
    def _sweep_blocks(self, i_p, h):
        """Row i's entries of ``sweep_block`` at the step h [s], from its springs' blocks (in
        ``spring_block``, made first) and the coupled effects' −h·∂f/∂v − h²·∂f/∂x = (h·β + h²)·H:
        b = b_spring − h·Σ β·H_ij − h²·Σ H_ij (a = 0, n = 0 where no spring is folded in)."""
        real = self.model.real
        for s in range(self.sweep_start[i_p], self.sweep_start[i_p + 1]):
            coupled = self.sweep_coupled[s]
            direction = ti.Vector.zero(real, 3)
            axial = ti.cast(0.0, real)
            isotropic = -(h * coupled[1] + h * h * coupled[0])
            k = self.sweep_spring[s]
            if k >= 0:
                direction = self.spring_block[k].direction
                axial = self.spring_block[k].axial
                isotropic += self.spring_block[k].isotropic
            self.sweep_block[s].direction = direction
            self.sweep_block[s].axial = axial
            self.sweep_block[s].isotropic = isotropic

    @ti.func
    def _side_product(self, u: ti.template(), i_p, lower: ti.template()):
        """Σ_j A_ij·u_j over the off-diagonal blocks of row i with j < i (``lower``) or j > i:
        −(a·n·(n·u_j) + b·u_j) over the entries with a spring, −b·u_j over the others."""
        result = ti.Vector.zero(self.model.real, 3)
        bounds = self.sweep_bounds[i_p]
        first, middle, last = self.sweep_start[i_p], bounds[0], bounds[1]
        if ti.static(not lower):
            first, middle, last = bounds[1], bounds[2], self.sweep_start[i_p + 1]
        for s in range(first, middle):
            n = self.sweep_block[s].direction
            u_j = u[self.sweep_neighbor[s]]
            result -= self.sweep_block[s].axial * n.dot(u_j) * n \
                + self.sweep_block[s].isotropic * u_j
        for s in range(middle, last):
            result -= self.sweep_block[s].isotropic * u[self.sweep_neighbor[s]]
        return result

    @ti.func
    def _gauss_seidel_start(self):
        """δ = s·δ₀, r̂ = W⁻¹·(rhs − s·A·δ₀) = c − s·g with c = W⁻¹·rhs and g = W⁻¹·A·δ₀, z = D·r̂,
        p = 0: returns (c·D·c, the cold start's r·M⁻¹·r, and r̂·z of the start taken). Since
        A = W + U (U the blocks above the diagonal), g = δ₀ + W⁻¹·U·δ₀: one forward sweep makes
        c and W⁻¹·U·δ₀ (row i's U·δ₀ reads δ₀ only), with no product with the whole of A."""
        model = self.model
        real = model.real
        cold, along, length_sq = ti.f64(0.0), ti.f64(0.0), ti.f64(0.0)
        ti.loop_config(serialize=True)
        for i_p in range(model.particle_count):  # c into residual, W⁻¹·U·δ₀ into backward
            c = ti.Vector.zero(real, 3)
            swept = ti.Vector.zero(real, 3)
            if self._free(i_p):
                c = self.inverse_block[i_p] @ (self.rhs[i_p]
                                               - self._side_product(self.residual, i_p, True))
                swept = self.inverse_block[i_p] @ (
                    self._side_product(self.delta_v, i_p, False)
                    - self._side_product(self.backward, i_p, True))
                g = self.delta_v[i_p] + swept
                block_c = self.block[i_p] @ c
                cold += ti.cast(c.dot(block_c), ti.f64)
                along += ti.cast(g.dot(block_c), ti.f64)
                length_sq += ti.cast(g.dot(self.block[i_p] @ g), ti.f64)
            self.residual[i_p] = c
            self.backward[i_p] = swept
        scale = ti.f64(0.0)
        if finite(along) and finite(length_sq) and length_sq > 0:
            scale = along / length_sq
        s = ti.cast(scale, real)
        rz = ti.f64(0.0)
        ti.loop_config(serialize=True)
        for i_p in range(model.particle_count):
            if self._free(i_p):
                r = self.residual[i_p] - s * (self.delta_v[i_p] + self.backward[i_p])
                z = self.block[i_p] @ r
                self.delta_v[i_p] = s * self.delta_v[i_p]
                self.residual[i_p] = r
                self.preconditioned[i_p] = z
                rz += ti.cast(r.dot(z), ti.f64)
            self.direction[i_p] = ti.Vector.zero(real, 3)
        return ti.Vector([cold, rz])

    @ti.func
    def _gauss_seidel_iteration(self, rz, beta):
        """One CG iteration on Â (module docstring): p = z + β·p and t = W⁻ᵀ·p in one backward
        sweep (row i's t reads p_i and the t_j of rows j > i only, so each p_i is made as its
        row is reached); q = W⁻¹·(p − D·t) (forward sweep, into ``product``; row i's
        q_i = D_i⁻¹·(p_i − Σ_{j<i} A_ij·q_j) − t_i, one product with a block less than forming
        D_i·t_i), Â·p = t + q; δ += α·t, r̂ −= α·Â·p, z = D·r̂. Returns (p·Â·p, the new r̂·z)."""
        model = self.model
        real = model.real
        n = model.particle_count
        b = ti.cast(beta, real)
        for k in range(n):  # rows descending
            i_p = n - 1 - k
            t = ti.Vector.zero(real, 3)
            if self._free(i_p):
                p = self.preconditioned[i_p] + b * self.direction[i_p]
                self.direction[i_p] = p
                t = self.inverse_block[i_p] @ (p - self._side_product(self.backward, i_p, False))
            self.backward[i_p] = t
        curvature = ti.f64(0.0)
        for i_p in range(n):  # rows ascending
            q = ti.Vector.zero(real, 3)
            if self._free(i_p):
                p, t = self.direction[i_p], self.backward[i_p]
                q = self.inverse_block[i_p] @ (p - self._side_product(self.product, i_p, True)) \
                    - t
                curvature += ti.cast(p.dot(t + q), ti.f64)
            self.product[i_p] = q
        a = ti.cast(rz / curvature, real)
        rz_new = ti.f64(0.0)
        for i_p in range(n):
            if self._free(i_p):
                t = self.backward[i_p]
                self.delta_v[i_p] += a * t
                r = self.residual[i_p] - a * (t + self.product[i_p])
                z = self.block[i_p] @ r
                self.residual[i_p] = r
                self.preconditioned[i_p] = z
                rz_new += ti.cast(r.dot(z), ti.f64)
        return ti.Vector([curvature, rz_new])
