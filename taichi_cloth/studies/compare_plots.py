"""The comparison's plots (matplotlib, no display needed), each written atomically as a PNG:

- ``error_vs_cost.png``: RMS error against wall-clock cost, log–log, one line per integrator and
  the Pareto front (the cheapest run for each accuracy);
- ``error_vs_dt.png``: RMS error against the step, log–log, with each integrator's fitted order,
  its unstable steps and its predicted stability limit;
- ``energy.png``: total energy over time, one panel per integrator, one line per stable step,
  the reference dashed.
"""

from pathlib import Path

import numpy as np
from matplotlib import colormaps
from matplotlib.figure import Figure
from matplotlib.lines import Line2D

from taichi_cloth.output.files import atomic_path

INTEGRATOR_STYLES = {"euler": ("tab:red", "o"), "symplectic": ("tab:blue", "s"),
                     "rk4": ("tab:green", "D"), "implicit": ("tab:purple", "^")}
INTEGRATOR_TITLES = {"euler": "explicit Euler", "symplectic": "symplectic (FB) Euler",
                     "rk4": "RK4", "implicit": "backward Euler"}
DPI = 110


def save(figure: Figure, target: Path, bottom: float = 0.0) -> None:
    """``figure`` as a PNG at ``target``, atomically; the panels laid out above ``bottom`` (a
    fraction of the height kept for a figure legend)."""
    figure.tight_layout(rect=(0.0, bottom, 1.0, 1.0))
    with atomic_path(target, ".png") as temporary:
        figure.savefig(temporary, format="png", dpi=DPI)


def stable_rows(summary: dict, name: str) -> list[dict]:
    return [row for row in summary["results"] if row["integrator"] == name and row["stable"]]


def setting(summary: dict) -> str:
    """The run setting for plot titles: scene, particles, simulated time, precision."""
    return (f"{summary['scene']}: {summary['particles']} particles, {summary['duration']:.3g} s "
            f"simulated, {summary['precision']}")


def milliseconds(dt: float) -> str:
    return f"{dt * 1e3:.3g} ms"


def plot_error_vs_cost(summary: dict, target: Path) -> None:
    figure = Figure(figsize=(7.5, 5.2))
    axes = figure.subplots()
    axes.set_xscale("log")
    axes.set_yscale("log")
    points = []
    for name in summary["integrators"]:
        color, marker = INTEGRATOR_STYLES[name]
        rows = sorted((row for row in stable_rows(summary, name)
                       if row["wall_seconds_per_sim_second"] > 0 and row["error_rms"] > 0),
                      key=lambda row: row["wall_seconds_per_sim_second"])
        if not rows:
            continue
        cost = [row["wall_seconds_per_sim_second"] for row in rows]
        error = [row["error_rms"] for row in rows]
        axes.plot(cost, error, marker=marker, color=color, label=INTEGRATOR_TITLES[name])
        for row, x, y in zip(rows, cost, error):
            axes.annotate(milliseconds(row["dt"]), (x, y), textcoords="offset points",
                          xytext=(4, 4), fontsize=7, color=color)
        points += zip(cost, error)
    front, best = [], np.inf
    for x, y in sorted(points):
        if y < best:
            front.append((x, y))
            best = y
    if front:
        axes.step(*zip(*front), where="post", color="0.5", linestyle=":", linewidth=1.2,
                  label="Pareto front: cheapest for an accuracy")
        axes.legend(fontsize=8)
    else:
        axes.text(0.5, 0.5, "no stable run", transform=axes.transAxes, ha="center")
    axes.set_xlabel("cost: wall-clock seconds per simulated second [s/s]")
    axes.set_ylabel("RMS position error against the reference [m]")
    axes.set_title(f"Error vs cost (labels: dt)\n{setting(summary)}", fontsize=10)
    axes.grid(True, which="both", alpha=0.3)
    save(figure, target)


