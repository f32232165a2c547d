"""The comparison's ``report.md``: the setting (reference, machine), a plain reading (the
cheapest integrator for each accuracy, where each one blew up, the fitted orders against
docs/physics.md), the results table and the plots; and the command's one-line summary."""

from pathlib import Path

from taichi_cloth.studies.compare_plots import INTEGRATOR_TITLES, milliseconds
from taichi_cloth.output.files import atomic_path

ACCURACY_TARGETS = ((1e-2, "1 cm"), (1e-3, "1 mm"), (1e-4, "0.1 mm"), (1e-6, "1 µm"))  # m


def number(value, digits: int = 3) -> str:
    """A table cell: ``digits`` significant digits, a dash for a missing value."""
    return "–" if value is None else f"{value:.{digits}g}"


def cheapest_runs(summary: dict, tolerance: float) -> dict:
    """Per integrator, its cheapest stable row with error_rms ≤ ``tolerance`` [m] (or None)."""
    cheapest = {}
    for name in summary["integrators"]:
        rows = [row for row in summary["results"] if row["integrator"] == name and row["stable"]
                and row["error_rms"] <= tolerance]
        cheapest[name] = min(rows, key=lambda row: row["wall_seconds_per_sim_second"],
                             default=None)
    return cheapest


def accuracy_section(summary: dict) -> list[str]:
    """A table of the cost of each accuracy per integrator and a sentence per accuracy."""
    names = summary["integrators"]
    lines = ["| RMS error at most | " + " | ".join(INTEGRATOR_TITLES[n] for n in names) + " |",
             "|---|" + "---|" * len(names)]
    sentences = []
    for tolerance, label in ACCURACY_TARGETS:
        cheapest = cheapest_runs(summary, tolerance)
        cells = [f"{row['wall_seconds_per_sim_second']:.3g} s/s (dt {milliseconds(row['dt'])})"
                 if row else "not reached" for row in cheapest.values()]
        lines.append(f"| {label} | " + " | ".join(cells) + " |")
        ranked = sorted((row["wall_seconds_per_sim_second"], name)
                        for name, row in cheapest.items() if row)
        if not ranked:
            sentences.append(f"- {label}: no swept run reaches it.")
            continue
        cost, winner = ranked[0]
        text = f"- {label}: cheapest is **{INTEGRATOR_TITLES[winner]}** at dt = " \
               f"{milliseconds(cheapest[winner]['dt'])} ({cost:.3g} s per simulated s)"
        if len(ranked) > 1:
            runner_up_cost, runner_up = ranked[1]
            text += f", {runner_up_cost / cost:.3g}× cheaper than {INTEGRATOR_TITLES[runner_up]}"
        sentences.append(text + ".")
    return sentences + [""] + lines


def stability_sentence(summary: dict, name: str) -> str:
    """Where ``name`` stayed stable and where it blew up, against its predicted limit."""
    rows = [row for row in summary["results"] if row["integrator"] == name]
    stable = [row["dt"] for row in rows if row["stable"]]
    unstable = [row for row in rows if not row["stable"]]
    limit = summary["stability"]["dt"][name]
    predicted = "no limit (unconditionally stable)" if limit is None else \
        "no stable step" if limit == 0 else f"{milliseconds(limit)}"
    text = f"- **{INTEGRATOR_TITLES[name]}** (predicted limit: {predicted}): "
    if not unstable:
        return text + f"stable at every swept dt, up to {milliseconds(max(stable))}."
    blown = ", ".join(f"{milliseconds(row['dt'])} (at t = {row['blowup_time']:.3g} s)"
                      for row in unstable)
    if not stable:
        return text + f"blew up at every swept dt: {blown}."
    note = "" if max(stable) < min(row["dt"] for row in unstable) else \
        " (not monotone in dt)"
    return text + f"stable up to {milliseconds(max(stable))}; blew up at {blown}{note}."


def order_table(summary: dict) -> list[str]:
    lines = ["| integrator | fitted order | expected (docs/physics.md) | fitted over dt |",
             "|---|---|---|---|"]
    for name in summary["integrators"]:
        order = summary["orders"][name]
        fitted = "not measurable (fewer than 2 stable runs above the round-off floor)" \
            if order["order"] is None else f"{order['order']:.2f}"
        over = ", ".join(milliseconds(dt) for dt in order["dts"]) or "–"
        lines.append(f"| {INTEGRATOR_TITLES[name]} | {fitted} | {order['expected']} | {over} |")
    return lines


def results_table(summary: dict) -> list[str]:
    lines = ["| integrator | dt [ms] | stable | cost [s/s] | compile [s] | RMS error [m] | "
             "max error [m] | energy drift | max strain | max penetration [mm] |",
             "|---|---|---|---|---|---|---|---|---|---|"]
    for row in summary["results"]:
        stable = "yes" if row["stable"] else f"no, blew up at t = {row['blowup_time']:.3g} s"
        penetration = row.get("max_penetration")
        lines.append(
            f"| {INTEGRATOR_TITLES[row['integrator']]} | {row['dt'] * 1e3:.4g} | {stable} | "
            f"{number(row.get('wall_seconds_per_sim_second'))} | "
            f"{number(row.get('compile_seconds'), 2)} | {number(row.get('error_rms'))} | "
            f"{number(row.get('error_max'))} | {number(row.get('energy_drift'))} | "
            f"{number(row.get('max_strain'))} | "
            f"{number(None if penetration is None else penetration * 1e3)} |")
    return lines


