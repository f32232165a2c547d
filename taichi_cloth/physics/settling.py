"""Settling: the garment comes to rest on the body, held still in its pose at t = 0, before
the animation's frame 0 (``simulation.settle`` > 0): kinetic damping with the scene's own
integrator and step, or half of it where the scene's step keeps it moving (``settle``)."""

import math
import time

import numpy as np

from taichi_cloth.cloth.garment import settling_ripple
from taichi_cloth.physics.metrics import RunRecord, largest_stretch_strain

SETTLE_CHECK_INTERVAL = 1.0 / 240.0  # s of settling between two checks of the kinetic energy
# At rest, the largest stretch strain moves by less than this between two checks: on a fine
# mesh a local wave after an impact on the hips (3 % strain on the 128 × 56 cotton hula) hides
# in a mean speed already below settle_speed.
SETTLED_STRAIN_CHANGE = 1e-3
SETTLE_STEP_HALVINGS = 2  # times settling starts again at half the step when not at rest
SETTLE_RETRY_MIN_SECONDS = 1.0  # s: a shorter cap is a budget, not a test of rest


def settle(simulation, run_record: RunRecord) -> dict | None:
    """Let the garment come to rest on the body held still in its pose at t = 0, before
    the animation (the scene's ``simulation.settle`` > 0): ``settle_at`` with the scene's own
    step; where that did not bring it to rest within a cap of at least
    ``SETTLE_RETRY_MIN_SECONDS``, again from the same start at half the step (at most
    ``SETTLE_STEP_HALVINGS`` times), and where a halved step did, the dance takes that step
    too: a garment that keeps moving on a still body at the scene's step moves numerically (a
    light polyester skirt at 64 × 28 under backward Euler at 1/60 s, CG stopped at 0.3 %,
    buzzed at ~0.3 m/s with thousands of triangles through each other; at 1/120 s it hangs
    still: docs/physics.md, "Settling before the dance"). Where no step brings it to rest (a
    motion of its own, such as wind), the run goes on from the scene's step's try, at that
    step. The state is then the run's frame 0. Returns what the kept try did (simulated
    seconds, the mean speed [m/s], whether it came to rest, how many times one of its frames
    was redone at half the step (``retries``)), the settling's step halvings and the dance's
    step ``dt`` [s], and for the implicit integrator the kept try's unconverged CG steps
    (which do not count as the run's), kept as ``simulation.settle_report``, or None when off;
    the tries' compile time goes to ``run_record``'s ``compile``, the rest of their wall time
    to ``settle``. A step halved by the frame guard while settling (for strain; the guard
    keeps a halved step for the rest of a run) says nothing of the dance, whose frames the
    guard checks in turn: kept, it made a silk skirt on the coarse body dance at 1/120 s
    instead of 1/60 s, at twice the cost and with ``retries`` 0 in stats.json. The implicit
    integrator's solves start cold while settling (its warm start is off, and back on for the
    dance): started from the last step's velocity change, CG's stopping error recurs alike from
    step to step on a garment near rest, and a silk skirt at 1/60 s buzzed at 0.1-0.7 m/s
    instead of coming to rest at 3 of 5 CG tolerances around the scene's, against none of 5
    started cold (docs/physics.md, "Settling before the dance")."""
    settings = simulation.scene.simulation
    if settings.settle <= 0:
        return None
    started = time.perf_counter()
    integrator = simulation.integrator
    warm_start = integrator.warm_start
    integrator.warm_start = False  # settling solves from cold (docstring)
    try:
        unconverged_before = getattr(integrator, "unconverged_steps", 0)
        start = simulation.positions()
        chosen = simulation.time_step
        before = simulation.snapshot(effects=True)
        compile_seconds = 0.0
        for halvings in range(SETTLE_STEP_HALVINGS + 1):
            if halvings:
                simulation.restore(before)  # the same start, integrator memory and crossings
            record = RunRecord()
            outcome = settle_at(simulation, start, chosen.dt / 2 ** halvings, record)
            compile_seconds += record.wall_seconds["compile"]
            at_rest = outcome[2]
            if at_rest or settings.settle < SETTLE_RETRY_MIN_SECONDS:
                break
            if halvings == 0:
                first_try = simulation.snapshot(effects=True), outcome, record
        if not at_rest and halvings:  # no step came to rest: the scene's step's try is kept
            snapshot, outcome, record = first_try
            simulation.restore(snapshot)
            halvings = 0
        simulation.set_time_step(chosen.dt / 2 ** halvings,
                                 chosen.substeps_per_frame * 2 ** halvings)
    finally:
        integrator.warm_start = warm_start
    run_record.wall_seconds["compile"] += compile_seconds
    run_record.wall_seconds["settle"] = time.perf_counter() - started - compile_seconds
    simulated, mean_speed, at_rest = outcome
    simulation.settle_report = {"simulated_seconds": simulated, "mean_speed": mean_speed,
                                "at_rest": bool(at_rest), "retries": record.retries,
                                "step_halvings": halvings, "dt": simulation.time_step.dt}
    if hasattr(simulation.integrator, "unconverged_steps"):  # settling's own, not the run's
        simulation.settle_report["unconverged_steps"] = \
            simulation.integrator.unconverged_steps - unconverged_before
        simulation.integrator.unconverged_steps = unconverged_before
    return simulation.settle_report


