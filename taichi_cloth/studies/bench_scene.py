"""The scene parts of ``bench`` (``--scene``): each effect's cost, the spring and contact passes on
their own, and a whole scene's simulated seconds per wall second (``studies/bench.py`` has the
reference sheet and the report)."""

import math
import statistics
import time
from collections.abc import Iterator

import taichi as ti

from taichi_cloth.effects import EFFECTS
from taichi_cloth.errors import InputError
from taichi_cloth.studies.timing import substep_row, timed_rate

METRIC_REPEATS = 20  # timings of the self-intersection count on a scene's last frame
SETTLED_FRAMES = 30  # frames into the motion (1 s of hula's) of the state that each effect's
                     # timing starts from
MIN_PAIRS = 20  # runs of a frame with and without an effect, at least


@ti.data_oriented
class PassTimer:
    """Kernels that run one pass of a simulation ``count`` times: the spring pass (packed grid
    cloth: pack + SIMD stencil, with the effects that act in it, bending and drag; otherwise
    the CSR gather of springs and dashpots), the contact pass (pose the
    capsules, then every particle's contact force) and the self-collision pass (its
    ``prepare``, then every particle's gather, then its post step, the side records: with its
    candidate lists kept, as most evaluations find them, or rebuilt every pass, as after half
    the padding of motion). Loops
    are serial when the integrator's are, like the substep they come from."""

    def __init__(self, simulation):
        self.simulation = simulation
        self.forces = simulation.forces
        self.model = simulation.model
        self.serial = simulation.integrator.serial
        self.out = ti.Vector.field(3, self.model.real, self.model.particle_count)
        self.contact = self._effect("collision")
        self.has_contact = self.contact is not None
        self.self_collision = self._effect("self_collision")
        self.has_self_collision = self.self_collision is not None

    def _effect(self, name: str):
        """The simulation's effect of that name, or None."""
        return next((e for e in self.simulation.effects if e.name == name), None)

    @ti.func
    def _springs(self, state):
        if ti.static(self.forces.has_packed):
            self.forces.packed.spring_pass(state.x, state.v)
        else:
            for i_p in range(self.model.particle_count):
                self.out[i_p] = self.forces.spring_force(state.x, state.v, i_p)

    @ti.func
    def _contact(self, state, t):
        if ti.static(self.has_contact):
            self.contact.prepare(state.x, state.v, t)
            for i_p in range(self.model.particle_count):
                self.out[i_p] = self.contact.force(self.model, state.x, state.v, i_p,
                                                   ti.cast(t, self.model.real))

    @ti.func
    def _self_collision(self, state, t, rebuild: ti.template()):
        if ti.static(self.has_self_collision):
            effect = self.self_collision
            if ti.static(rebuild):  # the list built again, as after half the padding
                effect.pairs.rebuild_asked[None] = 1
            effect.prepare(state.x, state.v, t)
            for i_p in range(self.model.particle_count):
                self.out[i_p] = effect.force(self.model, state.x, state.v, i_p,
                                             ti.cast(t, self.model.real))
            effect.apply(state, t)  # its post step: the side records at the step's end

    @ti.kernel
    def _run(self, state: ti.template(), t: ti.f64, count: ti.i32, which: ti.template()):
        ti.loop_config(serialize=ti.static(self.serial))
        for _ in range(count):
            if ti.static(which == "springs"):
                self._springs(state)
            elif ti.static(which == "contact"):
                self._contact(state, t)
            else:
                self._self_collision(state, t, ti.static(which == "self_collision_rebuilt"))

    def seconds_per_pass(self, which: str, seconds: float, repeats: int) -> float:
        state = self.simulation.state_in
        t = 0.5 / self.simulation.scene.scene.fps
        count = 64 if self.serial else 1

        def run_batch():
            self._run(state, t, count, which)
            ti.sync()

        run_batch()
        return 1.0 / statistics.median(timed_rate(run_batch, count, seconds, repeats))


def scene_simulation(scene_name: str, overrides: tuple = ()):
    """A Simulation of the scene (with its body, if any) after ``overrides``."""
    from taichi_cloth.physics.simulation import Simulation
    return Simulation.from_scene(scene_name, overrides)


def frame_rate(simulation, seconds: float, repeats: int) -> list[float]:
    """Substeps per second through ``advance_frame`` (body posing included), warm-up first."""
    from taichi_cloth.physics.metrics import RunRecord
    record = RunRecord()
    frame = [1]

    def run_batch():
        simulation.advance_frame(frame[0], record)
        frame[0] += 1

    run_batch()
    run_batch()
    return timed_rate(run_batch, simulation.time_step.substeps_per_frame, seconds, repeats)


