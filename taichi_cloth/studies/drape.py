"""The Cusick drape test (ISO 9073-9, BS 5058; Cusick, "The dependence of fabric drape on
bending and shear stiffness", J. Text. Inst. 1965) on the simulated fabric.

A circular specimen of 30 cm diameter rests on a support disc of 18 cm (the lab scene's
``[effects.support]``, a solid plate with penalty contact and friction), held at its centre (its
innermost ring is pinned, as the tester's centre pin holds the specimen), and hangs around the disc
under its own weight. At rest, the area of its shadow on the horizontal plane gives the drape
coefficient

    DC = (A_shadow − A_disc) / (A_specimen − A_disc),

between 0 (hanging straight down) and 1 (staying flat); stiffer fabrics (a longer bending length)
drape less. The folds (nodes) are the outward bulges of the hem: the peaks of its radius around
the centre. The specimen starts flat with a small deterministic ripple, so that it can buckle
into folds, settles dynamically (backward Euler at the lab's small step with kinetic damping: a
dynamic path finds a stable drape, where Newton steps alone could stop on the unstable
axisymmetric cone) and is then brought to rest by Newton steps (``fabric_lab.settle``).

The standard lays a second 18 cm disc on top. Clamping the specimen flat out to 9 cm was the
lab's first model and did not converge under refinement: where the folds meet a clamped flat edge
an almost inextensible sheet must focus its bending into a layer far narrower than any mesh
(docs/fabric-tests.md). On the support alone the cloth may lift off the disc near its edge
between the folds. The mesh resolves both of the drape's lengths (``reference_length``) and has
a ring on the support's edge (``disc_overrides``); so made, every preset's mean DC changes by
0.031 at most from 0.7 to 0.5 of the reference length (measured there).

A drape is multistable: a specimen settles into the fold count its start leads it to, and DC
falls with more folds. As the standard averages specimens (ISO 9073-9: three, each face up),
the test drapes ``SPECIMENS`` specimens whose start ripples differ (a sum of the 5- to 9-fold
modes with amplitudes and phases drawn from a seeded generator: the same for every mesh, so a
refinement meets the same starts) and reports their mean DC with the spread.
"""

import dataclasses
import math

import numpy as np

from taichi_cloth.physics.metrics import RunRecord
from taichi_cloth.studies.fabric_lab import lab_scene, lab_simulation, settle

SPECIMEN_RADIUS = 0.15  # m
DISC_RADIUS = 0.09  # m
CENTRE_HOLE = 0.01  # m: the mesh's innermost ring (pinned: the centre pin)
FOLD_LENGTH = (SPECIMEN_RADIUS - DISC_RADIUS) / 3  # m: a third of the 6 cm overhang
# The rings' span in parts of which the support's edge is a whole number: (9 − 1) : (15 − 1) cm
# = 4 : 7, so with a multiple of 7 ring gaps a ring lies on the edge
RING_GAP_PERIOD = 7
SHADOW_PIXEL = 5e-4  # m: raster of the shadow area
RIPPLE = 2e-4  # m: the largest vertical displacement of the start's ripple
RIPPLE_MODES = np.arange(5, 10)  # folds of the ripple's modes
SPECIMENS = 3
DYNAMIC_STEP = 1.0 / 60.0  # s
START_STEP = 1.0 / 240.0  # s: the fall's first START_STEPS steps (1/15 s), before DYNAMIC_STEP ...
START_STEPS = 16  # ... so that the overhang's first pull does not kick the cloth off the plate
DYNAMIC_STEPS = 600  # at most 10 s of falling at DYNAMIC_STEP, with kinetic damping ...
DYNAMIC_REST_SPEED = 2e-4  # m/s ... until no particle moves faster after a step
MOVE_TOLERANCE = 1e-7  # m per Newton step: at rest (the drape's area is settled long before)
RESIDUAL_TOLERANCE = 1e-3  # unbalanced force over a particle's weight
NODE_PROMINENCE = 0.1  # of the hem's radius range: a smaller bump is not a fold
BUCKLE_LIFT = 0.005  # m above the flat start: a drape lifts ~1.5 mm between its folds at most;
# a coarse specimen that buckled up on the plate stands centimetres high (not a drape)


