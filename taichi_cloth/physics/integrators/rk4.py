"""Classical fourth-order Runge–Kutta (seed §2.5.3) on the first-order system (x, v).

With a(x, v, t) = M⁻¹ F(x, v, t) and step h:

    k1 = (v_n,            a(x_n, v_n, t))
    k2 = (v_n + h/2·k1v,  a(x_n + h/2·k1x, v_n + h/2·k1v, t + h/2))
    k3 = (v_n + h/2·k2v,  a(x_n + h/2·k2x, v_n + h/2·k2v, t + h/2))
    k4 = (v_n + h·k3v,    a(x_n + h·k3x,   v_n + h·k3v,   t + h))
    (x, v)_{n+1} = (x, v)_n + h/6·(k1 + 2k2 + 2k3 + k4)

Every stage evaluates *all* forces, dampers included, at the stage's own positions and
velocities. The seed's listing evaluates the damping −c·v(t) with the step's starting velocity
in every stage, which drops the method to first order once damping is on; the order test with
damping (docs/physics.md) catches that.

Each stage is ``Forces.prepare`` and one loop over the particles: it gathers forces at the
previous stage state, adds the stage's weighted slope to running sums, and writes the next stage
state into the other stage buffer (the one being evaluated is still read for the neighbours'
forces). Pinned particles take their pin target at t + h.

On one thread (``serial``, the CPU's small cloth) the four stages are one run-time loop over a
table of their fractions and weights, always evaluating the same buffer (the state is copied in,
and each next stage state copied over it): ``Forces.prepare`` is inlined once, not four times,
which matters where it is large (self-collision's list and pairs compiled for 162 s four times
over, docs/performance.md; the gather, inlined in the loop's two branches, is small). A parallel
launch unrolls the four stages instead: a run-time loop around them would be its outermost
loop, and Taichi runs only that one in parallel. RK4 goes parallel above 2,048 particles, not
where an effect's passes take one thread in any launch (``Integrator.__init__``: `walk-dress`
with self-collision compiled for 199 s and stepped 6× slower in parallel).
"""

import taichi as ti

from taichi_cloth.physics.model import State
from taichi_cloth.physics.integrators.base import Integrator


@ti.data_oriented
class RungeKutta4(Integrator):
    name = "rk4"
    substep_batch = 1  # four stages per substep already; unrolling only slows compiles
    # four CSR force passes per substep: two threads pay off early (docs/performance.md)
    serial_particle_limit = 2048

    def __init__(self, forces, control, post_step=None):
        super().__init__(forces, control, post_step)
        n, real = self.model.particle_count, self.model.real
        self.stage = (State(n, real), State(n, real))
        self.sum_x = ti.Vector.field(3, real, n)
        self.sum_v = ti.Vector.field(3, real, n)

    @ti.func
    def substep(self, state_in, state_out, t, dt, buffer):
        if ti.static(self.serial):
            self._stages_in_loop(state_in, state_out, t, dt)
        else:
            self._stages_unrolled(state_in, state_out, t, dt)

    @ti.func
    def _stages_in_loop(self, start, out, t, dt):
        """The four stages as one serial loop: ``stage[0]`` is evaluated, ``stage[1]`` takes
        the next stage state and is copied back over it."""
        evaluated, following = ti.static(self.stage)
        model = self.model
        self._copy_state(start, evaluated)
        # per stage: fraction of h to its time, weight of its slope, fraction of h to the next
        # stage state (the tableau of the unrolled form below), each literal in its own
        # precision (a bare one is taken in the default precision first)
        stage_fraction = ti.Vector([ti.f64(0.0), ti.f64(0.5), ti.f64(0.5), ti.f64(1.0)])
        weight = ti.Vector([model.real(1.0 / 6.0), model.real(1.0 / 3.0),
                            model.real(1.0 / 3.0), model.real(1.0 / 6.0)])
        next_fraction = ti.Vector([model.real(0.5), model.real(0.5), model.real(1.0),
                                   model.real(0.0)])
        for s in range(4):
            stage_time = t + stage_fraction[s] * dt
            self.forces.prepare(evaluated.x, evaluated.v, stage_time)
            for i_p in range(model.particle_count):
                if s < 3:
                    self._stage_particle(start, evaluated, following, i_p, t, dt, stage_time,
                                         weight[s], next_fraction[s], s == 0, False)
                else:
                    self._stage_particle(start, evaluated, out, i_p, t, dt, stage_time,
                                         weight[s], next_fraction[s], False, True)
            if s < 3:
                self._copy_state(following, evaluated)

    @ti.func
    def _stages_unrolled(self, state_in, state_out, t, dt):
        first, second = ti.static(self.stage)
        # (state evaluated, fraction of h to its time, weight of its slope, fraction of h to the
        #  next stage state, which stage)
        self._stage(state_in, state_in, first, t, 0.0, dt, 1.0 / 6.0, 0.5, 0)
        self._stage(state_in, first, second, t, 0.5, dt, 1.0 / 3.0, 0.5, 1)
        self._stage(state_in, second, first, t, 0.5, dt, 1.0 / 3.0, 1.0, 1)
        self._stage(state_in, first, state_out, t, 1.0, dt, 1.0 / 6.0, 0.0, 2)

    @ti.func
    def _stage(self, start, evaluated, out, t, stage_fraction: ti.template(), dt,
               weight: ti.template(), next_fraction: ti.template(), position: ti.template()):
        """Evaluate at t + stage_fraction·dt. position: 0 first stage (start the sums), 1 middle,
        2 last (write the new state). The fractions and weights are Python floats, baked exactly
        in the model's precision."""
        stage_time = t + ti.f64(stage_fraction) * dt
        self.forces.prepare(evaluated.x, evaluated.v, stage_time)
        for i_p in range(self.model.particle_count):
            self._stage_particle(start, evaluated, out, i_p, t, dt, stage_time,
                                 self.model.real(weight), self.model.real(next_fraction),
                                 position == 0, position == 2)

    @ti.func
    def _stage_particle(self, start, evaluated, out, i_p, t, dt, stage_time, w, c, first, last):
        """Particle i_p's part of a stage evaluated at ``stage_time`` [s]: its slope, weighted
        by w into the running sums (which it starts when ``first``), and its next stage state,
        c·h from the step's ``start``, into ``out`` (when ``last``, its state at t + h)."""
        model = self.model
        h = ti.cast(dt, model.real)
        slope_x = evaluated.v[i_p]
        slope_v = model.particle_inv_mass[i_p] * self.forces.particle_force(
            evaluated.x, evaluated.v, i_p, ti.cast(stage_time, model.real))
        if first:
            self.sum_x[i_p] = w * slope_x
            self.sum_v[i_p] = w * slope_v
        else:
            self.sum_x[i_p] += w * slope_x
            self.sum_v[i_p] += w * slope_v
        if last:
            if model.particle_inv_mass[i_p] == 0:
                out.x[i_p], out.v[i_p] = self.control.pin_target(i_p, t + dt)
            else:
                out.x[i_p] = start.x[i_p] + h * self.sum_x[i_p]
                out.v[i_p] = start.v[i_p] + h * self.sum_v[i_p]
        elif model.particle_inv_mass[i_p] == 0:
            # the next stage sees a moving pin where it really is: a straight line from
            # x_n made the neighbours' anchor O(h²) off and RK4 second order on a dancer
            out.x[i_p], out.v[i_p] = self.control.pin_target(i_p, t + ti.cast(c, ti.f64) * dt)
        else:
            out.x[i_p] = start.x[i_p] + c * h * slope_x
            out.v[i_p] = start.v[i_p] + c * h * slope_v
