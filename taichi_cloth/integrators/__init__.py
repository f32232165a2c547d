"""Integrators by name. Each has ``step(state_in, state_out, t, dt)`` and never computes forces
itself: it calls ``Forces.particle_force`` (DESIGN.md)."""

from .euler import ExplicitEuler, SymplecticEuler
from .rk4 import RungeKutta4

INTEGRATORS = {cls.name: cls for cls in (ExplicitEuler, SymplecticEuler, RungeKutta4)}


def make_integrator(name: str, forces, post_step=None):
    """The integrator called ``name`` for these forces (``post_step``: see ``base.Integrator``)."""
    return INTEGRATORS[name](forces, post_step)
