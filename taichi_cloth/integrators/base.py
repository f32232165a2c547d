"""What every integrator shares: running substeps, several per kernel launch.

A Python call of a Taichi kernel costs tens of microseconds, more than a small cloth's whole
substep. An integrator therefore writes its substep as a ``@ti.func`` of top-level parallel loops,
and ``_advance`` unrolls ``count`` of them in one kernel with ``ti.static`` (each unrolled loop
stays a parallel loop), alternating the two states: substep k reads ``a`` and writes ``b`` when k
is even, the reverse when odd. An optional ``post_step`` (the contact projection) runs after each.
"""

import taichi as ti

from ..forces import Forces


@ti.data_oriented
class Integrator:
    """Base of the integrators: subclasses define ``substep(state_in, state_out, t, dt)``."""

    name = ""
    substep_batch = 4  # substeps per kernel launch; fewer where a substep is long (compile time)

    def __init__(self, forces: Forces, post_step=None):
        """post_step: an object with a ``@ti.func apply(state, t)`` run after every substep."""
        self.forces = forces
        self.model = forces.model
        self.post_step = post_step
        self.has_post_step = post_step is not None

    def step(self, state_in, state_out, t: float, dt: float) -> None:
        """One substep from state_in at time t [s] into state_out."""
        self._advance(state_in, state_out, t, dt, 1)

    def advance(self, state_a, state_b, t: float, dt: float, count: int):
        """``count`` substeps from state_a at time t; returns (newest state, the other one)."""
        self._advance(state_a, state_b, t, dt, count)
        return (state_b, state_a) if count % 2 else (state_a, state_b)

    @ti.kernel
    def _advance(self, a: ti.template(), b: ti.template(), t: ti.f64, dt: ti.f64,
                 count: ti.template()):
        for k in ti.static(range(count)):
            if ti.static(k % 2 == 0):
                self._substep_and_post(a, b, t + k * dt, dt)
            else:
                self._substep_and_post(b, a, t + k * dt, dt)

    @ti.func
    def _substep_and_post(self, state_in, state_out, t, dt):
        self.substep(state_in, state_out, t, dt)
        if ti.static(self.has_post_step):
            self.post_step.apply(state_out, t + dt)
