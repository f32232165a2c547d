"""A scene's simulation: it builds everything once, owns its state and its time step, and runs
frames × substeps.

``Simulation.from_scene`` builds, in order: the body rig (``physics.rig``, when the scene has a
[body]), the garment (``cloth.garment``), the constant model (``physics.model``), the prescribed
motion the rig writes (``physics.control``), the scene's effects (``effects/``), the packed grid
when it pays (``physics.packed_grid``), the force evaluation (``physics.forces``), the integrator
(``physics.integrators``), the states, and the time step (``physics.timestep``). The time step
changes in one place (``set_time_step``); ``snapshot``/``restore`` copy the state and what the
integrator and effects carry to the host and back (``physics.snapshot``: checkpoints, reruns).

Per frame the rig poses the body (capsules, pinned waist) across the frame, then the integrator
advances ``state_in → state_out`` substep by substep in kernel launches of several substeps; the
two states swap. No Python loop over particles and no copy to the host happens inside the
substep loop. Per frame the state is copied to NumPy once for the metrics (``physics.metrics``)
and the stability check: a non-finite or exploded state is redone with the step halved, and in
the end stops the run (``UnstableError``, exit code 3) before anything of that frame is written.
The guards the scene declares redo a frame at smaller steps and keep its best try
(``physics.redo_guards``, mixed in).
"""

import dataclasses
import sys
import time

import numpy as np
import taichi as ti

from taichi_cloth.cloth.garment import build_garment
from taichi_cloth.config.scene import Scene, load_scene
from taichi_cloth.effects import EffectContext, build_effects, model_options, post_step_of
from taichi_cloth.errors import UnstableError
from taichi_cloth.physics.control import Control
from taichi_cloth.physics.forces import Forces
from taichi_cloth.physics.integrators import INTEGRATORS, make_integrator
from taichi_cloth.physics.intersections import IntersectionCounter
from taichi_cloth.physics.metrics import (FrameMetrics, RunRecord, largest_stretch_strain,
                                          run_stats, spring_energy, state_problem,
                                          surface_penetration)
from taichi_cloth.physics.model import Model
from taichi_cloth.physics.packed_grid import packed_grid_for
from taichi_cloth.physics.redo_guards import RedoGuards
from taichi_cloth.physics.rig import BodyRig
from taichi_cloth.physics.snapshot import Snapshot
from taichi_cloth.physics.timestep import TimeStep, choose_time_step
from taichi_cloth.runtime import start_taichi