def reference_length(bending_length: float) -> float:
    """The length [m] the test's spacing is a fraction of: the fabric's bending length, at most
    ``FOLD_LENGTH``. A drape has two lengths to resolve, the bending length (the width of its
    bends) and the overhang it folds in; a stiff fabric's bending length (denim's 2.5 cm) leaves
    too few elements across the 6 cm overhang (3.4 at 0.7 of it: docs/fabric-tests.md)."""
    return min(bending_length, FOLD_LENGTH)


def disc_overrides(spacing: float) -> tuple[str, ...]:
    """The lab scene's specimen with particles about ``spacing`` [m] apart at the hem and rings
    at most ``spacing`` apart, one of them on the support's edge. The plate pushes on particles:
    where the edge falls between two rings, the element across it is held by its inner ring
    alone, so the edge's effective radius moved with the mesh (wool's DC by 0.09 between ring
    placements at 0.7·c: docs/fabric-tests.md)."""
    around = 4 * max(4, math.ceil(2 * math.pi * SPECIMEN_RADIUS / spacing / 4))
    gaps = RING_GAP_PERIOD * max(1, math.ceil((SPECIMEN_RADIUS - CENTRE_HOLE) / spacing
                                              / RING_GAP_PERIOD))
    rings = gaps + 1
    return (f"cloth.resolution=[{around}, {rings}]", f"cloth.waist_radius={CENTRE_HOLE!r}",
            f"cloth.hem_radius={SPECIMEN_RADIUS!r}", f"cloth.clamp_radius={CENTRE_HOLE!r}",
            f"effects.support.radius={DISC_RADIUS!r}")


def shadow_area(positions: np.ndarray, triangles: np.ndarray) -> float:
    """Area [m²] of the union of the triangles projected on the x–z plane, on a raster of
    ``SHADOW_PIXEL``."""
    extent = SPECIMEN_RADIUS * 1.05
    count = int(2 * extent / SHADOW_PIXEL)
    covered = np.zeros((count, count), dtype=bool)
    flat = positions[:, [0, 2]]
    for a, b, c in flat[triangles]:
        low = np.floor((np.minimum(np.minimum(a, b), c) + extent) / SHADOW_PIXEL).astype(int)
        high = np.ceil((np.maximum(np.maximum(a, b), c) + extent) / SHADOW_PIXEL).astype(int)
        low, high = np.clip(low, 0, count), np.clip(high, 0, count)
        if np.any(high <= low):
            continue
        xs = (np.arange(low[0], high[0]) + 0.5) * SHADOW_PIXEL - extent
        zs = (np.arange(low[1], high[1]) + 0.5) * SHADOW_PIXEL - extent
        px, pz = np.meshgrid(xs, zs, indexing="ij")
        d1 = (b[0] - a[0]) * (pz - a[1]) - (b[1] - a[1]) * (px - a[0])
        d2 = (c[0] - b[0]) * (pz - b[1]) - (c[1] - b[1]) * (px - b[0])
        d3 = (a[0] - c[0]) * (pz - c[1]) - (a[1] - c[1]) * (px - c[0])
        inside = ((d1 >= 0) & (d2 >= 0) & (d3 >= 0)) | ((d1 <= 0) & (d2 <= 0) & (d3 <= 0))
        covered[low[0]:high[0], low[1]:high[1]] |= inside
    return float(covered.sum()) * SHADOW_PIXEL ** 2


def drape_coefficient(shadow: float, flat_shadow: float = math.pi * SPECIMEN_RADIUS ** 2) -> float:
    """DC = (A_shadow − A_disc)/(A_specimen − A_disc), the specimen's area taken as the flat
    mesh's own shadow (its polygonal hem and centre hole measured alike), so flat is 1."""
    disc = math.pi * DISC_RADIUS ** 2
    return (shadow - disc) / (flat_shadow - disc)