def settle_at(simulation, start: np.ndarray, dt: float, record: RunRecord) -> tuple:
    """From positions ``start`` [m] at rest, a skirt first given a small ripple
    (``cloth.garment.settling_ripple``: its cone is an unstable equilibrium), steps of dt [s]
    of the scene's integrator with kinetic damping (every velocity zeroed whenever the kinetic
    energy has passed a peak, checked every ``SETTLE_CHECK_INTERVAL`` or step, so that each
    swing ends where it is fastest, near its equilibrium) until the garment is at rest: a
    frame's worth of steps since the last zeroing, after which the free particles' mean speed
    is below the scene's ``settle_speed`` and the largest strain changed by less than
    ``SETTLED_STRAIN_CHANGE`` since the last check; for at most ``settle`` simulated seconds.
    (The unbalanced force is no test of rest: in f32 the rounding of positions alone gives a
    stiff spring a force of k·ε·|x|.) Returns (simulated seconds, the last mean speed [m/s],
    whether at rest); frames redone at half the step count in ``record``."""
    settings = simulation.scene.simulation
    free = ~simulation.garment.pinned
    mass = simulation.model.host_mass
    rippled = start + settling_ripple(simulation.garment) * free[:, None]
    simulation.states.write(simulation.state_in, rippled, np.zeros_like(rippled))
    simulation.forget_crossings()
    steps_per_check = max(1, round(SETTLE_CHECK_INTERVAL / dt))
    checks_per_frame = max(1, round(simulation.frame_duration / (steps_per_check * dt)))
    simulation.set_time_step(dt, steps_per_check)
    previous, since_zeroed, simulated = 0.0, 0, 0.0
    mean_speed, at_rest, strain = math.inf, False, math.inf
    while simulated < settings.settle - 1e-9 and not at_rest:
        simulation.guarded_frame(1, record, still=True)  # may halve the step
        simulation.integrator.take_iterations()
        simulated += simulation.time_step.dt * simulation.time_step.substeps_per_frame
        since_zeroed += 1
        x, v = simulation.host_state()
        speed_sq = np.sum(v * v, axis=1)
        mean_speed = simulation.mean_free_speed(v)
        strain_before = strain
        strain = largest_stretch_strain(simulation.model, x)
        at_rest = since_zeroed >= checks_per_frame and mean_speed < settings.settle_speed \
            and abs(strain - strain_before) < SETTLED_STRAIN_CHANGE
        kinetic = 0.5 * float(np.sum(mass * speed_sq))
        if kinetic < previous and not at_rest:
            simulation.states.write(simulation.state_in, x, np.zeros_like(v))
            kinetic, since_zeroed = 0.0, 0
        previous = kinetic
    return simulated, mean_speed, at_rest
