"""``python -m taichi_cloth bench``: how fast a substep is, measured (never asserted in a test).

Reference problem (the sizes table), chosen so the figures compare with other simulators'
published cloth benchmarks: a square sheet of n × n particles 1 cm apart, lying flat and pinned
along one edge, stretch + shear + bend springs (12 per interior particle), gravity only, no
dashpots, float32, dt = 1/1920 s. Its fabric (130 g/m², 10 N/m stretch, 2 N/m shear, 1 N/m bend
springs) keeps symplectic Euler stable at that step for every n, since a square grid's spring
constants and the particle mass do not depend on n (``materials.py``). The sheet swings down.

Every figure is a rate over timed repeats of at least ``--seconds`` each, after a warm-up that
compiles the kernels (compile time excluded); the table shows the median repeat. ``NumpyCloth``
(``studies/numpy_cloth.py``) runs the same symplectic Euler step in NumPy as the baseline; the
tests use it as the oracle of the force kernel. The scene parts are in ``studies/bench_scene.py``.

Real scenes (``--scene``, a comma list; by default ``REAL_SCENES``): each with every integrator
(its own at the scene's step, the others at their auto step, all from the state the scene
settles into: particle-substeps per second and wall seconds per simulated second), and its whole run as ``simulate`` does it (start-up,
compile and settling timed apart); for ``hula`` (or every scene named with ``--scene``) also
the cost of each effect, from the scene with and without it measured in turns on the same
frame from the same settled state, backward Euler's CG held at the same iterations a step (an
effect the scene lacks is added with its defaults; a cost within the noise is reported as such,
never negative; the iterations an effect adds or saves are reported apart), and the spring and
contact passes on their own; by default also ``hula`` at 128 × 56. A scene that declares
self-collision is run whole a second time without it (``effects.self_collision=false``), and
the difference in stepping seconds per step is what self-collision costs over the run, its
list's rebuilds included, beside the spring pass (the issue's measure: the passes above time
it from one settled state only; the two runs take different paths, so the figure is rough).
"""

import time

import numpy as np
import taichi as ti

from taichi_cloth.effects.gravity import Gravity, GravitySettings
from taichi_cloth.physics.forces import Forces
from taichi_cloth.cloth.garment import build_garment
from taichi_cloth.physics.integrators import INTEGRATORS, make_integrator
from taichi_cloth.config.materials import Material
from taichi_cloth.physics.model import Model
from taichi_cloth.runtime import start_taichi, taichi_threads
from taichi_cloth.config.scene import load_scene, refuse_lab_specimen
from taichi_cloth.config.tables import ClothConfig
from taichi_cloth.physics.control import Control
from taichi_cloth.physics.packed_grid import packed_grid_for
from taichi_cloth.studies.bench_scene import (bench_effects, bench_passes, bench_scene_integrators,
                                              bench_scene_run)
from taichi_cloth.studies.numpy_cloth import NumpyCloth
from taichi_cloth.studies.timing import substep_row, timed_rate

REFERENCE_SPACING_M = 0.01
REFERENCE_DT_S = 1.0 / 1920.0
REFERENCE_MATERIAL = Material("reference", density=0.13, stretch_stiffness=10.0,
                              shear_stiffness=2.0, bend_stiffness=1e-4, damping=0.0,
                              thickness=4e-4, description="bench: stable at 1/1920 s")
DEFAULT_SIZES = (32, 64, 128, 256, 512)
DEFAULT_INTEGRATORS = ("symplectic", "euler", "rk4", "implicit")
REAL_SCENES = ("hula", "hula-paper", "flag", "drape")
FINE_HULA = ("cloth.resolution=[128, 56]",)
IMPLICIT_FRAME_SIZE = 64
IMPLICIT_FRAME_DT_S = 1.0 / 60.0