def hem_profile(positions: np.ndarray, columns: int) -> tuple[np.ndarray, np.ndarray]:
    """(angle [rad], horizontal radius [m]) of the hem particles (the last ring), by angle."""
    hem = positions[-columns:]
    angle = np.arctan2(hem[:, 2], hem[:, 0])
    order = np.argsort(angle)
    return angle[order], np.hypot(hem[:, 0], hem[:, 2])[order]


def node_count(radius: np.ndarray) -> int:
    """Folds: peaks of the hem's radius around the centre (periodic) that stand out from both
    neighbouring valleys by ``NODE_PROMINENCE`` of its range."""
    span = float(radius.max() - radius.min())
    if span <= 0:
        return 0
    start = int(np.argmin(radius))
    ring = np.roll(radius, -start)  # starts and ends at the lowest valley
    nodes, valley, peak = 0, ring[0], ring[0]
    rising = True
    for value in np.append(ring[1:], ring[0]):
        if rising:
            peak = max(peak, value)
            if peak - value > NODE_PROMINENCE * span and peak - valley > NODE_PROMINENCE * span:
                nodes += 1
                rising, valley = False, value
        else:
            valley = min(valley, value)
            if value - valley > NODE_PROMINENCE * span:
                rising, peak = True, value
    return nodes


def start_ripple(angle: np.ndarray, specimen: int) -> np.ndarray:
    """The start's vertical ripple [m] at polar angles ``angle`` for specimen number
    ``specimen``: Σ_k a_k·sin(k·θ + φ_k) over ``RIPPLE_MODES``, a and φ from a generator seeded
    with the specimen number, scaled so that its largest value is ``RIPPLE``."""
    rng = np.random.default_rng(specimen)
    amplitude = rng.uniform(0.5, 1.0, len(RIPPLE_MODES))
    phase = rng.uniform(0.0, 2 * np.pi, len(RIPPLE_MODES))
    fine = np.linspace(0.0, 2 * np.pi, 2048, endpoint=False)
    wave, peak = (np.sum(amplitude * np.sin(np.multiply.outer(theta, RIPPLE_MODES) + phase),
                         axis=-1) for theta in (angle, fine))
    return RIPPLE * wave / np.abs(peak).max()


def settle_dynamically(simulation, specimen: int) -> int:
    """From the flat start with specimen ``specimen``'s ripple, backward Euler steps
    (``START_STEPS`` of ``START_STEP``, then ``DYNAMIC_STEP``: with the larger step from the
    start, the plate's contact and the overhang's first pull threw the cloth over the disc up
    at metres a second, and silk's coarse specimen ended crumpled 5 cm above the plate instead
    of draping; docs/fabric-tests.md) with
    kinetic damping (velocities zeroed whenever the kinetic energy passes a peak) until every
    particle is slower than ``DYNAMIC_REST_SPEED`` after a step, or the fall has come back to
    where it last restarted (no particle more than ``MOVE_TOLERANCE`` from its place at the last
    zeroing: the specimen repeats one cycle around a fixed shape, a contact's chatter on the
    plate, which the Newton steps then bring to rest), at most ``DYNAMIC_STEPS`` after the
    start's. Returns the steps taken."""
    snapshot = simulation.snapshot()
    radius = np.hypot(snapshot.positions[:, 0], snapshot.positions[:, 2])
    angle = np.arctan2(snapshot.positions[:, 2], snapshot.positions[:, 0])
    ripple = start_ripple(angle, specimen) * np.clip((radius - DISC_RADIUS) / 0.01, 0, 1)
    start = snapshot.positions.copy()
    start[:, 1] += ripple
    simulation.restore(dataclasses.replace(snapshot, positions=start))
    record, mass, previous = RunRecord(), simulation.model.host_mass, math.inf
    restart = start
    for step in range(1, START_STEPS + DYNAMIC_STEPS + 1):
        if step in (1, START_STEPS + 1):
            simulation.set_time_step(START_STEP if step == 1 else DYNAMIC_STEP, 1)
        simulation.advance_frame(1, record)
        current = simulation.snapshot()
        speed_sq = np.sum(current.velocities ** 2, axis=1)
        if np.max(speed_sq) < DYNAMIC_REST_SPEED ** 2:
            break
        kinetic = 0.5 * float(np.sum(mass * speed_sq))
        if kinetic < previous:
            simulation.restore(dataclasses.replace(
                current, velocities=np.zeros_like(current.velocities)))
            if np.max(np.abs(current.positions - restart)) < MOVE_TOLERANCE:
                break
            restart = current.positions
            kinetic = 0.0
        previous = kinetic
    simulation.set_time_step(snapshot.dt, snapshot.substeps_per_frame)
    return step