def settled_start(simulation):
    """The scene settled (when it settles) and ``SETTLED_FRAMES`` frames into its motion (all
    but its last, if it has fewer): (its snapshot with what its effects carry, the frame
    after). Restored into a simulation with another set of effects, each effect gets its own
    memory by name; an effect the snapshot lacks starts afresh (self-collision added to a
    scene rebuilds its list at every run of the frame)."""
    from taichi_cloth.physics.metrics import RunRecord
    from taichi_cloth.physics.settling import settle
    record = RunRecord()
    settle(simulation, record)
    frames = max(0, min(SETTLED_FRAMES, simulation.scene.frame_count - 1))
    for frame in range(1, frames + 1):
        simulation.advance_frame(frame, record)
    return simulation.snapshot(effects=True), frames + 1


def frame_iterations(simulation, snapshot, frame: int) -> float | None:
    """CG iterations a step of one run of ``frame`` from ``snapshot`` (``frame_seconds``) at
    the integrator's tolerance, on the mean (None for an integrator without a solve)."""
    integrator = simulation.integrator
    if not integrator.uses_jacobian:
        return None
    integrator.take_iterations()
    frame_seconds(simulation, snapshot, frame)
    return statistics.mean(integrator.take_iterations())


def hold_iterations(simulation, iterations: int | None) -> None:
    """Every later solve of the simulation takes exactly ``iterations`` CG iterations
    (tolerance 0; nothing for None), so that two simulations do the same solver work."""
    if iterations is not None:
        simulation.integrator.tolerance = 0.0
        simulation.integrator.max_iterations = iterations


def frame_seconds(simulation, snapshot, frame: int) -> float:
    """Seconds per substep of one run of ``frame`` (body posing included) from ``snapshot``."""
    from taichi_cloth.physics.metrics import RunRecord
    simulation.restore(snapshot)
    ti.sync()
    started = time.perf_counter()
    simulation.advance_frame(frame, RunRecord())
    ti.sync()
    return (time.perf_counter() - started) / simulation.time_step.substeps_per_frame


def paired_seconds(first, second, snapshot, frame: int, seconds: float) -> tuple[list, list]:
    """Seconds per substep of two simulations on the same frame from the same state
    (``frame_seconds``), in pairs for at least ``seconds`` and ``MIN_PAIRS`` pairs, after a run
    of each untimed: each pair ran within a few frames' time, so that a change in the machine's
    load falls on both alike, and every other pair runs the second first, so that going first
    or second favours neither."""
    for simulation in (first, second):
        frame_seconds(simulation, snapshot, frame)
    times = ([], [])
    started = time.perf_counter()
    while len(times[0]) < MIN_PAIRS or time.perf_counter() - started < seconds:
        order = (0, 1) if len(times[0]) % 2 == 0 else (1, 0)
        for k in order:
            times[k].append(frame_seconds((first, second)[k], snapshot, frame))
    return times


def median_interval_ranks(count: int, confidence: float = 0.95) -> int:
    """The largest r such that the r-th and (count + 1 − r)-th smallest of ``count``
    independent values hold their median with probability ≥ ``confidence``, for any
    continuous distribution: 1 − 2·P(B ≤ r − 1) with B ~ Binomial(count, ½) (Conover,
    "Practical Nonparametric Statistics", 3rd ed., §3.2); 1 (the extremes) when even they fall
    short."""
    rank, below = 1, 1 / 2 ** count  # below: P(B ≤ rank − 1)
    while rank < count // 2:
        below_next = below + math.comb(count, rank) / 2 ** count
        if 1 - 2 * below_next < confidence:
            break
        rank, below = rank + 1, below_next
    return rank


def effect_cost(with_times: list, without_times: list) -> dict:
    """An effect's cost per substep from paired runs [s] (``paired_seconds``): the median of
    the pairs' differences, with a confidence interval of at least 95 % from their order
    statistics (``median_interval_ranks``, distribution-free). A cost is never negative:
    where the interval holds 0 the cost is not told from the noise (``below_noise``) and only
    the interval's upper end is given (``noise_us_per_substep``); where it lies below 0 the
    scene is faster with the effect (``faster_with_effect``: its frame ran another way, or
    compiled to other code) and the cost is none."""
    differences = sorted(w - o for w, o in zip(with_times, without_times))
    count = len(differences)
    rank = median_interval_ranks(count)
    low, high = differences[rank - 1], differences[count - rank]
    has_cost = low > 0
    return {"cost_us_per_substep": round(1e6 * statistics.median(differences), 3)
            if has_cost else None,
            "noise_us_per_substep": round(1e6 * max(high, 0.0), 3),
            "interval_us_per_substep": [round(1e6 * low, 3), round(1e6 * high, 3)],
            "below_noise": low <= 0 <= high, "faster_with_effect": high < 0}


