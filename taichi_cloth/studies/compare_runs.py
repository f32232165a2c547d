"""The runs of a comparison (``compare``): one integrator at one step (``Run``), the simulations
that make them (``Runner``: one per integrator, reused for every step), and one integrator's
runs as an executor's job (``IntegratorJob``, ``integrator_runs``)."""

import math
from dataclasses import dataclass, field

import numpy as np

from taichi_cloth.config.scene import load_scene
from taichi_cloth.errors import InputError, UnstableError
from taichi_cloth.output.progress import Progress
from taichi_cloth.physics.simulation import RunRecord, Simulation
from taichi_cloth.physics.timestep import TimeStep
from taichi_cloth.runtime import start_taichi
from taichi_cloth.studies.executors import WORKER_THREADS

WARMUP_FRAMES = 2  # frames 0 and 1 launch every kernel variant a run uses
TIMING_REPEATS = 5  # a short run is timed up to this many times, the fastest counts
TIMING_SECONDS = 0.2  # ... while its repeats total less than this [s] of substeps
# particle-substeps per second of each integrator in f64 on a small sheet (64 particles, one
# Taichi thread, the 2-core CPU machine; docs/comparison.md), and the compile time of one
# integrator's kernels [s]: what ``estimate_seconds`` says up front
NOMINAL_RATES = {"euler": 1.1e7, "symplectic": 1.1e7, "rk4": 2.9e6, "implicit": 1.6e5}
NOMINAL_COMPILE = 3.0


def estimate_seconds(jobs: list, frame_count: int, particles: int) -> float:
    """The wall time a comparison's ``jobs`` (``IntegratorJob``) should take on a machine like
    the one ``NOMINAL_RATES`` was measured on: every run's substeps (its warm-up frames and,
    when short, its timing repeats included) at its integrator's rate, and each integrator's
    compilation."""
    seconds = 0.0
    for job in jobs:
        seconds += NOMINAL_COMPILE
        for step in job.steps:
            run = frame_count * step.substeps_per_frame * particles / NOMINAL_RATES[job.integrator]
            if job.measured:
                run = run * (frame_count + WARMUP_FRAMES) / frame_count
                run += min(run * (TIMING_REPEATS - 1), TIMING_SECONDS)
            seconds += run
    return seconds


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


@dataclass(frozen=True)
class IntegratorJob:
    """The runs of one integrator at ``steps`` (an executor's job: ``integrator_runs``)."""

    scene_name: str
    overrides: tuple
    integrator: str
    steps: tuple
    precision: str = ""
    measured: bool = True


def integrator_runs(job: IntegratorJob, runner: Runner | None = None,
                    progress: Progress | None = None) -> list[Run]:
    """``job``'s runs, in order of its steps: with this process's ``runner`` and ``progress``
    (the serial executor), else (a worker) with a runner of its own on one Taichi thread."""
    if runner is None:
        start_taichi(load_scene(job.scene_name, job.overrides).simulation.arch,
                     threads=WORKER_THREADS)
        runner = Runner(job.scene_name, job.overrides)
    progress = progress or Progress("", 1, quiet=True)
    return [runner.run(job.integrator, step, progress, job.precision, job.measured)
            for step in job.steps]