def reference_cloth(size: int) -> ClothConfig:
    """The reference sheet of size × size particles (stretch, shear and skip-one bend springs:
    the peers' mass-spring cloth)."""
    side = REFERENCE_SPACING_M * (size - 1)
    return ClothConfig(shape="sheet", resolution=(size, size), size=(side, side), height=1.0,
                       orientation="horizontal", pin="top-edge", bending="springs")


def reference_model(size: int) -> Model:
    """The reference sheet's model: float32, no dashpots."""
    return Model(build_garment(reference_cloth(size), REFERENCE_MATERIAL), "f32", None)


def bench_reference(size: int, integrator_name: str, seconds: float, repeats: int,
                    dt: float = REFERENCE_DT_S) -> dict:
    """The reference sheet with one integrator: substeps per second."""
    model = reference_model(size)
    packed = packed_grid_for(model, INTEGRATORS[integrator_name].packs_springs)
    forces = Forces(model, [Gravity(GravitySettings())], packed)
    control = Control(model.garment.pinned, model.garment.positions, model.real)
    control.upload(model.uploads)
    integrator = make_integrator(integrator_name, forces, control)
    states = list(model.states(2).members)
    batch = max(1, min(256, round(2e6 / model.particle_count)))
    clock = [0.0]

    def run_batch():
        states[:] = integrator.advance(states[0], states[1], clock[0], dt, batch)
        clock[0] += batch * dt
        ti.sync()

    started = time.perf_counter()
    run_batch()  # compiles
    compile_seconds = time.perf_counter() - started
    run_batch()
    rates = timed_rate(run_batch, batch, seconds, repeats)
    finite = bool(np.isfinite(states[0].x.to_numpy()).all())
    return substep_row("reference", integrator_name, size, model.particle_count, rates,
                       dt=dt, finite=finite, compile_seconds=round(compile_seconds, 3),
                       threads="serial" if getattr(integrator, "serial", False) else "parallel")


def bench_numpy(size: int, seconds: float, repeats: int) -> dict:
    """The reference sheet stepped by ``NumpyCloth``."""
    model = reference_model(size)
    cloth = NumpyCloth(model, GravitySettings().g)
    state = [model.garment.positions.astype(np.float32),
             np.zeros((model.particle_count, 3), np.float32)]

    def run_batch():
        state[:] = cloth.step(state[0], state[1], REFERENCE_DT_S)

    run_batch()
    rates = timed_rate(run_batch, 1, seconds, repeats)
    return substep_row("reference", "numpy-symplectic", size, model.particle_count, rates,
                       dt=REFERENCE_DT_S, finite=bool(np.isfinite(state[0]).all()))


def scaling_exponent(rows: list[dict]) -> dict:
    """Per integrator, p in (seconds per substep) ∝ particles^p by least squares on logs
    (p = 1: cost linear in the particle count), and the seconds per particle-substep of the
    largest size."""
    fits = {}
    for name in dict.fromkeys(r["integrator"] for r in rows):
        own = [r for r in rows if r["integrator"] == name]
        if len(own) < 2:
            continue
        log_n = np.log([r["particles"] for r in own])
        log_cost = np.log([1.0 / r["substeps_per_second"] for r in own])
        exponent = float(np.polyfit(log_n, log_cost, 1)[0])
        largest = max(own, key=lambda r: r["particles"])
        fits[name] = {"exponent": round(exponent, 3),
                      "ns_per_particle_substep_at_largest":
                          round(1e9 / largest["particle_substeps_per_second"], 3),
                      "sizes": [r["size"] for r in own]}
    return fits


def bench_implicit_frames(seconds: float, repeats: int) -> dict:
    """Backward Euler on the 64 × 64 reference sheet at dt = 1/60 s."""
    row = bench_reference(IMPLICIT_FRAME_SIZE, "implicit", seconds, repeats, IMPLICIT_FRAME_DT_S)
    row["benchmark"] = "implicit-large-step"
    row["simulated_seconds_per_wall_second"] = row["substeps_per_second"] * IMPLICIT_FRAME_DT_S
    return row