def bench_effects(scene_name: str, seconds: float, repeats: int) -> Iterator[dict]:
    """The cost of each effect: the scene with and without it (added with its defaults when the
    scene lacks it and can have it), in microseconds per substep and nanoseconds per
    particle-substep; a cost within the noise is reported as such (``effect_cost``). Both
    run the same frame from the same state, settled and ``SETTLED_FRAMES`` into the motion,
    in turns (``paired_seconds``, for ``repeats`` × ``seconds``): a cost is the effect's
    work, not a change of trajectory (measured as two free runs, gravity and ground "cost"
    what a skirt that floats or lands does instead). Where the integrator solves (backward
    Euler), each solve is held at the iterations that the scene takes a step on that frame
    (``hold_iterations``): how many iterations an effect adds or saves depends on the state,
    and is reported apart (``cg_iterations_with`` / ``_without``, at the scene's tolerance).
    Each row is yielded when measured (a part cut short keeps its rows)."""
    base = scene_simulation(scene_name)
    snapshot, frame = settled_start(base)
    base_iterations = frame_iterations(base, snapshot, frame)
    held = None if base_iterations is None else max(1, round(base_iterations))
    hold_iterations(base, held)
    base_times = [frame_seconds(base, snapshot, frame) for _ in range(repeats + 1)][1:]
    particles = base.model.particle_count
    size = f"{base.garment.columns}x{base.garment.rows}"
    integrator = base.scene.simulation.integrator
    solver = {} if held is None else {"cg_iterations_held": held}
    yield substep_row("scene", integrator, size, particles, [1.0 / t for t in base_times],
                      scene=scene_name, effects=base.effect_names, frame=frame, **solver)
    for name in (effect.name for effect in EFFECTS):
        declared = name in base.scene.effects
        try:
            other = scene_simulation(scene_name,
                                     (f"effects.{name}={'false' if declared else 'true'}",))
        except InputError:  # the scene cannot have it (collision without a body, ...)
            continue
        iterations = {}
        if held is not None:
            other_iterations = frame_iterations(other, snapshot, frame)
            iterations = {"cg_iterations_with": other_iterations, "cg_iterations_without":
                          base_iterations} if not declared else \
                {"cg_iterations_with": base_iterations, "cg_iterations_without": other_iterations}
            hold_iterations(other, held)
        base_times, other_times = paired_seconds(base, other, snapshot, frame,
                                                 seconds * repeats)
        with_times, without_times = (base_times, other_times) if declared \
            else (other_times, base_times)
        cost = effect_cost(with_times, without_times)
        per_particle = None if cost["cost_us_per_substep"] is None else \
            round(1e3 * cost["cost_us_per_substep"] / particles, 3)
        yield substep_row("effect", integrator, size, particles,
                          [1.0 / t for t in other_times], scene=scene_name, effect=name,
                          declared_in_scene=declared,
                          substeps_per_second_with=1.0 / statistics.median(with_times),
                          substeps_per_second_without=1.0 / statistics.median(without_times),
                          cost_ns_per_particle_substep=per_particle, **cost, **solver,
                          **iterations)


def bench_scene_integrators(scene_name: str, seconds: float, repeats: int,
                            integrators: list[str] | None = None) -> Iterator[dict]:
    """The scene with every integrator (or those named): its own at the scene's step (as its
    settling leaves it), the others at their ``dt = "auto"`` step; substeps and
    particle-substeps per second through ``advance_frame`` from frame 1, and the wall seconds
    per simulated second that gives. Every integrator starts from the state the scene's own
    settles into (settled once; a garment hanging on the body, as the frames a user runs
    start, not one falling from its pattern shape). An integrator with no stable auto step
    (explicit Euler without dashpots) gets a row saying so. Each row is yielded when
    measured."""
    from taichi_cloth.config.scene import load_scene
    from taichi_cloth.physics.integrators import INTEGRATORS
    from taichi_cloth.physics.metrics import RunRecord
    from taichi_cloth.physics.settling import settle
    shipped_integrator = load_scene(scene_name).simulation.integrator
    shipped = scene_simulation(scene_name)
    settle(shipped, RunRecord())
    start = shipped.host_state()
    for name in integrators or INTEGRATORS:
        own = name == shipped_integrator
        if own:
            simulation = shipped
        else:
            try:
                simulation = scene_simulation(
                    scene_name, (f"simulation.integrator={name}", "simulation.dt=auto"))
            except InputError as error:
                yield {"benchmark": "scene-integrator", "scene": scene_name,
                       "integrator": name, "shipped": False, "no_stable_step": str(error)}
                continue
            simulation.states.write(simulation.state_in, *start)
            simulation.forget_crossings()
        rates = frame_rate(simulation, seconds, repeats)
        dt = simulation.time_step.dt
        yield substep_row(
            "scene-integrator", name, f"{simulation.garment.columns}x{simulation.garment.rows}",
            simulation.model.particle_count, rates, scene=scene_name, shipped=own, dt=dt,
            wall_seconds_per_simulated_second=1.0 / (statistics.median(rates) * dt))


