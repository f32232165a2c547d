"""The cantilever bending test (ASTM D1388 option A; Peirce, "The stiffness of cloth", J. Text.
Inst. 1930) on the simulated fabric.

A strip 2.5 cm wide lies along +z with its first two rows clamped (the platform; two rows fix the
slope), the rest overhanging the platform's edge by l. The edge is taken halfway between the two
clamped rows: the clamp's hinge (at row 1) stands for the half cells on both of its sides, so the
bending moment acts from there; with the edge at row 1 a strip of spacing h behaves as one h/2
longer (at h = c/2 its measured c came out 20 % short). At rest under its own weight its
tip lies on a line at angle θ below the horizontal through the edge. Peirce's relation gives the
bending length from any (l, θ):

    c = l·(cos(θ/2) / (8·tan θ))^(1/3),      at θ = 41.5°: c = 0.509·l ≈ l/2,

and the flexural rigidity G = ρ_A·g·c³ [N·m], which a fabric of bending rigidity B should match
(c = (B/(ρ_A·g))^(1/3)). As the standard does, the overhang is searched until the tip lies on
the 41.5° line (each try settles a strip of the new length, ``fabric_lab.settle``; the next
length is the measured c over 0.509); the bending length reported is Peirce's c at the last
try's (l, θ). The strip runs along the warp, or along the weft (the warp turned by 90°).
Peirce's formula approximates the exact elastica to a few per cent.
"""

import math

import numpy as np

from taichi_cloth.config.materials import STANDARD_GRAVITY
from taichi_cloth.studies.fabric_lab import lab_scene, lab_simulation, settle

STRIP_WIDTH = 0.025  # m (ASTM D1388)
TARGET_ANGLE = math.radians(41.5)
ANGLE_TOLERANCE = math.radians(0.5)
MAX_TRIES = 4
DIRECTIONS = {"warp": 0.0, "weft": 90.0}  # the strip's long axis: bias of the warp [degrees]


def peirce_factor(angle: float) -> float:
    """(cos(θ/2)/(8·tan θ))^(1/3): c = l·factor at tip angle θ [rad]."""
    return (math.cos(angle / 2) / (8 * math.tan(angle))) ** (1.0 / 3.0)


def strip_overrides(overhang: float, spacing: float, direction: str) -> tuple[str, ...]:
    """The lab scene's strip: overhang l [m] past the clamp edge (halfway between the two clamped
    rows), particles about ``spacing`` [m] apart (rows along the strip, l = (segments + ½)·row
    spacing; at least 3 across)."""
    segments = max(2, round(overhang / spacing - 0.5))
    row_spacing = overhang / (segments + 0.5)
    across = max(3, round(STRIP_WIDTH / spacing) + 1)
    return (f"cloth.resolution=[{across}, {segments + 2}]",
            f"cloth.size=[{STRIP_WIDTH!r}, {row_spacing * (segments + 1)!r}]",
            f"cloth.bias={DIRECTIONS[direction]!r}")


def tip_angle(positions: np.ndarray, columns: int) -> float:
    """θ [rad] of the line from the clamp edge (halfway between the clamped rows 0 and 1) to the
    tip (the last row's mean) below the horizontal."""
    edge = positions[:2 * columns].mean(axis=0)
    tip = positions[-columns:].mean(axis=0)
    return math.atan2(edge[1] - tip[1], tip[2] - edge[2])


def cantilever(material: tuple[str, ...], direction: str, spacing_fraction: float,
               extra: tuple[str, ...] = ()) -> dict:
    """The test on one strip direction at a particle spacing of ``spacing_fraction`` × the
    expected bending length: a result row (lengths in m, angles in degrees)."""
    scene_material = lab_scene("cantilever", material + extra).material
    expected = scene_material.bending_length[0 if direction == "warp" else 1]
    rigidity = scene_material.bend_stiffness if direction == "warp" else scene_material.bend_weft
    spacing = spacing_fraction * expected
    overhang = expected / peirce_factor(TARGET_ANGLE)
    for attempt in range(1, MAX_TRIES + 1):
        simulation = lab_simulation("cantilever", material + extra
                                    + strip_overrides(overhang, spacing, direction))
        settled = settle(simulation)
        angle = tip_angle(settled.positions, simulation.garment.columns)
        measured = overhang * peirce_factor(angle)
        if abs(angle - TARGET_ANGLE) < ANGLE_TOLERANCE or attempt == MAX_TRIES:
            break
        overhang = measured / peirce_factor(TARGET_ANGLE)
    density = scene_material.density
    return {
        "test": "cantilever", "material": scene_material.name, "direction": direction,
        "spacing_m": spacing, "particles": simulation.model.particle_count,
        "overhang_m": overhang, "tip_angle_deg": math.degrees(angle),
        "bending_length_m": measured, "expected_bending_length_m": expected,
        "length_error": measured / expected - 1.0,
        "flexural_rigidity_Nm": density * STANDARD_GRAVITY * measured ** 3, "bend_stiffness_Nm": rigidity,
        "tries": attempt, "settle_steps": settled.steps, "residual": settled.residual,
        "positions": settled.positions, "columns": simulation.garment.columns,
    }
