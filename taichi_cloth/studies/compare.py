"""The integrator comparison (the README's first promise): what each integrator's accuracy
costs in time.

``compare SCENE`` runs the scene once per integrator × time step and measures, per run:

- cost: wall-clock seconds of integrator substeps per simulated second. Every (integrator, dt)
  is first run for ``WARMUP_FRAMES`` frames, which compiles every kernel variant the run will
  launch (the two states swap after an odd substep count, and each order is its own Taichi
  instantiation); the measured run after it compiles nothing, and a short one is repeated and
  costs its fastest repeat. The per-frame guard and metrics (host copies) are not part of the
  cost; JIT compilation is reported apart.
- error against a reference trajectory (RK4 in double precision at ``REFERENCE_REFINEMENT``
  times smaller a step than the smallest swept one, or ``--reference-dt``): the positions of the
  free (unpinned) particles at every frame end; ``error_rms`` is the root mean square over
  particles and frames, ``error_max`` the largest single distance [m].
- energy drift: (E_end − E_ref,end) / max_t KE_ref, the run's total energy (kinetic + the effects'
  potentials + springs) at the end minus the reference's, in units of the reference's peak kinetic energy: the
  energy the integrator made (+) or destroyed (−) beyond the physical damping, measured on the
  scale of the motion, and independent of where gravity's potential is zero.
- stability: every run has ``simulation.max_retries = 0``, so the guard does not halve the step;
  a run whose state becomes non-finite or explodes is recorded as unstable at that frame.
- max strain of the stretch springs and max penetration into the body [m].

Runs use double precision unless ``--set simulation.precision=f32`` says otherwise (single
precision floors position errors near 1e-7 m, which hides RK4's order). One ``Simulation`` per
integrator serves every dt: between runs its state is reset to the rest state and its time step
replaced, so kernels compile once per integrator, not once per run.

Outputs (``output/compare/<scene>/``): ``results.csv``, ``summary.json``, ``report.md``, plots
(``compare_plots``) and a labelled side-by-side video and contact sheet (``compare_video``).
"""

import math
import os
import platform
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import taichi as ti

from taichi_cloth.output.run import OUTPUT_ROOT, check_writable, safe_name
from taichi_cloth.errors import InputError, UnstableError
from taichi_cloth.flags import choice_list, number_list
from taichi_cloth.output.files import write_csv, write_json
from taichi_cloth.physics.integrators import INTEGRATORS
from taichi_cloth.output.progress import Progress
from taichi_cloth.config.scene import load_scene
from taichi_cloth.physics.simulation import RunRecord, Simulation
from taichi_cloth.physics.timestep import IMPLICIT_FRAME_FRACTION, TimeStep, fixed_time_step

REFERENCE_INTEGRATOR = "rk4"
REFERENCE_REFINEMENT = 4  # reference dt = smallest swept dt / this (RK4: 256× more accurate)
WARMUP_FRAMES = 2  # frames 0 and 1 launch every kernel variant a run uses
TIMING_REPEATS = 5  # a short run is timed up to this many times, the fastest counts
TIMING_SECONDS = 0.2  # ... while its repeats total less than this [s] of substeps
DEFAULT_DURATION_CAP = 1.0  # s: default --duration is the scene's, at most this
SWEEP_POINTS_MAX = 8  # default sweep: at most this many steps, spaced by a factor >= 2
ORDER_FIT_POINTS = 3  # the order is fitted on this many smallest steps
ROUNDOFF_FLOOR = 100  # errors below this × machine epsilon × cloth size are round-off
EXPECTED_ORDERS = {"euler": 1, "symplectic": 1, "rk4": 4, "implicit": 1}  # docs/physics.md
CSV_COLUMNS = ("integrator", "dt", "dt_requested", "substeps_per_frame", "stable",
               "blowup_time", "wall_seconds_per_sim_second", "compile_seconds", "error_rms",
               "error_max", "energy_drift", "max_strain", "max_penetration")


def integrator_names(text: str | None) -> tuple[str, ...]:
    """--integrators: a comma list of integrator names (default: all four)."""
    if text is None:
        return tuple(INTEGRATORS)
    return choice_list(text, "--integrators", INTEGRATORS, "integrator")


