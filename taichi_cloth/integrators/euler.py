"""Explicit Euler and symplectic ("FB") Euler (seed §2.5.1 and §2.5.2).

Both take one force evaluation per step, a = M⁻¹ F(x_n, v_n, t_n), and differ only in which
velocity moves the positions:

    explicit Euler:   x_{n+1} = x_n + h·v_n,       v_{n+1} = v_n + h·a
    symplectic Euler: v_{n+1} = v_n + h·a,         x_{n+1} = x_n + h·v_{n+1}

(the seed's §2.5.2 listing prints v(t) in the position update, but its text says the position
uses the *future* velocity: that is the symplectic method implemented here; cf. PositionBasedDynamics
``TimeIntegration.h``). A step reads only ``state_in`` and writes only ``state_out``, so the
force gather and the update fuse into one loop over the particles. Pinned particles (inverse mass
0) take their pin target at t + h.

On a grid cloth (``forces.has_grid``) a substep is one loop over the packed groups: the SIMD
spring pass of a group, then the update of its particles, then their new state packed into the
other packed copy (on a periodic grid, the groups holding wrapped columns are packed after the
loop, when every column is done). The packed state is thus carried from substep to substep and
packed from the state only once per launch (``begin_launch``), or again after every projection
pass (``post_step`` moves particles behind the update's back). One loop per substep instead of
three (pack, springs, update) saves two thread-pool hand-offs of ~40 µs each on this machine.
"""

import taichi as ti

from ..model import SIMD_LANES
from .base import Integrator


@ti.data_oriented
class EulerStep(Integrator):
    """One force evaluation, then one update; ``uses_new_velocity`` picks the variant."""

    uses_new_velocity = False
    packs_springs = True

    @ti.func
    def begin_launch(self, state):
        if ti.static(self.forces.has_grid):
            self.forces.pack(state.x, state.v, 0)

    @ti.func
    def substep(self, state_in, state_out, t, dt, buffer):
        """One step from state_in (packed copy ``buffer`` on a grid) at t [s] into state_out."""
        forces = self.forces
        if ti.static(forces.has_grid):
            grid = self.model.grid
            forces.prepare_effects(t)
            if ti.static(self.has_post_step):
                forces.pack(state_in.x, state_in.v, buffer)
            for row, group in ti.ndrange(grid.rows, ti.static(forces.filled_groups)):
                forces.group_springs(buffer, row, group)
                first_column = (group - 1) * SIMD_LANES
                for i_p in range(row * grid.columns + first_column,
                                 row * grid.columns + ti.min(first_column + SIMD_LANES,
                                                             grid.columns)):
                    self._update(state_in, state_out, i_p, t, dt)
                if ti.static(not grid.periodic) or group <= forces.last_own_group:
                    forces.pack_group(state_out.x, state_out.v, 1 - buffer, row, group)
            if ti.static(grid.periodic):  # wrapped columns come from other groups' updates
                forces.pack_halo(state_out.x, state_out.v, 1 - buffer)
        else:
            forces.prepare(state_in.x, state_in.v, t)
            for i_p in range(self.model.particle_count):
                self._update(state_in, state_out, i_p, t, dt)

    @ti.func
    def _update(self, state_in, state_out, i_p, t, dt):
        """Particle i_p's new (x, v) from its force at (state_in, t), after ``prepare``."""
        model = self.model
        x, v, x_out, v_out = ti.static(state_in.x, state_in.v, state_out.x, state_out.v)
        h = ti.cast(dt, model.real)
        inv_mass = model.particle_inv_mass[i_p]
        if inv_mass == 0:
            x_out[i_p], v_out[i_p] = model.pin_target(i_p, t + dt)
        else:
            acceleration = inv_mass * self.forces.particle_force(x, v, i_p, ti.cast(t, model.real))
            v_new = v[i_p] + h * acceleration
            if ti.static(self.uses_new_velocity):
                x_out[i_p] = x[i_p] + h * v_new
            else:
                x_out[i_p] = x[i_p] + h * v[i_p]
            v_out[i_p] = v_new


class ExplicitEuler(EulerStep):
    """x and v both from the old state: energy of an undamped oscillator grows by 1 + (ωh)²."""

    name = "euler"
    uses_new_velocity = False


class SymplecticEuler(EulerStep):
    """v first, then x with the new v: stable for ωh < 2 on an undamped oscillator."""

    name = "symplectic"
    uses_new_velocity = True