def format_rate(value: float) -> str:
    return f"{value:.3g}"


def table(rows: list[dict]) -> str:
    """The sizes table: particle-substeps per second, integrators across, sizes down."""
    reference = [r for r in rows if r["benchmark"] == "reference"]
    if not reference:
        return ""
    integrators = list(dict.fromkeys(r["integrator"] for r in reference))
    sizes = list(dict.fromkeys(r["size"] for r in reference))
    lines = ["particle-substeps per second (reference sheet, f32, dt = 1/1920 s; substeps/s in "
             "brackets)",
             f"{'size':>9} {'particles':>9} " + " ".join(f"{name:>22}" for name in integrators)]
    for size in sizes:
        cells = []
        for name in integrators:
            match = [r for r in reference if r["size"] == size and r["integrator"] == name]
            cells.append(f"{format_rate(match[0]['particle_substeps_per_second'])} "
                         f"({format_rate(match[0]['substeps_per_second'])})" if match else "-")
        particles = next(r["particles"] for r in reference if r["size"] == size)
        lines.append(f"{f'{size}x{size}':>9} {particles:>9} "
                     + " ".join(f"{cell:>22}" for cell in cells))
    return "\n".join(lines)


def report(rows: list[dict], fits: dict) -> str:
    """The console report: the sizes table, the scaling fits and the scene parts."""
    parts = [table(rows)]
    if fits:
        parts.append("cost ∝ particles^p (least squares on logs): " + ", ".join(
            f"{name} p = {fit['exponent']:.2f} ({fit['ns_per_particle_substep_at_largest']:.3g} "
            f"ns per particle-substep at {fit['sizes'][-1]}²)" for name, fit in fits.items()))
    for row in rows:
        kind = row["benchmark"]
        if kind == "scene":
            parts.append(f"{row['scene']} ({row['size']}, {row['integrator']}, "
                         f"{', '.join(row['effects'])}): "
                         f"{format_rate(row['substeps_per_second'])} substeps/s on frame "
                         f"{row['frame']}, each effect's cost on it from the same state"
                         + (f", CG held at {row['cg_iterations_held']} iterations a step"
                            if "cg_iterations_held" in row else ""))
        elif kind == "effect":
            state = "declared" if row["declared_in_scene"] else "added"
            low, high = row["interval_us_per_substep"]
            if row["cost_us_per_substep"] is not None:
                cost = f"{row['cost_us_per_substep']:8.2f} µs per substep, " \
                    f"{row['cost_ns_per_particle_substep']:7.2f} ns per particle-substep"
            elif row["faster_with_effect"]:
                cost = f"no cost: the substep is {-high:.2f} to {-low:.2f} µs faster with it"
            else:
                cost = f"below the noise (at most {row['noise_us_per_substep']:.2f} µs per " \
                    "substep)"
            if "cg_iterations_held" in row:
                cost += (f"; CG iterations a step {row['cg_iterations_with']:.1f} with it, "
                         f"{row['cg_iterations_without']:.1f} without")
            parts.append(f"  effect {row['effect']:<10} ({state}): {cost}")
        elif kind == "scene-integrator":
            if "no_stable_step" in row:
                parts.append(f"{row['scene']:>10} {row['integrator']:<11} no stable auto step")
            else:
                mark = " (shipped)" if row["shipped"] else ""
                parts.append(f"{row['scene']:>10} {row['integrator']:<11} {row['size']:>7} "
                             f"dt {row['dt']:.3g} s: "
                             f"{format_rate(row['particle_substeps_per_second'])} "
                             f"particle-substeps/s, {row['wall_seconds_per_simulated_second']:.3g} "
                             f"wall s per simulated s{mark}")
        elif kind == "passes":
            self_collision = "" if "self_collision_us_per_substep" not in row else (
                f", self-collision {row['self_collision_us_per_substep']:.2f} µs "
                f"({row['self_collision_rebuilt_us_per_substep']:.2f} µs when its lists are "
                f"rebuilt)")
            parts.append(f"{row['scene']} passes: springs {row['springs_us_per_substep']:.2f} µs, "
                         f"contact {row['contact_us_per_substep']:.2f} µs{self_collision} "
                         f"per substep")
        elif kind == "scene-run":
            parts.append(f"{row['scene']} ({row['size']}, {row['integrator']}) whole run: "
                         f"{row['simulated_seconds']:.3g} s simulated in "
                         f"{row['wall_seconds']:.2f} s wall "
                         f"({row['wall_seconds_per_simulated_second']:.2f} per simulated s): "
                         f"stepping {row['stepping_seconds']:.2f} s, each frame's checks and "
                         f"metrics {row['checks_seconds']:.2f} s; "
                         f"start-up {row['startup_seconds']:.2f} s, compile "
                         f"{row['compile_seconds']:.2f} s, settling {row['settle_seconds']:.2f} s; "
                         f"self-intersection count {row['self_intersection_ms_per_frame']:.2f} ms "
                         f"per frame (at most {row['max_self_intersections']} pairs)"
                         + (f"; self-collision's list built {row['self_collision_builds']} "
                            f"times in {row['steps']} steps" if "steps" in row else ""))
        elif kind == "self-collision-run":
            springs = "" if "springs_us_per_substep" not in row else (
                f" (the spring pass: {row['springs_us_per_substep']:.2f} µs)")
            parts.append(f"{row['scene']} self-collision over the whole run: "
                         f"{row['us_per_step']:.1f} µs a step{springs}, stepping "
                         f"{row['stepping_seconds_with']:.2f} s with it and "
                         f"{row['stepping_seconds_without']:.2f} s without in {row['steps']} "
                         f"steps (two runs on different paths: a rough figure)")
        elif kind == "implicit-large-step":
            parts.append(f"implicit, {row['size']}x{row['size']} sheet, dt = 1/60 s: "
                         f"{format_rate(row['substeps_per_second'])} steps/s = "
                         f"{row['simulated_seconds_per_wall_second']:.2f} simulated seconds per "
                         f"wall second")
    return "\n".join(p for p in parts if p)