def plot_error_vs_dt(summary: dict, target: Path) -> None:
    figure = Figure(figsize=(7.5, 5.2))
    axes = figure.subplots()
    axes.set_xscale("log")
    axes.set_yscale("log")
    limits = summary["stability"]["dt"]
    for name in summary["integrators"]:
        color, marker = INTEGRATOR_STYLES[name]
        rows = sorted(stable_rows(summary, name), key=lambda row: row["dt"])
        order = summary["orders"][name]
        label = INTEGRATOR_TITLES[name]
        if order["order"] is not None:
            label += f": order {order['order']:.2f} (expected {order['expected']})"
        if rows:
            dts = np.array([row["dt"] for row in rows])
            error = np.array([row["error_rms"] for row in rows])
            axes.plot(dts, error, marker=marker, color=color, linestyle="none", label=label)
        if order["order"] is not None:
            fit_dts = np.array(order["dts"])
            fit_errors = np.array([row["error_rms"] for row in rows if row["dt"] in order["dts"]])
            constant = np.exp(np.mean(np.log(fit_errors) - order["order"] * np.log(fit_dts)))
            line = np.geomspace(fit_dts.min() / 1.5, fit_dts.max() * 1.5, 20)
            axes.plot(line, constant * line ** order["order"], color=color, linestyle="--",
                        linewidth=1)
        unstable = [row["dt"] for row in summary["results"]
                    if row["integrator"] == name and not row["stable"]]
        axes.plot(unstable, [0.97] * len(unstable), marker=marker, color=color,
                  linestyle="none", markerfacecolor="none", markersize=8,
                  transform=axes.get_xaxis_transform())
        if limits[name]:
            axes.axvline(limits[name], color=color, linestyle=":", linewidth=1)
    if not all(row["stable"] for row in summary["results"]):
        low, high = axes.get_ylim()
        axes.set_ylim(low, high * 30)  # room at the top for the unstable runs' markers
        axes.plot([], [], marker="o", color="0.3", markerfacecolor="none", linestyle="none",
                  label="unstable runs (hollow, at the top)")
    axes.plot([], [], color="0.3", linestyle=":", label="predicted stability limit")
    axes.plot([], [], color="0.3", linestyle="--", label="fitted error ∝ dtᵖ")
    axes.set_xlabel("time step dt [s]")
    axes.set_ylabel("RMS position error against the reference [m]")
    reference = summary["reference"]
    axes.set_title(f"Error vs time step (reference: {reference['integrator']}, "
                   f"{reference['precision']}, dt = {milliseconds(reference['dt'])})\n"
                   f"{setting(summary)}", fontsize=10)
    axes.grid(True, which="both", alpha=0.3)
    axes.legend(fontsize=8, loc="lower right")
    save(figure, target)


def plot_energy(summary: dict, runs: list, reference, target: Path) -> None:
    """runs: the sweep's ``compare.Run`` list; reference: the reference ``Run``."""
    names = summary["integrators"]
    figure = Figure(figsize=(4.2 * len(names), 4.0))
    panels = np.atleast_1d(figure.subplots(1, len(names)))
    base = reference.energy[0]
    dts = sorted({run.time_step.dt for run in runs}, reverse=True)
    colors = dict(zip(dts, colormaps["viridis"](np.linspace(0.0, 0.9, len(dts)))))
    for axes, name in zip(panels, names):
        for run in runs:
            if run.integrator == name and run.stable:
                axes.plot(run.times, np.array(run.energy) - base, color=colors[run.time_step.dt],
                          label=f"dt = {milliseconds(run.time_step.dt)}")
        axes.plot(reference.times, np.array(reference.energy) - base, color="black",
                  linestyle="--", linewidth=1, label="reference")
        blown = [run.time_step.dt for run in runs if run.integrator == name and not run.stable]
        title = INTEGRATOR_TITLES[name]
        if blown:
            title += "\nblew up at dt = " + ", ".join(f"{dt * 1e3:.3g}" for dt in blown) + " ms"
        axes.set_title(title, fontsize=9)
        axes.set_xlabel("simulated time t [s]")
        axes.grid(True, alpha=0.3)
    panels[0].set_ylabel("total energy E(t) − E_ref(first frame) [J]")
    # one legend for every panel, below them, where it covers no curve
    handles = [Line2D([], [], color=colors[dt], label=f"dt = {milliseconds(dt)}") for dt in dts]
    handles.append(Line2D([], [], color="black", linestyle="--", linewidth=1, label="reference"))
    figure.legend(handles=handles, loc="lower center", ncol=min(len(handles), 8), fontsize=8,
                  frameon=False)
    figure.suptitle(f"Energy over time (kinetic + gravity + springs)  —  {setting(summary)}",
                    fontsize=10)
    save(figure, target, bottom=0.08)


def write_plots(directory: Path, summary: dict, runs: list, reference) -> None:
    plot_error_vs_cost(summary, directory / "error_vs_cost.png")
    plot_error_vs_dt(summary, directory / "error_vs_dt.png")
    plot_energy(summary, runs, reference, directory / "energy.png")
