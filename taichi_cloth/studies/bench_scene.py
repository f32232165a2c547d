"""The scene parts of ``bench`` (``--scene``): each effect's cost, the spring and contact passes on
their own, and a whole scene's simulated seconds per wall second (``studies/bench.py`` has the
reference sheet and the report)."""

import statistics
import time

import taichi as ti

from taichi_cloth.effects import EFFECTS
from taichi_cloth.errors import InputError
from taichi_cloth.studies.timing import substep_row, timed_rate


@ti.data_oriented
class PassTimer:
    """Kernels that run one pass of a simulation ``count`` times: the spring pass (grid
    cloth: pack + SIMD stencil; otherwise the CSR gather) and the contact pass (pose the
    capsules, then every particle's contact force). Loops are serial when the integrator's
    are, like the substep they come from."""

    def __init__(self, simulation):
        self.simulation = simulation
        self.forces = simulation.forces
        self.model = simulation.model
        self.serial = simulation.integrator.serial
        self.out = ti.Vector.field(3, self.model.real, self.model.particle_count)
        contacts = [e for e in simulation.effects if e.name == "collision"]
        self.contact = contacts[0] if contacts else None
        self.has_contact = self.contact is not None

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

    @ti.kernel
    def _run(self, state: ti.template(), t: ti.f64, count: ti.i32, which: ti.template()):
        ti.loop_config(serialize=ti.static(self.serial))
        for _ in range(count):
            if ti.static(which == "springs"):
                self._springs(state)
            else:
                self._contact(state, t)

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


def bench_effects(scene_name: str, seconds: float, repeats: int) -> list[dict]:
    """The cost of each effect: the scene with and without it (added with its defaults when the
    scene lacks it and can have it), in microseconds per substep and nanoseconds per
    particle-substep."""
    base = scene_simulation(scene_name)
    base_rates = frame_rate(base, seconds, repeats)
    base_rate = statistics.median(base_rates)
    particles = base.model.particle_count
    size = f"{base.garment.columns}x{base.garment.rows}"
    integrator = base.scene.simulation.integrator
    rows = [substep_row("scene", integrator, size, particles, base_rates,
                        scene=scene_name, effects=base.effect_names)]
    for name in (effect.name for effect in EFFECTS):
        declared = name in base.scene.effects
        try:
            other = scene_simulation(scene_name,
                                     (f"effects.{name}={'false' if declared else 'true'}",))
        except InputError:  # the scene cannot have it (collision without a body, ...)
            continue
        other_rates = frame_rate(other, seconds, repeats)
        with_rate, without_rate = (base_rate, statistics.median(other_rates)) if declared \
            else (statistics.median(other_rates), base_rate)
        cost = 1.0 / with_rate - 1.0 / without_rate
        rows.append(substep_row("effect", integrator, size, particles, other_rates,
                                scene=scene_name, effect=name, declared_in_scene=declared,
                                substeps_per_second_with=with_rate,
                                substeps_per_second_without=without_rate,
                                cost_us_per_substep=round(1e6 * cost, 3),
                                cost_ns_per_particle_substep=round(1e9 * cost / particles, 3)))
    return rows


def bench_passes(scene_name: str, seconds: float, repeats: int) -> dict:
    """The spring pass and the contact pass of the scene on their own, seconds per pass."""
    simulation = scene_simulation(scene_name)
    timer = PassTimer(simulation)
    springs = timer.seconds_per_pass("springs", seconds, repeats)
    contact = timer.seconds_per_pass("contact", seconds, repeats) if timer.has_contact else 0.0
    return {"benchmark": "passes", "scene": scene_name,
            "integrator": simulation.scene.simulation.integrator,
            "size": f"{simulation.garment.columns}x{simulation.garment.rows}",
            "particles": simulation.model.particle_count,
            "substeps_per_second": 1.0 / (springs + contact),
            "particle_substeps_per_second": simulation.model.particle_count / (springs + contact),
            "springs_us_per_substep": round(1e6 * springs, 3),
            "contact_us_per_substep": round(1e6 * contact, 3)}


def bench_scene_run(scene_name: str) -> dict:
    """The whole scene, every frame, as ``simulate`` runs it: simulated seconds per wall
    second, compilation excluded."""
    simulation = scene_simulation(scene_name)
    frames = simulation.scene.frame_count
    started = time.perf_counter()
    record = simulation.run(frames)
    wall = time.perf_counter() - started - record.wall_seconds["compile"]
    simulated = frames / simulation.scene.scene.fps
    substeps = frames * simulation.time_step.substeps_per_frame
    return {"benchmark": "scene-run", "scene": scene_name,
            "integrator": simulation.scene.simulation.integrator,
            "size": f"{simulation.garment.columns}x{simulation.garment.rows}",
            "particles": simulation.model.particle_count,
            "substeps_per_second": substeps / wall,
            "particle_substeps_per_second": substeps * simulation.model.particle_count / wall,
            "frames": frames, "dt": simulation.time_step.dt, "simulated_seconds": simulated,
            "wall_seconds": round(wall, 3),
            "compile_seconds": round(record.wall_seconds["compile"], 3),
            "simulated_seconds_per_wall_second": simulated / wall}
