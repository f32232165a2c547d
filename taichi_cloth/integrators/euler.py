"""Explicit Euler and symplectic ("FB") Euler (seed §2.5.1 and §2.5.2).

Both take one force evaluation per step, a = M⁻¹ F(x_n, v_n, t_n), and differ only in which
velocity moves the positions:

    explicit Euler:   x_{n+1} = x_n + h·v_n,       v_{n+1} = v_n + h·a
    symplectic Euler: v_{n+1} = v_n + h·a,         x_{n+1} = x_n + h·v_{n+1}

(the seed's §2.5.2 listing prints v(t) in the position update, but its text says the position
uses the *future* velocity: that is the symplectic method implemented here; cf. PositionBasedDynamics
``TimeIntegration.h``). A step reads only ``state_in`` and writes only ``state_out``, so after
``Forces.prepare`` the force gather and the update fuse into one loop over the particles. Pinned
particles (inverse mass 0) take their pin target at t + h.
"""

import taichi as ti

from .base import Integrator


@ti.data_oriented
class EulerStep(Integrator):
    """One force evaluation, then one update; ``uses_new_velocity`` picks the variant."""

    uses_new_velocity = False
    packs_springs = True

    @ti.func
    def substep(self, state_in, state_out, t, dt):
        model = self.model
        x, v, x_out, v_out = ti.static(state_in.x, state_in.v, state_out.x, state_out.v)
        h = ti.cast(dt, model.real)
        time = ti.cast(t, model.real)
        self.forces.prepare(x, v, t)
        for i_p in range(model.particle_count):
            inv_mass = model.particle_inv_mass[i_p]
            if inv_mass == 0:
                x_out[i_p], v_out[i_p] = model.pin_target(i_p, t + dt)
            else:
                acceleration = inv_mass * self.forces.particle_force(x, v, i_p, time)
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