def executor_sentence(executor: dict | None) -> str:
    """Where the runs ran, and whether several shared a machine (their costs then include that
    contention)."""
    if executor is None:
        return "- **Runs**: one after another in one process."
    shared = {host: count for host, count in executor["machines"].items() if count > 1}
    where = ", ".join(f"{host} ({count})" for host, count in executor["machines"].items())
    note = (f" Runs shared a machine ({', '.join(shared)}): their costs include the contention "
            f"of {max(shared.values())} workers side by side, so compare them with care."
            if shared else " One run at a time per machine.")
    return (f"- **Runs**: {executor['kind']} executor, {executor['workers']} worker(s) on "
            f"{where}, {executor['threads_per_worker']} Taichi thread each.{note}")


def report_text(summary: dict) -> str:
    reference, machine, stability = summary["reference"], summary["machine"], summary["stability"]
    lines = [
        f"# Integrator comparison: {summary['scene']}", "",
        f"{summary['particles']} particles, {summary['duration']:.4g} s simulated "
        f"({summary['frames']} frames at {summary['fps']} fps), {summary['precision']} precision. "
        f"Every run has `simulation.max_retries = 0`: a step that blows up is recorded as "
        f"unstable, never silently halved.", "",
        f"- **Reference**: {reference['integrator']} in {reference['precision']} at dt = "
        f"{milliseconds(reference['dt'])} ({reference['substeps_per_frame']} substeps per frame).",
        f"- **Machine**: {machine['cpu']}, {machine['cores']} logical cores; Taichi "
        f"{machine['taichi']} on arch {machine['taichi_arch']}; Python {machine['python']}; "
        f"{machine['system']}.",
        executor_sentence(summary.get("executor")),
        f"- **Cloth**: highest angular frequency ω_max = {number(stability['omega_max'], 4)} "
        f"rad/s (contact included), Rayleigh damping time β = {stability['damping_time']:.3g} s "
        f"(explicit Euler is stable only for dt ≤ β, docs/physics.md).", "",
        "## Reading", "",
        "Which integrator is cheapest for a given accuracy (the cheapest swept run whose RMS "
        "error is at most the target):", "",
        *accuracy_section(summary), "",
        "Where each one blows up:", "",
        *(stability_sentence(summary, name) for name in summary["integrators"]), "",
        "Convergence order, fitted as the slope of log(RMS error) over log(dt) on the (up to "
        "three) smallest stable steps whose error is above the round-off floor "
        f"({summary['error_floor']:.2g} m):", "",
        *order_table(summary), "",
        "## Results", "",
        *results_table(summary), "",
        "- **cost**: wall-clock seconds of integrator substeps per simulated second, after a "
        f"warm-up that compiles every kernel variant; a short run is repeated (up to "
        f"{summary['timing']['repeats']} runs while they total under "
        f"{summary['timing']['seconds']:g} s) and costs its fastest; the per-frame guard and "
        "metrics are not counted. **compile**: the JIT compilation the run needed (an "
        "integrator's first run compiles most of it).",
        "- **RMS / max error**: distance of the free particles from the reference at every frame "
        "end, root mean square and largest.",
        "- **energy drift**: (E_end − E_ref,end) / max_t KE_ref, the energy (kinetic + gravity + "
        "springs) the integrator made (+) or destroyed (−) beyond the physical damping, in units "
        "of the reference's peak kinetic energy.",
        "- **max strain**: of the stretch springs, (l − L)/L. **max penetration**: into the body's "
        "capsules.", "",
        "## Plots", "",
        "![Error vs cost](error_vs_cost.png)", "", "![Error vs dt](error_vs_dt.png)", "",
        "![Energy over time](energy.png)", "",
        f"Side by side at dt = {milliseconds(summary['video_dt'])}: `side_by_side.mp4` and "
        "`contact_sheet.png` (when rendered).", ""]
    return "\n".join(lines)


def write_report(target: Path, summary: dict) -> None:
    text = report_text(summary)
    with atomic_path(target) as temporary:
        temporary.write_text(text, encoding="utf-8")


def summary_line(summary: dict, directory: Path) -> str:
    """One line: runs, the reference, the fitted orders and where the outputs are."""
    steps = len({row["dt"] for row in summary["results"]})
    orders = ", ".join(f"{name} {number(order['order'])}"
                       for name, order in summary["orders"].items())
    unstable = sum(not row["stable"] for row in summary["results"])
    return (f"{summary['scene']}: {len(summary['integrators'])} integrators × {steps} steps "
            f"({unstable} unstable), reference {summary['reference']['integrator']} "
            f"{summary['reference']['precision']} at dt = "
            f"{milliseconds(summary['reference']['dt'])}; fitted orders {orders} → {directory}")