def run_bench(sizes, integrators, scene_names, seconds: float, repeats: int,
              arch: str = "cpu", progress=None, profile: bool = False,
              threads: int | None = None) -> tuple[list[dict], dict]:
    """Rows of every requested part and the scaling fits. ``sizes``/``integrators`` None and
    ``scene_names`` None: everything (the default sizes and integrators, ``REAL_SCENES``, hula's
    effects and passes, hula at 128 × 56, the implicit large step); given sizes or integrators
    alone: the sizes table only; scenes: their parts only (effects and passes too), with
    integrators their integrator rows for those alone, and the sizes table only if sizes are
    given. threads: Taichi's CPU thread count (None: one per core)."""
    start_taichi(arch, kernel_profiler=profile, threads=threads)
    everything = sizes is None and integrators is None and scene_names is None
    rows = []
    say = progress or (lambda message: None)
    if everything or sizes is not None or (integrators is not None and scene_names is None):
        for size in sizes or DEFAULT_SIZES:
            for name in integrators or DEFAULT_INTEGRATORS:
                say(f"{name} {size}x{size}")
                rows.append(bench_reference(size, name, seconds, repeats))
            say(f"numpy {size}x{size}")
            rows.append(bench_numpy(size, seconds, repeats))
    if everything or scene_names is not None:
        for name in scene_names or REAL_SCENES:
            passes = None
            if scene_names is not None or name == "hula":
                say(f"{name}: effects")
                rows.extend(bench_effects(name, seconds, repeats))
                say(f"{name}: passes")
                passes = bench_passes(name, seconds, repeats)
                rows.append(passes)
            say(f"{name}: " + ("every integrator" if integrators is None
                               else ", ".join(integrators)))
            rows.extend(bench_scene_integrators(name, seconds, repeats, integrators))
            say(f"{name}: whole run")
            whole = bench_scene_run(name)
            rows.append(whole)
            if "self_collision" in load_scene(name).effects:
                say(f"{name}: whole run without self-collision")
                rows.append(self_collision_run_cost(whole, bench_scene_run(
                    name, ("effects.self_collision=false",)), passes))
    if everything:
        say("hula at 128x56: whole run")
        rows.append(bench_scene_run("hula", FINE_HULA))
        say("implicit 64x64 at 1/60 s")
        rows.append(bench_implicit_frames(seconds, repeats))
    return rows, scaling_exponent([r for r in rows if r["benchmark"] == "reference"])