SMALLEST_STEP = 1e-7  # s: a step below this would need millions of substeps a frame


def seconds_list(text: str | None, flag: str) -> tuple[float, ...]:
    """A comma list of positive, finite seconds for ``flag`` (--dts, --duration, ...); a time
    step (--dts, --reference-dt, --video-dt) at least ``SMALLEST_STEP``."""
    values = () if text is None else number_list(text, flag)
    if flag != "--duration" and any(value < SMALLEST_STEP for value in values):
        raise InputError(f"{flag} {text}: a step below {SMALLEST_STEP:g} s would take millions "
                         f"of substeps a frame; give larger steps")
    return values


def seconds_value(text: str | None, flag: str) -> float | None:
    """One positive number of seconds for ``flag``, or None when the flag is absent."""
    values = seconds_list(text, flag)
    if len(values) > 1:
        raise InputError(f"{flag} {text}: expected one number of seconds")
    return values[0] if values else None


def default_dts(limits: dict, frame_time: float) -> tuple[float, ...]:
    """A geometric series of steps [s], largest first, spanning every explicit integrator's
    predicted stability limit (``limits``: integrator → step [s], inf for any, 0 for none): from
    twice the largest finite limit (at least half a frame when backward Euler runs, its default
    step; at most a frame) down to half the smallest or below, spaced by a factor of 2, or more
    when that would take over ``SWEEP_POINTS_MAX`` steps."""
    finite = [h for h in limits.values() if 0.0 < h < math.inf]
    upper = 2.0 * max(finite) if finite else frame_time
    if "implicit" in limits:
        upper = max(upper, IMPLICIT_FRAME_FRACTION * frame_time)
    upper = min(upper, frame_time)
    lower = min(0.5 * min(finite), upper) if finite else upper / 16.0
    span = upper / lower
    ratio = max(2.0, span ** (1.0 / (SWEEP_POINTS_MAX - 1)))
    count = math.ceil(math.log(span) / math.log(ratio) - 1e-9) + 1
    return tuple(upper / ratio ** k for k in range(count))


@dataclass
class Run:
    """One run of one integrator at one step: per-frame measurements up to where it stopped.

    positions: (K, N, 3) frame-end positions [m]; energy, kinetic_energy: (K,) [J]; times: (K,)
    frame-end times [s]; blowup_time: end of the frame that failed [s] (None when stable);
    blowup_positions: the state the guard rejected there [m], when it is still finite (it shows
    how the run fails); compile_seconds, simulate_seconds: wall-clock [s]."""

    integrator: str
    time_step: TimeStep
    stable: bool = True
    blowup_time: float | None = None
    blowup_positions: np.ndarray | None = None
    compile_seconds: float = 0.0
    simulate_seconds: float = 0.0
    times: list = field(default_factory=list)
    positions: list = field(default_factory=list)
    energy: list = field(default_factory=list)
    kinetic_energy: list = field(default_factory=list)
    max_strain: float = 0.0
    max_penetration: float = 0.0


