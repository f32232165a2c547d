"""What every integrator shares: running substeps, several per kernel launch.

A Python call of a Taichi kernel costs tens of microseconds, more than a small cloth's whole
substep, and every parallel loop costs a hand-off to the thread pool and back. An integrator
therefore writes its substep as a ``@ti.func`` of loops (``Forces.prepare``'s passes, then its
particle updates) and runs many per launch, in one of two ways:

- parallel (large cloth): ``_advance`` unrolls ``substep_batch`` substeps with ``ti.static``, each
  loop a parallel loop over the particles;
- serial (cloth of at most ``serial_particle_limit`` particles, where the hand-offs cost more
  than a second core gains): ``_advance_serial`` runs a frame's substeps in as few launches as
  keep each under ``SERIAL_LAUNCH_WORK`` particle-substeps (a fraction of a second: Ctrl-C and
  SIGTERM are honoured between launches), a serial loop over substeps around serial particle
  loops, on one thread.

In a parallel launch substep k reads state ``a`` and writes ``b`` when k is even, the reverse
when odd; a serial launch inlines its substep once, from ``a`` into ``b``, and copies ``b`` back
into ``a`` after each (``_advance_serial``). Each substep is also told ``k % 2``, the packed
copy (``PackedGrid.pack``) that holds its input when the integrator carries a packed state from
substep to substep, which ``begin_launch`` fills at the start of a launch (and ``end_launch`` may
unpack at its end).
An optional ``post_step`` (the contact projection) runs after each substep.
"""

import taichi as ti

from taichi_cloth.physics.forces import Forces
from taichi_cloth.runtime import runs_on_cpu, without_taichi_passes

# Below this many particles one thread beats two (the measurement behind it is in
# docs/performance.md, "Launch sizes"); an integrator with more work per particle sets its own
# ``serial_particle_limit``.
SERIAL_PARTICLE_LIMIT = 32768
# Particle-substeps per serial launch at most: ~0.05–0.5 s at 1e7–1e8 particle-substeps/s.
SERIAL_LAUNCH_WORK = 5_000_000


def made_before(state_a, state_b) -> bool:
    """Whether state_a's fields were made before state_b's: the order in which a kernel that
    serves both directions takes a pair of states. It is the same in every run of a scene
    (Taichi numbers its SNodes in order; Python's ``id`` is not), so the offline cache holds the
    one kernel a run needs."""
    return state_a.x.snode._id < state_b.x.snode._id


