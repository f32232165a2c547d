"""The virtual textile lab (``python -m taichi_cloth fabric-test cantilever|drape``): the
standard tests a textile lab runs on a fabric, run on the simulated cloth, reported against the
fabric's measured properties (``studies/cantilever.py``, ``studies/drape.py``).

Both tests need the cloth at rest under its own weight, a true static equilibrium. ``settle``
reaches it by backward Euler steps from rest: every step starts with all velocities zero (the
limit of kinetic damping, Cundall 1971), so a step of length h solves
(M − h²·K)·Δx = h²·f(x + Δx) linearised, i.e. a Newton step on f(x) = 0 regularised by M/h²
(Levenberg–Marquardt). With h = 0.5 s the mass term is small against the cloth's stiffness
and the steps are Newton's; they stop when no particle moves more than ``MOVE_TOLERANCE`` and the
residual force (the largest unbalanced force on a free particle, over that particle's weight) is
below ``RESIDUAL_TOLERANCE``; the residual is reported with every result.
"""

import dataclasses
import math
import sys
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from taichi_cloth.config.materials import PRESETS, STANDARD_GRAVITY
from taichi_cloth.config.scene import LAB_SCENES, load_scene, resolve_scene_path
from taichi_cloth.errors import InputError
from taichi_cloth.output.files import write_csv
from taichi_cloth.physics.metrics import RunRecord
from taichi_cloth.physics.simulation import Simulation

MOVE_TOLERANCE = 1e-9  # m per step: at rest
RESIDUAL_TOLERANCE = 1e-4  # unbalanced force over the particle's weight
MAX_SETTLE_STEPS = 1000  # denim's drape slides over the plate's edge: ~500 (docs/fabric-tests.md)


@dataclass
class Settled:
    """A settled simulation: positions [m] (N, 3), the steps taken, the last step's largest
    move [m], and the residual (largest unbalanced force on a free particle / its weight)."""

    simulation: Simulation
    positions: np.ndarray
    steps: int
    last_move: float
    residual: float


def material_overrides(material: str) -> tuple[str, ...]:
    """``--material``: a preset name, or a scene file whose ``[cloth.material]`` is used."""
    if material in PRESETS:
        return (f"cloth.material={material}",)
    if material.endswith(".toml"):
        scene = load_scene(str(resolve_scene_path(material)))
        overrides = [f"cloth.material.preset={scene.cloth.material.preset}"]
        for name, value in vars(scene.cloth.material).items():
            if name != "preset" and value is not None:
                overrides.append(f"cloth.material.{name}={value!r}")
        return tuple(overrides)
    raise InputError(f"--material {material}: not a preset ({', '.join(PRESETS)}) or a scene "
                     f"file (.toml)")


def lab_scene(test: str, overrides: tuple[str, ...]):
    """The lab scene ``scenes/lab/<test>.toml`` with ``overrides`` (a ``config.scene.Scene``)."""
    return load_scene(str(LAB_SCENES / f"{test}.toml"), overrides)


def lab_simulation(test: str, overrides: tuple[str, ...]) -> Simulation:
    """The simulation of ``lab_scene(test, overrides)``."""
    return Simulation.from_scene(lab_scene(test, overrides))


def residual(simulation: Simulation) -> float:
    """Largest |f_i| / (m_i·g) over the free particles at the current state (g the standard
    gravity)."""
    force = np.linalg.norm(simulation.total_forces(), axis=1)
    free = ~simulation.garment.pinned
    return float(np.max(force[free] / (simulation.model.host_mass[free] * STANDARD_GRAVITY)))


def settle(simulation: Simulation, move_tolerance: float = MOVE_TOLERANCE,
           residual_tolerance: float = RESIDUAL_TOLERANCE) -> Settled:
    """Newton steps from rest until no particle moves more than ``move_tolerance`` [m] in a
    step and the residual is under ``residual_tolerance`` (module docstring)."""
    record = RunRecord()
    previous = simulation.positions()
    remaining = math.inf
    for step in range(MAX_SETTLE_STEPS):
        simulation.advance_frame(1, record)
        snapshot = simulation.snapshot()
        simulation.restore(dataclasses.replace(snapshot,
                                               velocities=np.zeros_like(snapshot.velocities)))
        move = float(np.max(np.abs(snapshot.positions - previous)))
        previous = snapshot.positions
        if not np.isfinite(move):
            raise ArithmeticError("the lab specimen became non-finite while settling")
        if move < move_tolerance:
            remaining = residual(simulation)
            if remaining < residual_tolerance:
                break
    else:
        remaining = residual(simulation)
    return Settled(simulation, previous, step + 1, move, remaining)