class Runner:
    """The simulations of a comparison, one per (integrator, precision), each reused for every
    dt: a run resets the state to rest and swaps in its step. Each is built with dt = "auto",
    so the core's own step choice (``timestep``: ω_max, the springs' damping, the contacts)
    predicts its integrator's stability limit."""

    def __init__(self, scene_name: str, overrides: tuple):
        """overrides: the scene's ``--set`` list (the precision default and duration included)."""
        self.scene_name = scene_name
        self.overrides = overrides
        self.simulations = {}  # (integrator, precision or "") → (Simulation, rest State)
        self.limits = {}  # integrator → predicted largest stable step [s] (inf: any, 0: none)
        self.omega_max = None  # the cloth's highest angular frequency [rad/s], contact included

    def _build(self, extra: list[str]) -> Simulation:
        return Simulation.from_scene(self.scene_name, self.overrides + tuple(extra))

    def simulation(self, integrator: str, precision: str = "") -> tuple[Simulation, object]:
        """The simulation of ``integrator`` (``precision``: force "f64"/"f32", "" = scene's)."""
        key = (integrator, precision)
        if key not in self.simulations:
            extra = [f"simulation.integrator={integrator}", "simulation.max_retries=0"]
            if precision:
                extra.append(f"simulation.precision={precision}")
            try:
                simulation = self._build(extra + ["simulation.dt=auto"])
                bound = simulation.time_step.stable_dt
                self.limits.setdefault(integrator, math.inf if bound is None else bound)
                self.omega_max = simulation.time_step.omega_max
            except InputError:  # "auto" finds no stable step: explicit Euler without dashpots
                simulation = self._build(extra + ["simulation.dt=1.0"])
                self.limits.setdefault(integrator, 0.0)
            self.simulations[key] = (simulation, simulation.snapshot())
        return self.simulations[key]

    def run(self, integrator: str, time_step: TimeStep, progress: Progress, precision: str = "",
            measured: bool = True) -> Run:
        """The scene with ``integrator`` at ``time_step``. ``measured``: first a warm-up of
        ``WARMUP_FRAMES`` frames; its wall time less what those frames cost in the measured run
        is the compilation time; a short run is repeated (up to ``TIMING_REPEATS`` runs while they
        total under ``TIMING_SECONDS``) and costs its fastest, as timeit does, so that scheduler
        noise does not decide which integrator is cheaper. A run that blows up is returned
        unstable (no cost), not raised."""
        simulation, rest = self.simulation(integrator, precision)
        frame_count = simulation.scene.frame_count
        warmup = None
        if measured:
            warmup = self._simulate(simulation, rest, integrator, time_step,
                                    min(WARMUP_FRAMES, frame_count))
        run = warmup if warmup is not None and not warmup.stable else \
            self._simulate(simulation, rest, integrator, time_step, frame_count, progress)
        repeats, spent = 1, run.simulate_seconds
        while measured and run.stable and repeats < TIMING_REPEATS and spent < TIMING_SECONDS:
            again = self._simulate(simulation, rest, integrator, time_step, frame_count)
            run.simulate_seconds = min(run.simulate_seconds, again.simulate_seconds)
            repeats, spent = repeats + 1, spent + again.simulate_seconds
        skipped = frame_count if run is warmup else frame_count + 1 - len(run.times)
        for _ in range(skipped):  # the frames a blown-up run will not simulate
            progress.update(run.blowup_time)
        if warmup is not None and run is not warmup:
            share = run.simulate_seconds * (len(warmup.times) - 1) / max(len(run.times) - 1, 1)
            run.compile_seconds += max(warmup.compile_seconds + warmup.simulate_seconds - share,
                                       0.0)
        return run

    @staticmethod
    def _simulate(simulation: Simulation, rest, integrator: str, time_step: TimeStep,
                  frame_count: int, progress: Progress | None = None) -> Run:
        simulation.restore(rest)
        simulation.set_time_step(time_step.dt, time_step.substeps_per_frame)
        run = Run(integrator, time_step)

        def on_frame(frame, metrics):
            run.times.append(metrics.t)
            run.positions.append(simulation.positions())
            run.energy.append(metrics.kinetic_energy + metrics.potential_energy)
            run.kinetic_energy.append(metrics.kinetic_energy)
            run.max_strain = max(run.max_strain, metrics.max_strain)
            run.max_penetration = max(run.max_penetration, metrics.max_penetration)
            if progress is not None and frame > 0:
                progress.update(metrics.t)

        record = RunRecord()
        try:
            simulation.run(frame_count, on_frame, record)
        except UnstableError as error:
            run.stable = False
            run.blowup_time = simulation.frame_time(error.frame)
            rejected = simulation.positions()  # max_retries = 0: the frame was not rolled back
            if np.isfinite(rejected).all():
                run.blowup_positions = rejected
        run.compile_seconds = record.wall_seconds["compile"]
        run.simulate_seconds = record.wall_seconds["simulate"]
        return run


def trajectory_error(run: Run, reference: Run, free: np.ndarray) -> tuple[float, float]:
    """(RMS, max) distance [m] of the free particles from the reference over all frame ends."""
    distance = np.linalg.norm(np.stack(run.positions)[:, free]
                              - np.stack(reference.positions)[:, free], axis=2)
    return float(np.sqrt(np.mean(distance ** 2))), float(np.max(distance))