def drape(material: tuple[str, ...], spacing_fraction: float,
          extra: tuple[str, ...] = (), specimens: int = SPECIMENS) -> dict:
    """The test at a hem spacing of ``spacing_fraction`` × ``reference_length`` of the fabric's
    mean bending length on ``specimens`` specimens: a result row (areas in m²) with their mean
    DC, its spread and each specimen's DC and folds; the picture's fields are those of the
    specimen nearest the mean."""
    scene_material = lab_scene("drape", material + extra).material
    bending_length = float(np.mean(scene_material.bending_length))
    spacing = spacing_fraction * reference_length(bending_length)
    simulation = lab_simulation("drape", material + extra + disc_overrides(spacing))
    triangles = simulation.garment.triangles
    flat = simulation.snapshot()
    flat_shadow = shadow_area(flat.positions, triangles)
    results = []
    for specimen in range(specimens):
        simulation.restore(flat)
        fall_steps = settle_dynamically(simulation, specimen)
        settled = settle(simulation, MOVE_TOLERANCE, RESIDUAL_TOLERANCE)
        shadow = shadow_area(settled.positions, triangles)
        angle, radius = hem_profile(settled.positions, simulation.garment.columns)
        results.append({"drape_coefficient": drape_coefficient(shadow, flat_shadow),
                        "shadow_area_m2": shadow, "nodes": node_count(radius),
                        "fall_steps": fall_steps, "settle_steps": settled.steps,
                        "residual": settled.residual,
                        "lift_m": float(np.max(settled.positions[:, 1] - flat.positions[:, 1])),
                        "positions": settled.positions, "hem_angle": angle, "hem_radius": radius})
    plate = simulation.scene.effects.get("support")  # gone only if --set removed it
    coefficients = np.array([r["drape_coefficient"] for r in results])
    shown = results[int(np.argmin(np.abs(coefficients - coefficients.mean())))]
    return {
        "test": "drape", "material": scene_material.name, "direction": "-",
        "spacing_m": spacing, "particles": simulation.model.particle_count,
        "bending_length_m": bending_length, "specimens": specimens,
        "drape_coefficient": float(coefficients.mean()),
        "drape_coefficient_spread": float(coefficients.max() - coefficients.min()),
        "specimen_drape_coefficients": [round(float(c), 4) for c in coefficients],
        "specimen_nodes": [r["nodes"] for r in results],
        "shadow_area_m2": shown["shadow_area_m2"], "nodes": shown["nodes"],
        "fall_steps": max(r["fall_steps"] for r in results),
        "settle_steps": max(r["settle_steps"] for r in results),
        "residual": max(r["residual"] for r in results),
        "lift_m": max(r["lift_m"] for r in results),
        "positions": shown["positions"], "triangles": triangles,
        "hem_angle": shown["hem_angle"], "hem_radius": shown["hem_radius"],
        "support": plate and (plate.height, plate.plate_thickness, plate.radius),
    }