def self_collision_run_cost(with_it: dict, without: dict, passes: dict | None) -> dict:
    """The row of what self-collision costs a step over a whole run: a scene's whole run
    ``with_it`` against ``without`` it, in stepping seconds per step, with the spring pass of
    the scene's ``passes`` row when it has one (None)."""
    steps = with_it["steps"]  # the frames' steps at the scene's step (a redone frame's not)
    return {"benchmark": "self-collision-run", "scene": with_it["scene"],
            "stepping_seconds_with": with_it["stepping_seconds"],
            "stepping_seconds_without": without["stepping_seconds"], "steps": steps,
            "us_per_step": round(1e6 * (with_it["stepping_seconds"]
                                        - without["stepping_seconds"]) / steps, 1),
            **({"springs_us_per_substep": passes["springs_us_per_substep"]}
               if passes is not None else {})}


def rows_document(rows: list[dict], fits: dict) -> list[dict]:
    """The JSON file: the rows, then one row per scaling fit."""
    return rows + [{"benchmark": "scaling", "integrator": name, **fit}
                   for name, fit in fits.items()]


def bench_command(sizes: str | None, integrators: str | None, scenes: str | None,
                  json_path: str | None, seconds: float, repeats: int, arch: str,
                  quiet: bool, profile: bool = False, threads: int | None = None) -> int:
    """The ``bench`` command: the report on the console, the rows as JSON to ``json_path``
    (with a first row naming the backend and its CPU thread count)."""
    from pathlib import Path

    from taichi_cloth.errors import InputError
    from taichi_cloth.flags import choice_list, number_list
    from taichi_cloth.output.files import write_json
    size_list = number_list(sizes, "--sizes", int, 4, "particles per side") \
        if sizes is not None else None
    integrator_list = choice_list(integrators, "--integrators", INTEGRATORS, "integrator") \
        if integrators is not None else None
    if not (0 < seconds < 3600) or repeats < 1:  # also refuses nan
        raise InputError("--seconds must be between 0 and 3600 and --repeats at least 1")
    if threads is not None and threads < 1:
        raise InputError(f"--threads must be at least 1 (got {threads})")
    scene_names = None
    if scenes is not None:
        scene_names = [name.strip() for name in scenes.split(",") if name.strip()]
        if not scene_names:
            raise InputError("--scene: give one or more scene names or files, comma-separated")
        for name in scene_names:
            refuse_lab_specimen(name)  # a bad name fails before any measuring
            load_scene(name)
    say = None if quiet else (lambda message: print(f"bench: {message}", flush=True))
    rows, fits = run_bench(size_list, integrator_list, scene_names, seconds, repeats, arch, say,
                           profile, threads)
    machine = {"benchmark": "machine", "arch": arch, "cpu_threads": taichi_threads()}
    print(f"Taichi on {arch}, {machine['cpu_threads']} CPU threads")
    print(report(rows, fits))
    if profile:
        ti.profiler.print_kernel_profiler_info()
    if json_path:
        write_json(Path(json_path), [machine] + rows_document(rows, fits))
    return 0