@ti.data_oriented
class Integrator:
    """Base of the integrators. A subclass sets ``name`` and defines ``substep(state_in,
    state_out, t, dt, buffer)``, a ``@ti.func`` (one substep: forces from ``self.forces``, pinned
    particles from ``self.control.pin_target``); it may define ``begin_launch``/``end_launch``,
    and ``memory``/``restore_memory`` for what it carries between steps. Callers use ``step``
    (one substep), ``launch`` (one kernel launch) or ``advance`` (any count)."""

    name = ""
    packs_springs = False  # one force evaluation per substep: worth the SIMD spring pass
    uses_jacobian = False  # whether it asks the effects for their Jacobian blocks
    substep_batch = 2  # parallel substeps per kernel launch (each unrolled copy adds compile time)
    serial_particle_limit = SERIAL_PARTICLE_LIMIT  # cloth this small runs on one thread
    substeps_write_states = True  # False where substeps keep the state in packed lanes
    warm_start = False  # whether a step's solve starts from the last step's (the implicit one)
    # whether the launch kernels compile without Taichi's IR passes (``without_taichi_passes``)
    compiles_without_passes = False

    def __init__(self, forces: Forces, control, post_step=None):
        """control: the prescribed motion (``physics.control.Control``: where pinned particles
        are); post_step: an object with a ``@ti.func apply(state, t)`` run after every
        substep."""
        self.forces = forces
        self.model = forces.model
        self.control = control
        self.post_step = post_step
        self.has_post_step = post_step is not None
        # one thread, a whole frame per launch: on the CPU only (``runtime.runs_on_cpu``); an
        # integrator's own lower limit is for its particle loops, which a force evaluation on
        # one thread (``prepares_on_one_thread``) would leave waiting: then the base's
        limit = self.serial_particle_limit
        if any(effect.prepares_on_one_thread for effect in forces.prepared_effects):
            limit = max(limit, SERIAL_PARTICLE_LIMIT)
        self.serial = self.model.particle_count <= limit and runs_on_cpu()

    def memory(self) -> dict:
        """Host copies of what the integrator carries from step to step besides the state
        (NumPy arrays by name; none here), for a checkpoint."""
        return {}

    def solver_report(self, iterations: list[int]) -> dict:
        """What ``stats.json`` reports of a solver, given its iterations per step: nothing
        here (no solver)."""
        return {}

    def restore_memory(self, memory: dict) -> None:
        """Put back what ``memory`` returned (a resumed run then takes the very same steps)."""

    def launch_counts(self, count: int) -> list[int]:
        """Substeps per kernel launch for ``count`` substeps."""
        if self.serial:
            chunk = max(1, SERIAL_LAUNCH_WORK // self.model.particle_count)
            return [chunk] * (count // chunk) + ([count % chunk] if count % chunk else [])
        batch = self.substep_batch
        return [batch] * (count // batch) + [1] * (count % batch)

    def kernel_variant(self, count: int, state_a, state_b):
        """Which compiled kernel a launch of ``count`` substeps from ``state_a`` runs (the first
        launch of each compiles it). In parallel mode the states are template arguments, so each
        order of the pair is a kernel of its own; the serial kernel orders them itself."""
        return "serial" if self.serial else (count, made_before(state_a, state_b))

    def step(self, state_in, state_out, t: float, dt: float) -> None:
        """One substep from state_in at time t [s] into state_out."""
        self.launch(state_in, state_out, t, dt, 1)

    def launch(self, state_a, state_b, t: float, dt: float, count: int):
        """One kernel launch of ``count`` substeps (an entry of ``launch_counts``) from state_a at
        time t [s]; returns (newest state, the other one)."""
        self._launch(state_a, state_b, t, dt, count)
        return (state_b, state_a) if count % 2 else (state_a, state_b)

    def advance(self, state_a, state_b, t: float, dt: float, count: int):
        """``count`` substeps from state_a at time t, in ``launch_counts`` launches; returns
        (newest state, the other one)."""
        done = 0
        for launch in self.launch_counts(count):
            state_a, state_b = self.launch(state_a, state_b, t + done * dt, dt, launch)
            done += launch
        return state_a, state_b

    def take_iterations(self) -> list[int]:
        """Solver iterations per step since the last call (an iterative solver's; none here)."""
        return []

    def _launch(self, a, b, t: float, dt: float, count: int) -> None:
        with without_taichi_passes(self.compiles_without_passes):
            if not self.serial:
                self._advance(a, b, t, dt, count)
            elif made_before(a, b):  # one compiled kernel per pair, whichever is newest
                self._advance_serial(a, b, t, dt, count, 0)
            else:
                self._advance_serial(b, a, t, dt, count, 1)

    @ti.kernel
    def _advance(self, a: ti.template(), b: ti.template(), t: ti.f64, dt: ti.f64,
                 count: ti.template()):
        self.begin_launch(a)
        for k in ti.static(range(count)):
            if ti.static(k % 2 == 0):
                self._substep_and_post(a, b, t + k * dt, dt, k % 2)
            else:
                self._substep_and_post(b, a, t + k * dt, dt, k % 2)
        if ti.static(count % 2 == 0):
            self.end_launch(a, 0)
        else:
            self.end_launch(b, 1)

    @ti.kernel
    def _advance_serial(self, a: ti.template(), b: ti.template(), t: ti.f64, dt: ti.f64,
                        count: ti.i32, start_in_b: ti.i32):
        """Substeps from a (start_in_b = 0) or from b (1). Each substep goes from a into b and
        (where substeps write the states) b is copied back into a, so the kernel inlines one
        substep, not one per direction (its compile takes half as long: a frame kernel with
        self-collision compiled for ~47 s with two); afterwards a and b both hold the newest
        state where substeps write them, else ``end_launch`` unpacks it into the state that
        the parity of ``count + start_in_b`` names, the one the caller reads."""
        if start_in_b == 1:  # loops under a branch run serially
            self._copy_state(b, a)
        self.begin_launch(a)
        ti.loop_config(serialize=True)
        for k in range(count):
            self._substep_and_post(a, b, t + k * dt, dt, k % 2)
            if ti.static(self.substeps_write_states):
                self._copy_state(b, a)
        if (count + start_in_b) % 2 == 0:
            self.end_launch(a, count % 2)
        else:
            self.end_launch(b, count % 2)

    @ti.func
    def _copy_state(self, source, target):
        """target's positions and velocities := source's (on this thread)."""
        for i_p in range(self.model.particle_count):
            target.x[i_p] = source.x[i_p]
            target.v[i_p] = source.v[i_p]

    @ti.func
    def begin_launch(self, state):
        """What a launch does once before its substeps, from its input state: nothing here."""

    @ti.func
    def end_launch(self, state, buffer):
        """What a launch does once after its substeps, into its newest state (held by packed
        copy ``buffer``): nothing here."""

    @ti.func
    def _substep_and_post(self, state_in, state_out, t, dt, buffer):
        self.substep(state_in, state_out, t, dt, buffer)
        if ti.static(self.has_post_step):
            self.post_step.apply(state_out, t + dt)
