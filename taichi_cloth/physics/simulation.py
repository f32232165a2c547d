"""A scene's simulation: build everything once, then frames × substeps.

Per substep the body (when there is one) moves the pin frame and the capsules, and the
integrator advances ``state_in → state_out``; the two states swap. No Python loop over particles
and no copy to the host happens inside the substep loop. Per frame the state is copied to NumPy
once for the metrics (energies, strain, penetration, centre of mass) and the stability check:
a non-finite or exploded state stops the run with ``UnstableError`` (exit code 3) before anything
of that frame is written.
"""

import dataclasses
import time
from dataclasses import dataclass, field

import numpy as np
import taichi as ti

from taichi_cloth.errors import UnstableError
from taichi_cloth.physics.forces import Forces, make_effects, spring_energy, stretch_strain
from taichi_cloth.cloth.garment import build_garment
from taichi_cloth.physics.integrators import INTEGRATORS, make_integrator
from taichi_cloth.physics.integrators.implicit import SolverBreakdown
from taichi_cloth.physics.model import Model
from taichi_cloth.runtime import start_taichi
from taichi_cloth.config.scene import Scene
from taichi_cloth.physics.timestep import TimeStep, choose_time_step


@dataclass
class FrameMetrics:
    """One frame's measurements (SI units) as they go into ``stats.json``."""

    frame: int
    t: float
    kinetic_energy: float
    potential_energy: float
    max_strain: float
    max_penetration: float
    center_of_mass: list
    cg_iterations: float | None = None  # implicit integrator: mean CG iterations per step

    def as_dict(self) -> dict:
        return {key: value for key, value in self.__dict__.items() if value is not None}


@dataclass
class RunRecord:
    """What a run measured: per-frame metrics and wall-clock seconds per phase."""

    frames: list = field(default_factory=list)
    wall_seconds: dict = field(default_factory=lambda: {"compile": 0.0, "simulate": 0.0})
    cg_iterations: list = field(default_factory=list)  # per implicit step
    retries: int = 0  # frames rolled back and redone with the step halved

    @property
    def max_strain(self) -> float:
        return max((f.max_strain for f in self.frames), default=0.0)

    @property
    def max_penetration(self) -> float:
        return max((f.max_penetration for f in self.frames), default=0.0)