def bench_passes(scene_name: str, seconds: float, repeats: int) -> dict:
    """The spring pass, the contact pass and the self-collision pass of the scene on their own,
    seconds per pass, at the scene's first frame (settled, when the scene settles)."""
    from taichi_cloth.physics.metrics import RunRecord
    from taichi_cloth.physics.settling import settle
    simulation = scene_simulation(scene_name)
    settle(simulation, RunRecord())
    timer = PassTimer(simulation)
    springs = timer.seconds_per_pass("springs", seconds, repeats)
    contact = timer.seconds_per_pass("contact", seconds, repeats) if timer.has_contact else 0.0
    self_collision = {}
    if timer.has_self_collision:
        for which in ("self_collision", "self_collision_rebuilt"):
            self_collision[f"{which}_us_per_substep"] = round(
                1e6 * timer.seconds_per_pass(which, seconds, repeats), 3)
    return {"benchmark": "passes", "scene": scene_name,
            "integrator": simulation.scene.simulation.integrator,
            "size": f"{simulation.garment.columns}x{simulation.garment.rows}",
            "particles": simulation.model.particle_count,
            "substeps_per_second": 1.0 / (springs + contact),
            "particle_substeps_per_second": simulation.model.particle_count / (springs + contact),
            "springs_us_per_substep": round(1e6 * springs, 3),
            "contact_us_per_substep": round(1e6 * contact, 3), **self_collision}


def bench_scene_run(scene_name: str, overrides: tuple = ()) -> dict:
    """The whole scene, every frame, as ``simulate`` runs it (settling first): start-up (the
    scene read, the simulation built, the step chosen), compile, settle and simulated seconds
    per wall second of the frames, each timed on its own (the frames' seconds include the
    per-frame checks and metrics; of them, ``stepping_seconds`` are the substeps' launches alone,
    ``simulate``'s figure in ``stats.json``; the self-intersection count is also timed alone on
    the last frame); with
    self-collision, how many times its list was built in the frames' steps (a frame redone at a
    smaller step counts the builds of the try it keeps, and takes more steps than ``steps``)."""
    from taichi_cloth.physics.metrics import RunRecord
    from taichi_cloth.physics.settling import settle
    started = time.perf_counter()
    simulation = scene_simulation(scene_name, overrides)
    startup = time.perf_counter() - started
    record = RunRecord()
    settle(simulation, record)
    frames = simulation.scene.frame_count
    compiled_before = record.wall_seconds["compile"]
    stepped_before = record.wall_seconds["simulate"]
    started = time.perf_counter()
    simulation.run(frames, record=record)
    wall = time.perf_counter() - started - (record.wall_seconds["compile"] - compiled_before)
    stepping = record.wall_seconds["simulate"] - stepped_before
    simulated = frames / simulation.scene.scene.fps
    substeps = frames * simulation.time_step.substeps_per_frame
    stats = simulation.stats(record)
    final = simulation.positions()
    started = time.perf_counter()
    for _ in range(METRIC_REPEATS):
        simulation.intersections.count(final)
    intersection_seconds = (time.perf_counter() - started) / METRIC_REPEATS
    builds = {}
    if "self_collision" in stats["effects"]:  # how often a step paid for the list's rebuild
        counts = [frame["self_collision_builds"] for frame in stats["per_frame"]]
        builds = {"self_collision_builds": counts[-1] - counts[0], "steps": substeps}
    return {"benchmark": "scene-run", "scene": scene_name, "overrides": list(overrides),
            "integrator": simulation.scene.simulation.integrator,
            "size": f"{simulation.garment.columns}x{simulation.garment.rows}",
            "particles": simulation.model.particle_count,
            "substeps_per_second": substeps / wall,
            "particle_substeps_per_second": substeps * simulation.model.particle_count / wall,
            "frames": frames, "dt": simulation.time_step.dt, "simulated_seconds": simulated,
            "wall_seconds": round(wall, 3), "stepping_seconds": round(stepping, 3),
            "checks_seconds": round(wall - stepping, 3), "startup_seconds": round(startup, 3),
            "compile_seconds": round(record.wall_seconds["compile"], 3),
            "settle_seconds": round(record.wall_seconds.get("settle", 0.0), 3),
            "simulated_seconds_per_wall_second": simulated / wall,
            "wall_seconds_per_simulated_second": wall / simulated,
            "max_strain": stats["max_strain"], "max_penetration": stats["max_penetration"],
            "max_self_intersections": stats["max_self_intersections"],
            "self_intersection_ms_per_frame": round(1e3 * intersection_seconds, 3),
            **({"cg": stats["cg"]} if "cg" in stats else {}), **builds}
