"""Pictures of the textile lab's results (matplotlib, written whole): the cantilever strip in
profile with the 41.5° line, and the drape seen from above (its shadow, the support disc and
the flat specimen's outline) and from the side."""

import math
from pathlib import Path

from matplotlib.collections import PolyCollection
from matplotlib.patches import Rectangle
from matplotlib.figure import Figure

from taichi_cloth.studies.cantilever import TARGET_ANGLE
from taichi_cloth.studies.compare_plots import save
from taichi_cloth.studies.drape import DISC_RADIUS, SPECIMEN_RADIUS


def plot_cantilever(row: dict, target: Path) -> None:
    """The strip's centre line in profile (z along the strip, y up, in cm), the platform, the
    41.5° line from its edge, and the measured bending length."""
    positions, columns = row["positions"], row["columns"]
    centre = positions.reshape(-1, columns, 3).mean(axis=1) * 100.0
    edge = centre[:2].mean(axis=0)
    figure = Figure(figsize=(6.4, 4.0))
    axes = figure.add_subplot()
    axes.plot(centre[:, 2] - edge[2], centre[:, 1] - edge[1], "o-", color="tab:blue",
              markersize=3, label=f"{row['material']}, {row['direction']} strip")
    axes.fill_between([-1.5, 0.0], [-0.4, -0.4], [0.0, 0.0], color="0.7", label="platform")
    reach = row["overhang_m"] * 100.0 * 1.1
    axes.plot([0, reach], [0, -reach * math.tan(TARGET_ANGLE)], "--", color="tab:red",
              label="41.5° line")
    axes.set_aspect("equal")
    axes.set_xlabel("along the strip from the platform edge [cm]")
    axes.set_ylabel("height [cm]")
    axes.set_title(f"cantilever: l = {row['overhang_m'] * 100:.2f} cm, θ = "
                   f"{row['tip_angle_deg']:.1f}°, c = {row['bending_length_m'] * 100:.2f} cm "
                   f"(B gives {row['expected_bending_length_m'] * 100:.2f} cm)", fontsize=9)
    axes.legend(fontsize=8, loc="lower left")
    axes.grid(alpha=0.3)
    save(figure, target)


def plot_drape(row: dict, target: Path) -> None:
    """The settled specimen from above (its triangles projected: the shadow) with the support
    disc and the flat specimen's circle, and from the side with the support plate's outline;
    lengths in cm."""
    positions, triangles = row["positions"] * 100.0, row["triangles"]
    figure = Figure(figsize=(9.0, 4.2))
    top, side = figure.add_subplot(1, 2, 1), figure.add_subplot(1, 2, 2)
    top.add_collection(PolyCollection(positions[triangles][:, :, [0, 2]], facecolors="0.35",
                                      edgecolors="none", antialiased=False))
    for radius, style, label in ((SPECIMEN_RADIUS, "--", "specimen, flat"),
                                 (DISC_RADIUS, "-", "support disc")):
        angle = [2 * math.pi * k / 256 for k in range(257)]
        top.plot([radius * 100 * math.cos(a) for a in angle],
                 [radius * 100 * math.sin(a) for a in angle], style, color="tab:red",
                 linewidth=1, label=label)
    top.set_aspect("equal")
    top.set_xlim(-16, 16)
    top.set_ylim(-16, 16)
    top.set_title(f"{row['material']}: DC = {row['drape_coefficient']:.3f}, "
                  f"{row['nodes']} nodes", fontsize=9)
    top.set_xlabel("x [cm]")
    top.set_ylabel("z [cm]")
    top.legend(fontsize=7, loc="upper right")
    side.add_collection(PolyCollection(positions[triangles][:, :, [0, 1]], facecolors="0.45",
                                       edgecolors="0.2", linewidths=0.1))
    if row["support"] is not None:
        top_face, thickness, radius = (100.0 * value for value in row["support"])
        side.add_patch(Rectangle((-radius, top_face - thickness), 2 * radius, thickness,
                                 fill=False, edgecolor="tab:red", linewidth=1))
    height = positions[:, 1].max()
    side.set_xlim(-16, 16)
    side.set_ylim(height - 16, height + 2)
    side.set_aspect("equal")
    side.set_title("from the side", fontsize=9)
    side.set_xlabel("x [cm]")
    side.set_ylabel("y [cm]")
    save(figure, target)