class Simulation(RedoGuards):
    """Everything a scene needs to run: rig, model, control, effects, forces, integrator, states,
    time step (module docstring)."""

    def __init__(self, scene: Scene):
        start_taichi(scene.simulation.arch)
        self.scene = scene
        self.frame_duration = 1.0 / scene.scene.fps  # [s]
        self.body_rig = BodyRig(scene) if scene.body is not None else None
        waist_height = self.body_rig.waist_height if self.body_rig is not None else None
        self.garment = build_garment(scene.cloth, scene.material, waist_height, scene.path)
        self.surface_edges = self.garment.edges
        self.intersections = IntersectionCounter(self.garment.triangles,
                                                 self.garment.particle_count)
        if not self.garment.is_grid:  # a mesh from a file: say if it is tangled at rest
            tangled = self.intersections.count(self.garment.positions)
            if tangled:
                print(f"warning: {scene.path}: cloth.mesh: {tangled} pairs of its triangles pass "
                      f"through each other at rest; the cloth starts tangled there",
                      file=sys.stderr)
        self.guards_crossings = "self_collision" in scene.effects  # ``guarded_frame``
        # the limits of the redo guards that the scene sets (``_advance_refining``)
        self.redo_limits = {name: limit for name, limit in (
            ("strain", scene.simulation.redo_strain),
            ("penetration", scene.simulation.redo_penetration)) if limit > 0}
        self._crossings = None  # crossing pairs in the current state, when counted
        self._measured = None  # the redo guards' measures of the current state, when taken
        self._backed_up_integrator = {}  # the integrator's memory at the frame's start
        self.settle_report = None  # what ``settling.settle`` did (a resumed run copies it back)
        self.model = Model(self.garment, scene.simulation.precision,
                           **model_options(scene.effects))
        if self.body_rig is not None:
            self.control = self.body_rig.make_control(self.garment.pinned,
                                                      self.garment.positions, self.model.real)
        else:
            self.control = Control(self.garment.pinned, self.garment.positions, self.model.real)
        integrator_class = INTEGRATORS[scene.simulation.integrator]
        self.effects = build_effects(scene.effects, EffectContext(
            self.model, self.control, integrator_class.uses_jacobian))
        self.control.upload(self.model.uploads)
        for effect in self.effects:
            effect.upload()
        self.forces = Forces(self.model, self.effects,
                             packed_grid_for(self.model, integrator_class.packs_springs,
                                             self.effects))
        self.integrator = make_integrator(scene.simulation.integrator, self.forces, self.control,
                                          post_step_of(self.effects), scene.simulation)
        # scratch for ``total_forces``, allocated before the states send the model's uploads
        self.force_scratch = ti.Vector.field(3, self.model.real, self.model.particle_count)
        self.states = self.model.states(3)  # state_in, state_out and the backup of a redo
        self.state_in, self.state_out, self.backup = self.states.members
        self._compiled_variants = set()
        self.time_step = self._choose_time_step()
        # the step again if that changed an effect's stiffness, so its report holds what the
        # kernels use (the same dt); then the effects set for the run's step (``_follow_redo``)
        if any([effect.fit_time_step(self.time_step, scene.simulation.integrator)
                for effect in self.effects]):
            self.time_step = self._choose_time_step()
        self._follow_redo(0)

    @classmethod
    def from_scene(cls, scene: Scene | str, overrides: tuple[str, ...] = ()) -> "Simulation":
        """The simulation of ``scene``: a loaded ``Scene``, or a scene name or file with
        ``--set`` style overrides (``config.scene.load_scene``)."""
        if isinstance(scene, str):
            scene = load_scene(scene, tuple(overrides))
        return cls(scene)

    def _choose_time_step(self) -> TimeStep:
        scene, garment, model = self.scene, self.garment, self.model
        contact_modes, bounding_modes = [], {}
        for effect in self.effects:
            modes = effect.stability_modes()
            contact_modes += modes
            if effect.bounds_given_step:
                bounding_modes[effect.name] = modes
        return choose_time_step(
            scene.simulation.dt, self.frame_duration, scene.simulation.integrator,
            garment.positions, model.host_spring_ends, model.host_stiffness, garment.mass,
            ~garment.pinned, model.dashpot_time or 0.0, contact_modes, scene.simulation.safety,
            self.forces.coupled_effects, self._pin_drive, bounding_modes)

    def _pin_drive(self) -> tuple[float, float]:
        """(the largest acceleration [m/s²] of the pins the body carries during the scene's
        dance, the median rest length [m] of the stretch springs that hang from a pin, one end
        pinned); (0, 0) without such pins."""
        if self.body_rig is None:
            return 0.0, 0.0
        acceleration = self.body_rig.peak_pin_acceleration(self.scene.scene.duration)
        ends = self.model.host_spring_ends[:self.model.stretch_count]
        hanging = self.garment.pinned[ends].sum(axis=1) == 1
        if acceleration == 0 or not hanging.any():
            return 0.0, 0.0
        return acceleration, float(np.median(
            self.model.host_rest_length[:self.model.stretch_count][hanging]))

    def set_time_step(self, dt: float, substeps_per_frame: int) -> None:
        """Step with dt [s], ``substeps_per_frame`` of them per frame (dt · substeps = the frame's
        duration); what ``dt = "auto"`` estimated is kept for the report."""
        self.time_step = dataclasses.replace(self.time_step, dt=dt,
                                             substeps_per_frame=substeps_per_frame)

    @property
    def effect_names(self) -> list[str]:
        return self.forces.compiled_names

    def frame_time(self, frame: int) -> float:
        """Simulated time [s] of ``frame``: frame 0 is the start (t = 0), frame k is k/fps."""
        return frame / self.scene.scene.fps

    def host_state(self) -> tuple[np.ndarray, np.ndarray]:
        """Host copies of the current positions [m] and velocities [m/s], (N, 3) float64."""
        return self.states.read(self.state_in)

    def positions(self) -> np.ndarray:
        return self.host_state()[0]

    def total_forces(self) -> np.ndarray:
        """Every particle's total force [N] (N, 3) at the current state, at t = 0."""
        self.forces.evaluate(self.state_in.x, self.state_in.v, 0.0, self.force_scratch)
        return self.force_scratch.to_numpy().astype(np.float64)

    def snapshot(self, effects: bool = False) -> Snapshot:
        """Host copies of the current state, time step and integrator memory; with
        ``effects`` also what the effects carry (a run's checkpoint: resumed, it goes on
        bit for bit)."""
        effect_memory = {f"{effect.name}.{key}": value for effect in self.effects
                         for key, value in effect.memory().items()} if effects else {}
        return Snapshot(*self.host_state(), dt=self.time_step.dt,
                        substeps_per_frame=self.time_step.substeps_per_frame,
                        integrator_memory=self.integrator.memory(), effect_memory=effect_memory)

    def restore(self, snapshot: Snapshot) -> None:
        """Put a ``snapshot`` back: the next frame continues exactly from it (the effects'
        history from scratch where it holds none)."""
        self.states.write(self.state_in, snapshot.positions, snapshot.velocities)
        self.set_time_step(snapshot.dt, snapshot.substeps_per_frame)
        self.integrator.restore_memory(snapshot.integrator_memory)
        self.forget_crossings()
        for effect in self.effects:
            prefix = f"{effect.name}."
            memory = {key[len(prefix):]: value for key, value in snapshot.effect_memory.items()
                      if key.startswith(prefix)}
            if memory:
                effect.restore_memory(memory)

    def forget_crossings(self) -> None:
        """The positions were set from outside: crossings counted and measures taken afresh,
        effects' history gone."""
        self._crossings = self._measured = None
        for effect in self.effects:
            effect.forget_history()

    def _back_up(self) -> None:
        """The state and what the effects and the integrator carry from step to step (the
        implicit one's warm start), kept for a redone frame."""
        self.states.copy(self.backup, self.state_in)
        self._backed_up_integrator = self.integrator.memory()
        for effect in self.effects:
            effect.back_up()

    def _roll_back(self) -> None:
        """The state of the last ``_back_up`` put back, and what the effects and the
        integrator carried then: each try of a frame starts from the same."""
        self.states.copy(self.state_in, self.backup)
        self.integrator.restore_memory(self._backed_up_integrator)
        for effect in self.effects:
            effect.roll_back()

    def mean_free_speed(self, v: np.ndarray) -> float:
        """Mean speed [m/s] of the free (unpinned) particles at velocities v (N, 3)."""
        free = ~self.garment.pinned
        return float(np.mean(np.linalg.norm(v[free], axis=1))) if free.any() else 0.0

    def surface_depth(self, x: np.ndarray) -> np.ndarray:
        """How deep [m] each surface sample of the cloth at x lies in the colliders
        (``metrics.surface_penetration``)."""
        return surface_penetration(self.effects, x, self.surface_edges, self.garment.triangles)

    def measure(self, frame: int, x: np.ndarray, v: np.ndarray, crossings: int | None = None,
                halvings: dict | None = None, strain: float | None = None,
                depth: np.ndarray | None = None) -> FrameMetrics:
        """Metrics of a (checked) state x [m], v [m/s] at ``frame``: energies (kinetic;
        potential = the effects' + the springs'), strain, penetration of the whole surface
        (particles, edge midpoints and triangle centroids: ``metrics.surface_samples``) into
        every collider, mean speed, pairs of triangles through each other
        (``intersections``; ``crossings`` when already counted), centre of mass; the frame's
        ``halvings`` of each redo guard on. ``strain``, ``depth``: x's largest stretch strain and
        its samples' depths (``surface_depth``) if taken."""
        mass = self.model.host_mass
        kinetic = 0.5 * float(np.sum(mass * np.sum(v * v, axis=1)))
        energies = [effect.potential_energy(x, mass) for effect in self.effects]
        potential = sum(energies) + spring_energy(self.model, x)
        depth = self.surface_depth(x) if depth is None else depth
        extra = {name: value for effect, energy in zip(self.effects, energies)
                 for name, value in effect.frame_metrics(x, energy).items()}
        for guard in (["tunnelling"] if self.guards_crossings else []) + list(self.redo_limits):
            extra[f"{guard}_halvings"] = (halvings or {}).get(guard, 0)
        return FrameMetrics(
            frame=frame, t=self.frame_time(frame), kinetic_energy=kinetic,
            potential_energy=potential,
            max_strain=largest_stretch_strain(self.model, x) if strain is None else strain,
            max_penetration=float(depth.max(initial=0.0)),
            penetrating_samples=int(np.count_nonzero(depth)),
            mean_speed=self.mean_free_speed(v),
            self_intersections=self.intersections.count(x) if crossings is None else crossings,
            center_of_mass=[float(c) for c in np.sum(mass[:, None] * x, 0) / np.sum(mass)],
            extra=extra)

    def guarded_frame(self, frame: int, record: RunRecord,
                      still: bool = False) -> FrameMetrics | None:
        """Advance to ``frame`` and check it; its metrics (``measure``), or None for a settling
        frame (``still``: ``physics.settling``, which takes what it needs itself). A bad
        frame is rolled back and retried with the step halved (the smaller step is kept for the
        rest of the run), up to ``simulation.max_retries`` times; then ``UnstableError``.
        Nothing non-finite leaves. With self-collision declared or ``simulation.redo_strain`` or
        ``redo_penetration`` set, each try is itself refined (``_advance_refining``)."""
        self._back_up()
        self._measure_start()
        for attempt in range(self.scene.simulation.max_retries + 1):
            problem, x, v, crossings, halvings, strain, depth = self._advance_refining(
                frame, record, still)
            if problem is None:
                return None if still else self.measure(frame, x, v, crossings, halvings, strain,
                                                       depth)
            if attempt == self.scene.simulation.max_retries:
                break
            record.retries += 1
            self._roll_back()
            self.set_time_step(self.time_step.dt / 2, 2 * self.time_step.substeps_per_frame)
        integrator = self.scene.simulation.integrator
        if self.time_step.requested == "auto":  # the step it failed at, halvings included
            advice = f"set simulation.dt below {self.time_step.dt:.3g} s"
        else:
            advice = "lower simulation.dt or set it to \"auto\""
        if integrator != "implicit":
            advice += ", or use integrator = \"implicit\""
        if integrator == "euler":
            advice += "; explicit Euler also needs [effects.damping]"
        halvings = f" after {record.retries} halvings of the step" if record.retries else ""
        where = "settling" if still else f"frame {frame}"
        raise UnstableError(f"{where}: the cloth {problem} with integrator '{integrator}' "
                            f"at dt = {self.time_step.dt:.6g} s{halvings}; {advice}", frame)

    def _follow_redo(self, halvings: int) -> None:
        """Tell every effect that the frame is tried at the run's step over 2^``halvings`` of
        the tunnelling guard (0: the run's step; ``Effect.follow_redo``)."""
        for effect in self.effects:
            effect.follow_redo(halvings)

    def _end_state(self):
        """(x [m], v [m/s], x's largest stretch strain or None, ``metrics.state_problem``)
        now."""
        x, v = self.host_state()
        strain = largest_stretch_strain(self.model, x) if np.isfinite(x).all() else None
        return x, v, strain, state_problem(self.model, self.scene.simulation, x, v, strain)

    def advance_frame(self, frame: int, record: RunRecord, still: bool = False) -> None:
        """The substeps to ``frame`` (≥ 1: t from (frame − 1)/fps to frame/fps), one kernel
        launch per entry of ``Integrator.launch_counts``; ``still``: the body held at its pose
        at t = 0 instead (``settle``). The first launch of each kernel variant compiles it: its
        wall time goes to ``compile``, the rest to ``simulate``."""
        if self.body_rig is not None:
            self.body_rig.prepare_frame(frame - 1, still)
        dt, substeps = self.time_step.dt, self.time_step.substeps_per_frame
        done = 0
        for count in self.integrator.launch_counts(substeps):
            t = self.frame_time(frame - 1) + done * dt
            variant = self.integrator.kernel_variant(count, self.state_in, self.state_out)
            started = time.perf_counter()
            self.state_in, self.state_out = self.integrator.launch(
                self.state_in, self.state_out, t, dt, count)
            if variant not in self._compiled_variants:
                ti.sync()
                self._compiled_variants.add(variant)
                record.wall_seconds["compile"] += time.perf_counter() - started
            else:
                record.wall_seconds["simulate"] += time.perf_counter() - started
            done += count
        started = time.perf_counter()
        ti.sync()
        record.wall_seconds["simulate"] += time.perf_counter() - started

    def run(self, frame_count: int, on_frame=None, record: RunRecord | None = None,
            first_frame: int = 0) -> RunRecord:
        """Frames ``first_frame`` … ``frame_count`` into ``record`` (a new one if None: pass
        your own to keep what was measured when a run is interrupted): frame 0 is the state as
        it is (t = 0, measured, nothing simulated), frame k ≥ 1 is simulated from the state of
        frame k − 1, which must be the current state; ``on_frame(frame, metrics)`` after each."""
        record = RunRecord() if record is None else record
        for frame in range(first_frame, frame_count + 1):
            if frame == 0:
                x, v, strain, problem = self._end_state()
                if problem is not None:
                    raise UnstableError(f"frame 0: the starting cloth {problem}", 0)
                metrics = self.measure(0, x, v, strain=strain)
            else:
                metrics = self.guarded_frame(frame, record)
            iterations = self.integrator.take_iterations()
            if iterations:
                record.cg_iterations.extend(iterations)
                metrics.cg_iterations = float(np.mean(iterations))
            record.frames.append(metrics)
            if on_frame is not None:
                on_frame(frame, metrics)
        return record

    def stats(self, record: RunRecord) -> dict:
        """The ``stats.json`` document (README, "Outputs"): ``metrics.run_stats``."""
        return run_stats(self, record)
