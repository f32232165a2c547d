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
The reference and each integrator's runs are jobs for an executor (``--workers``,
``--cluster``; ``executors``): by default one after another in this process. Every worker,
this process included, runs Taichi on one thread, so that costs measured side by side stay
comparable; ``summary.json`` says which machines ran how many workers.

Outputs (``output/compare/<scene>/``): ``results.csv``, ``summary.json``, ``report.md``, plots
(``compare_plots``) and a labelled side-by-side video and contact sheet (``compare_video``).
"""

import functools
import math
from pathlib import Path

import numpy as np

from taichi_cloth.output.run import OUTPUT_ROOT, check_writable, safe_name
from taichi_cloth.errors import InputError, UnstableError
from taichi_cloth.flags import choice_list, number_list
from taichi_cloth.output.files import write_csv, write_json
from taichi_cloth.physics.integrators import INTEGRATORS
from taichi_cloth.output.progress import Progress, announce
from taichi_cloth.config.scene import arch_override, load_scene, refuse_lab_specimen
from taichi_cloth.physics.timestep import IMPLICIT_FRAME_FRACTION, TimeStep, fixed_time_step
from taichi_cloth.runtime import start_taichi
from taichi_cloth.studies.machine import machine_description
from taichi_cloth.studies.compare_runs import (TIMING_REPEATS, TIMING_SECONDS, IntegratorJob,
                                               Run, Runner, estimate_seconds, integrator_runs)
from taichi_cloth.studies.executors import WORKER_THREADS, Lost, make_executor

REFERENCE_INTEGRATOR = "rk4"
REFERENCE_REFINEMENT = 4  # reference dt = smallest swept dt / this (RK4: 256× more accurate)
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


def duration_text(seconds: float) -> str:
    """``seconds`` as a person says it: 40 s, 3 min, 1.5 h."""
    if seconds < 90:
        return f"{seconds:.0f} s"
    if seconds < 5400:
        return f"{seconds / 60:.0f} min"
    return f"{seconds / 3600:.1f} h"


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
            video_dt: str | None = None, video: bool = True, workers: int | None = None,
            cluster: str | None = None) -> int:
    """The ``compare`` command: sweep, reference, CSV, summary, plots, report and video. The
    reference and each integrator's runs are jobs for the executor of ``workers`` (default 1:
    this process) or ``cluster`` (``executors``); Taichi runs on one thread in each."""
    from taichi_cloth.studies import compare_plots
    from taichi_cloth.studies import compare_report
    names = integrator_names(integrators)
    requested_dts = seconds_list(dts, "--dts")
    seconds = seconds_value(duration, "--duration")
    reference_seconds = seconds_value(reference_dt, "--reference-dt")
    video_seconds = seconds_value(video_dt, "--video-dt")
    refuse_lab_specimen(scene_name)
    extra, flags = arch_override(["simulation.precision=f64", *overrides], arch)
    scene = load_scene(scene_name, tuple(extra), flags)
    seconds = seconds or min(scene.scene.duration, DEFAULT_DURATION_CAP)
    extra.append(f"scene.duration={seconds!r}")
    directory = Path(out) if out else OUTPUT_ROOT / "compare" / safe_name(scene.name)
    check_writable(directory, "--out")
    executor = make_executor(1 if workers is None and cluster is None else workers, cluster)
    start_taichi(scene.simulation.arch, threads=WORKER_THREADS)

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
    jobs = [IntegratorJob(scene_name, tuple(extra), REFERENCE_INTEGRATOR, (reference_step,),
                          "f64", measured=False)]
    jobs += [IntegratorJob(scene_name, tuple(extra), name, tuple(steps)) for name in names]
    estimate = estimate_seconds(jobs, scene.frame_count, simulation.model.particle_count)
    announce(f"compare {scene.name}", f"the reference and {len(names)} integrators × "
                                      f"{len(steps)} steps: about {duration_text(estimate)} "
                                      f"on one core of a 2-core CPU machine like CI's", quiet)
    with Progress(f"compare {scene.name}", run_count * scene.frame_count, quiet) as progress:
        in_process = executor.kind == "serial"
        function = functools.partial(integrator_runs, runner=runner, progress=progress) \
            if in_process else integrator_runs
        done = {}
        try:
            for job, outcome in executor.run(function, jobs):
                if isinstance(outcome, Lost):
                    raise InputError(f"compare: the {job.integrator} runs were lost: "
                                     f"{outcome.reason}")
                done[id(job)] = outcome
                for _ in range(0 if in_process else len(outcome) * scene.frame_count):
                    progress.update(scene.scene.duration)
        finally:
            executor.close()
        reference = done[id(jobs[0])][0]
        if not reference.stable:
            raise UnstableError(f"the reference ({REFERENCE_INTEGRATOR}, f64, dt = "
                                f"{reference_step.dt:.4g} s) blew up at t = "
                                f"{reference.blowup_time:.3g} s; give a smaller --reference-dt",
                                len(reference.times))
        runs = [run for job in jobs[1:] for run in done[id(job)]]
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
        "machine": machine_description(),
        "executor": {"kind": executor.kind, "workers": executor.workers,
                     "machines": executor.machines(), "threads_per_worker": WORKER_THREADS},
        "results": rows}
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