def fitted_order(dts, errors, floor: float) -> dict | None:
    """The convergence order p of error ≈ C·dtᵖ: the least-squares slope of log(error) over
    log(dt) on the ``ORDER_FIT_POINTS`` smallest steps whose error is above ``floor`` [m] (the
    round-off floor): the asymptotic end of the sweep, away from the stability limit, where
    higher powers of dt still bend the curve. None with fewer than 2 such steps."""
    points = sorted((dt, error) for dt, error in zip(dts, errors) if error > floor)
    used = points[:ORDER_FIT_POINTS]
    if len(used) < 2:
        return None
    slope, _ = np.polyfit(np.log([dt for dt, _ in used]), np.log([e for _, e in used]), 1)
    return {"order": float(slope), "dts": [dt for dt, _ in used]}


def machine_description() -> dict:
    """The CPU model (/proc/cpuinfo), logical cores, the Taichi backend and versions."""
    cpu = platform.processor() or "unknown"
    cpuinfo = Path("/proc/cpuinfo")
    if cpuinfo.exists():
        models = [line.split(":", 1)[1].strip() for line in cpuinfo.read_text().splitlines()
                  if line.startswith("model name")]
        cpu = models[0] if models else cpu
    return {"cpu": cpu, "cores": os.cpu_count(),
            "taichi_arch": ti.lang.impl.current_cfg().arch.name,
            "taichi": ".".join(map(str, ti.__version__)), "python": platform.python_version(),
            "system": platform.platform()}


def result_row(run: Run, reference: Run, free: np.ndarray, duration: float) -> dict:
    """The CSV row of a run (blank cost, error, energy, strain and penetration when it blew
    up)."""
    row = {"integrator": run.integrator, "dt": run.time_step.dt,
           "dt_requested": run.time_step.requested,
           "substeps_per_frame": run.time_step.substeps_per_frame, "stable": run.stable,
           "blowup_time": run.blowup_time, "compile_seconds": run.compile_seconds}
    if run.stable:
        error_rms, error_max = trajectory_error(run, reference, free)
        row.update(wall_seconds_per_sim_second=run.simulate_seconds / duration,
                   error_rms=error_rms, error_max=error_max,
                   energy_drift=(run.energy[-1] - reference.energy[-1])
                   / max(max(reference.kinetic_energy), 1e-300),
                   max_strain=run.max_strain, max_penetration=run.max_penetration)
    return row


def unique_steps(dts, frame_time: float) -> list[TimeStep]:
    """The steps really taken for the requested ``dts`` [s], largest first, one per substep
    count (two requests that round to the same step run once)."""
    steps = {}
    for dt in sorted(dts, reverse=True):
        step = fixed_time_step(dt, frame_time)
        steps.setdefault(step.substeps_per_frame, step)
    return list(steps.values())


def convergence_orders(rows: list[dict], names, floor: float) -> dict:
    """Per integrator: the order fitted on its stable rows' RMS errors (``fitted_order``), the
    order docs/physics.md expects, and the steps [s] the fit used."""
    orders = {}
    for name in names:
        stable = [row for row in rows if row["integrator"] == name and row["stable"]]
        fit = fitted_order([row["dt"] for row in stable], [row["error_rms"] for row in stable],
                           floor)
        orders[name] = {"order": fit["order"] if fit else None,
                        "expected": EXPECTED_ORDERS[name], "dts": fit["dts"] if fit else []}
    return orders


def video_step(rows: list[dict], steps: list[TimeStep], names) -> TimeStep:
    """The default step of the side-by-side video: the largest swept step at which every
    integrator stayed stable, else the smallest swept one."""
    for step in steps:
        if all(row["stable"] for row in rows if row["dt"] == step.dt and
               row["integrator"] in names):
            return step
    return steps[-1]