def table(rows: list[dict], columns: list[tuple[str, str, str]]) -> str:
    """A fixed-width table of ``rows``: (key, heading, format) per column."""
    widths = [max(len(heading), 10) for _, heading, _ in columns]
    lines = ["  ".join(f"{heading:>{w}}" for (_, heading, _), w in zip(columns, widths))]
    for row in rows:
        lines.append("  ".join(f"{format(row[key], fmt):>{w}}"
                               for (key, _, fmt), w in zip(columns, widths)))
    return "\n".join(lines)


CANTILEVER_COLUMNS = [("material", "material", "s"), ("direction", "direction", "s"),
                      ("spacing_m", "spacing [m]", ".4f"), ("particles", "particles", "d"),
                      ("overhang_m", "l [m]", ".4f"), ("tip_angle_deg", "θ [°]", ".2f"),
                      ("bending_length_m", "c [m]", ".4f"),
                      ("expected_bending_length_m", "c from B [m]", ".4f"),
                      ("length_error", "c error", "+.3f"),
                      ("flexural_rigidity_Nm", "G [N·m]", ".3e"),
                      ("bend_stiffness_Nm", "B [N·m]", ".3e"), ("residual", "residual", ".1e")]
DRAPE_COLUMNS = [("material", "material", "s"), ("spacing_m", "spacing [m]", ".4f"),
                 ("particles", "particles", "d"), ("bending_length_m", "c [m]", ".4f"),
                 ("drape_coefficient", "DC", ".3f"),
                 ("drape_coefficient_spread", "DC spread", ".3f"), ("nodes", "nodes", "d"),
                 ("lift_m", "lift [m]", ".4f"), ("residual", "residual", ".1e")]
PICTURE_KEYS = ("positions", "triangles", "columns", "hem_angle", "hem_radius", "support")


def fabric_test_command(test: str, materials: str, resolutions: str, overrides: list[str],
                        out: str | None, quiet: bool, specimens: int = 3) -> int:
    """``fabric-test``: run ``test`` for each material (comma list of presets or scene files)
    at each resolution (particle spacing as a fraction of the bending length, for the drape
    of ``drape.reference_length``; the drape on ``specimens`` specimens); print the table,
    write ``results.csv`` and a picture per run into ``out``."""
    from taichi_cloth.flags import number_list
    from taichi_cloth.studies import fabric_plots
    from taichi_cloth.studies.cantilever import DIRECTIONS, cantilever
    from taichi_cloth.studies.drape import BUCKLE_LIFT, drape
    material_list = [item.strip() for item in materials.split(",") if item.strip()]
    if not material_list:
        raise InputError(f"--material {materials}: no material given")
    material_sets = [(name, material_overrides(name)) for name in material_list]
    fractions = number_list(resolutions, "--resolution", float, 0.0, "bending lengths")
    if not 1 <= specimens <= 20:
        raise InputError(f"--specimens {specimens}: give 1 to 20 specimens")
    if max(fractions) > 1.0:
        raise InputError(f"--resolution {resolutions}: a spacing above one bending length "
                         f"cannot resolve the bend; use e.g. 0.5,0.25")
    extra = tuple(overrides)
    lab_simulation(test, material_sets[0][1] + extra)  # a bad --set fails before any work
    directory = Path(out) if out else Path("output") / "fabric-test" / test
    rows = []
    for name, material in material_sets:
        for fraction in fractions:
            runs = [cantilever(material, direction, fraction, extra) for direction in DIRECTIONS] \
                if test == "cantilever" else [drape(material, fraction, extra, specimens)]
            for row in runs:
                label = f"{row['material']}_{row.get('direction', '-')}_{fraction:g}".replace(
                    "_-", "")
                plot = fabric_plots.plot_cantilever if test == "cantilever" \
                    else fabric_plots.plot_drape
                plot(row, directory / f"{test}_{label}.png")
                rows.append({key: value for key, value in row.items()
                             if key not in PICTURE_KEYS})
                if not quiet:
                    print(f"fabric-test: {test} {label} done", flush=True)
                if row.get("lift_m", 0.0) > BUCKLE_LIFT:
                    print(f"fabric-test: {test} {label}: a specimen stands "
                          f"{row['lift_m'] * 100:.1f} cm above its flat start, buckled up on the "
                          f"plate instead of draping: its DC is not a drape's; use a finer "
                          f"--resolution", file=sys.stderr, flush=True)
    columns = CANTILEVER_COLUMNS if test == "cantilever" else DRAPE_COLUMNS
    print(table(rows, columns))
    write_csv(directory / "results.csv", rows, list(rows[0]))
    if not quiet:
        print(f"→ {directory}")
    return 0
