"""Explicit Euler and symplectic ("FB") Euler (seed §2.5.1 and §2.5.2).

Both take one force evaluation per step, a = M⁻¹ F(x_n, v_n, t_n), and differ only in which
velocity moves the positions:

    explicit Euler:   x_{n+1} = x_n + h·v_n,       v_{n+1} = v_n + h·a
    symplectic Euler: v_{n+1} = v_n + h·a,         x_{n+1} = x_n + h·v_{n+1}

(the seed's §2.5.2 listing prints v(t) in the position update, but its text says the position
uses the *future* velocity: that is the symplectic method implemented here; cf. PositionBasedDynamics
``TimeIntegration.h``). A step reads only ``state_in`` and writes only ``state_out``, so the force
gather and the update fuse into one kernel. Pinned particles (inverse mass 0) take their pin
target at t + h.
"""

import taichi as ti

from ..forces import Forces


@ti.data_oriented
class EulerStep:
    """One force evaluation, then one update; ``uses_new_velocity`` picks the variant."""

    uses_new_velocity = False

    def __init__(self, forces: Forces):
        self.forces = forces
        self.model = forces.model

    def step(self, state_in, state_out, t: float, dt: float) -> None:
        """Advance from state_in at time t [s] by dt [s] into state_out."""
        self._step(state_in.x, state_in.v, state_out.x, state_out.v, t, dt)

    @ti.kernel
    def _step(self, x: ti.template(), v: ti.template(), x_out: ti.template(),
              v_out: ti.template(), t: ti.f64, dt: ti.f64):
        model = self.model
        h = ti.cast(dt, model.real)
        time = ti.cast(t, model.real)
        for i_p in x:
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