class Simulation:
    """Everything a scene needs to run: model, forces, integrator, states, time step."""

    def __init__(self, scene: Scene, body_rig=None):
        """body_rig: a ``rig.BodyRig`` when the scene has a body (None for cloth alone)."""
        start_taichi(scene.simulation.arch)
        self.scene = scene
        self.body_rig = body_rig
        material = scene.material
        waist_height = body_rig.waist_height if body_rig is not None else None
        self.garment = build_garment(scene.cloth, material, waist_height, scene.path)
        damping = scene.effects.get("damping")
        self.model = Model(self.garment, scene.simulation.precision,
                           damping.scale if damping is not None else None,
                           body_rig.sample_count if body_rig is not None else 2)
        extra = body_rig.attach(self.model, scene.effects) if body_rig is not None else {}
        self.forces = Forces(self.model, make_effects(scene.effects, extra),
                             INTEGRATORS[scene.simulation.integrator].packs_springs)
        collision = scene.effects.get("collision")
        projection = body_rig.contact if collision is not None and \
            collision.mode == "penalty+projection" else None
        self.integrator = make_integrator(scene.simulation.integrator, self.forces, projection,
                                          scene.simulation)
        self.time_step = self._choose_time_step()
        self.state_in, self.state_out, self.backup = self.model.states(3)
        self._compiled_batches = set()
        self.gravity = scene.effects["gravity"].g if "gravity" in scene.effects else 0.0

    def _choose_time_step(self) -> TimeStep:
        scene, garment, model = self.scene, self.garment, self.model
        contact_modes = [(config.stiffness, config.damping) for name, config
                         in scene.effects.items() if name in ("collision", "ground")]
        damping_time = garment.damping_time * scene.effects["damping"].scale \
            if model.has_dashpots else 0.0
        return choose_time_step(
            scene.simulation.dt, 1.0 / scene.scene.fps, scene.simulation.integrator,
            garment.positions, model.host_spring_ends, model.host_stiffness, garment.mass,
            ~garment.pinned, damping_time, contact_modes, scene.simulation.safety)

    @property
    def effect_names(self) -> list[str]:
        return self.forces.compiled_names

    def frame_time(self, frame: int) -> float:
        """Simulated time [s] at the end of ``frame`` (0-based)."""
        return (frame + 1) / self.scene.scene.fps

    def positions(self) -> np.ndarray:
        return self.state_in.x.to_numpy().astype(np.float64)

    def state_problem(self, x: np.ndarray, v: np.ndarray) -> str | None:
        """Why the state is not usable (non-finite, over-strained or too fast), or None."""
        settings = self.scene.simulation
        if not (np.isfinite(x).all() and np.isfinite(v).all()):
            return "became non-finite"
        strain = float(np.max(stretch_strain(self.model, x))) if self.model.stretch_count else 0.0
        if strain > settings.blowup_strain:
            return f"exploded (max strain {strain:.3g} > simulation.blowup_strain " \
                   f"{settings.blowup_strain:g})"
        speed = float(np.sqrt(np.max(np.sum(v * v, axis=1))))
        if speed > settings.max_speed:
            return f"exploded (a particle at {speed:.3g} m/s > simulation.max_speed " \
                   f"{settings.max_speed:g})"
        return None

    def measure(self, frame: int, x: np.ndarray, v: np.ndarray) -> FrameMetrics:
        """Metrics of a (checked) state x [m], v [m/s] at the end of ``frame``."""
        mass = self.model.host_mass
        strain = stretch_strain(self.model, x) if self.model.stretch_count else np.zeros(1)
        kinetic = 0.5 * float(np.sum(mass * np.sum(v * v, axis=1)))
        potential = self.gravity * float(np.sum(mass * x[:, 1])) + spring_energy(self.model, x)
        penetration = self.body_rig.max_penetration(x) if self.body_rig is not None else 0.0
        return FrameMetrics(
            frame=frame, t=self.frame_time(frame), kinetic_energy=kinetic,
            potential_energy=potential, max_strain=float(np.max(strain)),
            max_penetration=penetration,
            center_of_mass=[float(c) for c in np.sum(mass[:, None] * x, 0) / np.sum(mass)])

    def guarded_frame(self, frame: int, record: "RunRecord") -> FrameMetrics:
        """Advance ``frame`` and check it. A bad frame is rolled back and retried with the step
        halved (the smaller step is kept for the rest of the run), up to
        ``simulation.max_retries`` times; then ``UnstableError``. Nothing non-finite leaves."""
        self.backup.copy_from(self.state_in)
        for attempt in range(self.scene.simulation.max_retries + 1):
            try:
                self.advance_frame(frame, record)
                x = self.positions()
                v = self.state_in.v.to_numpy().astype(np.float64)
                problem = self.state_problem(x, v)
            except SolverBreakdown as breakdown:
                problem = f"could not be solved for ({breakdown})"
            if problem is None:
                return self.measure(frame, x, v)
            if attempt == self.scene.simulation.max_retries:
                break
            record.retries += 1
            self.state_in.copy_from(self.backup)
            self.time_step = dataclasses.replace(
                self.time_step, dt=self.time_step.dt / 2,
                substeps_per_frame=2 * self.time_step.substeps_per_frame)
        integrator = self.scene.simulation.integrator
        advice = "lower simulation.dt or set it to \"auto\", or use integrator = \"implicit\""
        if integrator == "euler":
            advice += "; explicit Euler also needs [effects.damping]"
        halvings = f" after {record.retries} halvings of the step" if record.retries else ""
        raise UnstableError(f"frame {frame}: the cloth {problem} with integrator '{integrator}' "
                            f"at dt = {self.time_step.dt:.6g} s{halvings}; {advice}", frame)

    def advance_frame(self, frame: int, record: "RunRecord") -> None:
        """The substeps of ``frame`` (t from frame/fps to (frame+1)/fps), in the integrator's
        launches (``Integrator.launch_counts``). The first launch of each kernel variant compiles
        it: its wall time goes to ``compile``, the rest to ``simulate``."""
        if self.body_rig is not None:
            self.body_rig.prepare_frame(frame)
        dt, substeps = self.time_step.dt, self.time_step.substeps_per_frame
        done = 0
        for count in self.integrator.launch_counts(substeps):
            t = frame / self.scene.scene.fps + done * dt
            variant = self.integrator.kernel_variant(count, self.state_in, self.state_out)
            started = time.perf_counter()
            self.state_in, self.state_out = self.integrator.advance(
                self.state_in, self.state_out, t, dt, count)
            if variant not in self._compiled_batches:
                ti.sync()
                self._compiled_batches.add(variant)
                record.wall_seconds["compile"] += time.perf_counter() - started
            else:
                record.wall_seconds["simulate"] += time.perf_counter() - started
            done += count
        started = time.perf_counter()
        ti.sync()
        record.wall_seconds["simulate"] += time.perf_counter() - started

    def run(self, frame_count: int, on_frame=None, record: RunRecord | None = None,
            first_frame: int = 0) -> RunRecord:
        """Simulate frames ``first_frame`` … ``frame_count`` − 1 (the state must be that of
        ``first_frame``'s start) into ``record`` (a new one if None: pass your own to keep what
        was measured when a run is interrupted); call ``on_frame(frame, metrics)`` after each."""
        record = RunRecord() if record is None else record
        for frame in range(first_frame, frame_count):
            metrics = self.guarded_frame(frame, record)
            if hasattr(self.integrator, "take_iterations"):
                iterations = self.integrator.take_iterations()
                record.cg_iterations.extend(iterations)
                metrics.cg_iterations = float(np.mean(iterations))
            record.frames.append(metrics)
            if on_frame is not None:
                on_frame(frame, metrics)
        return record

    def _solver_report(self, record: RunRecord) -> dict:
        """CG iterations per step of the implicit integrator (nothing for the explicit ones)."""
        if not record.cg_iterations:
            return {}
        return {"cg": {"tolerance": self.scene.simulation.cg_tolerance,
                       "max_iterations": self.scene.simulation.cg_max_iterations,
                       "iterations_mean": float(np.mean(record.cg_iterations)),
                       "iterations_max": int(np.max(record.cg_iterations)),
                       "unconverged_steps": self.integrator.unconverged_steps}}

    def stats(self, record: RunRecord) -> dict:
        """The ``stats.json`` document (DESIGN.md, "Outputs")."""
        scene = self.scene
        return {
            "scene": scene.name,
            "integrator": scene.simulation.integrator,
            "dt": self.time_step.dt,
            "substeps_per_frame": self.time_step.substeps_per_frame,
            "retries": record.retries,
            "time_step": self.time_step.report(),
            "precision": scene.simulation.precision,
            "material": scene.material.name,
            "frames": len(record.frames),
            "particles": self.model.particle_count,
            "springs": self.model.spring_count,
            "springs_per_family": self.model.family_counts,
            "capsules": self.body_rig.capsule_count if self.body_rig is not None else 0,
            "effects": self.effect_names,
            "finite": True,
            "max_strain": record.max_strain,
            "max_penetration": record.max_penetration,
            "wall_seconds": {k: round(v, 4) for k, v in record.wall_seconds.items()},
            **self._solver_report(record),
            "per_frame": [f.as_dict() for f in record.frames],
        }
