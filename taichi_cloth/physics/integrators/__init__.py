"""Integrators by name. Each is an ``Integrator`` (``base.py``: ``step``, ``advance`` and the
launch splitting) and never computes forces itself: it calls ``Forces.particle_force`` (and the
Jacobian products, for the implicit one)."""

from taichi_cloth.physics.integrators.euler import ExplicitEuler, SymplecticEuler
from taichi_cloth.physics.integrators.implicit import BackwardEuler
from taichi_cloth.physics.integrators.rk4 import RungeKutta4

INTEGRATORS = {cls.name: cls for cls in (ExplicitEuler, SymplecticEuler, RungeKutta4,
                                         BackwardEuler)}


def make_integrator(name: str, forces, control, post_step=None, settings=None):
    """The integrator called ``name`` for these forces and this prescribed motion
    (``physics.control.Control``); ``post_step``: see ``base.Integrator``; ``settings``: the
    scene's ``[simulation]``, for the implicit solver's tolerance."""
    if name == BackwardEuler.name and settings is not None:
        return BackwardEuler(forces, control, post_step, settings.cg_tolerance,
                             settings.cg_max_iterations, settings.newton_iterations)
    return INTEGRATORS[name](forces, control, post_step)