def compare(scene_name: str, overrides: list[str], integrators: str | None = None,
            dts: str | None = None, duration: str | None = None, out: str | None = None,
            arch: str | None = None, quiet: bool = False, reference_dt: str | None = None,
            video_dt: str | None = None, video: bool = True) -> int:
    """The ``compare`` command: sweep, reference, CSV, summary, plots, report and video."""
    from taichi_cloth.studies import compare_plots
    from taichi_cloth.studies import compare_report
    names = integrator_names(integrators)
    requested_dts = seconds_list(dts, "--dts")
    seconds = seconds_value(duration, "--duration")
    reference_seconds = seconds_value(reference_dt, "--reference-dt")
    video_seconds = seconds_value(video_dt, "--video-dt")
    extra = ["simulation.precision=f64", *overrides] + ([f"simulation.arch={arch}"] if arch else [])
    scene = load_scene(scene_name, tuple(extra))
    seconds = seconds or min(scene.scene.duration, DEFAULT_DURATION_CAP)
    extra.append(f"scene.duration={seconds!r}")
    directory = Path(out) if out else OUTPUT_ROOT / "compare" / safe_name(scene.name)
    check_writable(directory, "--out")

    runner = Runner(scene_name, tuple(extra))
    for name in names:  # each integrator's simulation, and its predicted stability limit
        runner.simulation(name)
    simulation = runner.simulation(names[0])[0]
    scene, frame_time = simulation.scene, 1.0 / simulation.scene.scene.fps
    steps = unique_steps(requested_dts or default_dts({name: runner.limits[name] for name in names},
                                                       frame_time), frame_time)
    reference_step = fixed_time_step(reference_seconds or steps[-1].dt / REFERENCE_REFINEMENT,
                                     frame_time)
    extra_video = video and video_seconds is not None and \
        fixed_time_step(video_seconds, frame_time).dt not in [s.dt for s in steps]
    run_count = 1 + len(names) * (len(steps) + extra_video)
    with Progress(f"compare {scene.name}", run_count * scene.frame_count, quiet) as progress:
        reference = runner.run(REFERENCE_INTEGRATOR, reference_step, progress, "f64",
                               measured=False)
        if not reference.stable:
            raise UnstableError(f"the reference ({REFERENCE_INTEGRATOR}, f64, dt = "
                                f"{reference_step.dt:.4g} s) blew up at t = "
                                f"{reference.blowup_time:.3g} s; give a smaller --reference-dt",
                                len(reference.times))
        runs = [runner.run(name, step, progress) for name in names for step in steps]
        simulated = scene.frame_count * frame_time
        free = ~simulation.garment.pinned
        rows = [result_row(run, reference, free, simulated) for run in runs]
        shown = fixed_time_step(video_seconds, frame_time) if video_seconds is not None else \
            video_step(rows, steps, names)
        shown_runs = [run for run in runs if run.time_step.dt == shown.dt]
        if video and not shown_runs:
            shown_runs = [runner.run(name, shown, progress, measured=False) for name in names]

    floor = ROUNDOFF_FLOOR * np.finfo(simulation.model.numpy_real).eps * \
        float(np.ptp(simulation.garment.positions, axis=0).max())
    summary = {
        "scene": scene.name, "duration": simulated, "frames": scene.frame_count,
        "fps": scene.scene.fps, "particles": simulation.model.particle_count,
        "precision": scene.simulation.precision, "integrators": list(names),
        "reference": {"integrator": REFERENCE_INTEGRATOR, "precision": "f64",
                      "dt": reference_step.dt,
                      "substeps_per_frame": reference_step.substeps_per_frame},
        "error_floor": floor, "timing": {"repeats": TIMING_REPEATS, "seconds": TIMING_SECONDS},
        "stability": {"omega_max": runner.omega_max,
                      "damping_time": simulation.garment.damping_time
                      * scene.effects["damping"].scale if "damping" in scene.effects else 0.0,
                      "dt": {name: (runner.limits[name] if math.isfinite(runner.limits[name])
                                    else None) for name in names}},
        "orders": convergence_orders(rows, names, floor), "video_dt": shown.dt,
        "machine": machine_description(), "results": rows}
    write_csv(directory / "results.csv", rows, CSV_COLUMNS)
    write_json(directory / "summary.json", summary)
    compare_plots.write_plots(directory, summary, runs, reference)
    compare_report.write_report(directory / "report.md", summary)
    if video:
        from taichi_cloth.studies.compare_video import write_video_and_sheet
        write_video_and_sheet(directory, simulation, shown_runs, quiet)
    if not quiet:
        print(compare_report.summary_line(summary, directory))
    return 0
