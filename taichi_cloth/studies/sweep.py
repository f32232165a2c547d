"""``sweep``: many simulations of one scene, the Cartesian product of ``--set`` values.

A plan is a scene, fixed overrides, and a grid: dotted scene keys, each with a list of values
(``--grid cloth.material=silk,cotton --grid "cloth.resolution=[16,8],[32,14]"``, or a plan file
with a ``[sweep]`` table, ``plan_from_file``). Every combination is one run of ``simulate`` into
its own folder ``<out>/runs/<index>-<values>/`` (``stats.json`` and the simulation cache, as a
single run writes them), plus a thumbnail of its last frame and ``result.json``: its row of the
table (parameters, exit status, metrics, timings, the machine and the package versions). The
sweep writes ``sweep.json`` (the plan and its runs), ``results.csv`` and ``results.json`` (every
run's row) and ``contact_sheet.png`` (a thumbnail per run, ``sweep_sheet``).

Runs are independent, so they go to an executor (``executors``: this process, local worker
processes, or a Dask cluster). A run that fails (a bad value: exit 2; unstable: exit 3; any
other error: 1) is a row with its error, and the sweep goes on. ``--resume`` continues a sweep in
its folder: a run whose ``result.json`` is there is not run again.

Timings stay comparable: every worker's Taichi runs on one thread (``WORKER_THREADS``), each row
names its host, and the table says how many workers shared each machine. On the CPU a run's
``stats.json`` is the same, bit for bit, whichever executor ran it (but for ``wall_seconds``,
which measures the machine).
"""

import itertools
import json
import time
import tomllib
from dataclasses import asdict, dataclass
from importlib import metadata
from pathlib import Path

from taichi_cloth.config.scene import load_scene, refuse_lab_specimen
from taichi_cloth.errors import InputError, UnstableError
from taichi_cloth.output.files import write_csv, write_json, write_png
from taichi_cloth.output.folder import OwnedFolder
from taichi_cloth.output.progress import announce
from taichi_cloth.output.run import OUTPUT_ROOT, check_writable, safe_name
from taichi_cloth.studies.executors import WORKER_THREADS

RUNS_DIR = "runs"
RESULT_FILE = "result.json"
PLAN_FILE = "sweep.json"
THUMBNAIL = "thumbnail.png"
THUMBNAIL_SIZE = (320, 240)  # pixels
FORMAT = 1
PACKAGES = ("taichi", "numpy", "meshio", "h5py", "imageio", "matplotlib")  # recorded per run
STATUS = {0: "done", 1: "failed", 2: "bad input", 3: "unstable"}
METRICS = ("frames", "particles", "integrator", "dt", "max_strain", "max_penetration",
           "max_self_intersections")
TIMINGS = ("compile_seconds", "settle_seconds", "simulate_seconds", "run_seconds")
# A worker's runtime is reset before a run when it holds more field trees than this: Taichi's CPU
# and CUDA backends hold at most 512 per runtime, and each run allocates a few (3 for a small
# sheet, more with effects), so a worker would fail after some hundred runs without it.
FIELD_TREES_BEFORE_RESET = 256


@dataclass(frozen=True)
class SweepJob:
    """One run of a sweep: its folder, the scene and every ``--set`` it runs with, and the
    grid's values for it (``parameters``: (key, value text) pairs)."""

    index: int
    folder: str
    scene: str
    overrides: tuple
    parameters: tuple
    frames: int | None

    @property
    def name(self) -> str:
        return Path(self.folder).name


@dataclass(frozen=True)
class SweepPlan:
    """scene: a shipped scene's name or a .toml path; fixed: ``--set`` texts for every run;
    grid: (key, (value texts ...)) pairs; frames: ``--frames`` for every run (None: the
    scene's)."""

    scene: str
    fixed: tuple
    grid: tuple
    frames: int | None

    def jobs(self, directory: Path) -> list[SweepJob]:
        """Every combination of the grid's values, the last key varying fastest."""
        keys = [key for key, _ in self.grid]
        combinations = list(itertools.product(*(values for _, values in self.grid)))
        width = max(3, len(str(len(combinations) - 1)))
        jobs = []
        for index, values in enumerate(combinations):
            name = f"{index:0{width}d}-{'_'.join(safe_name(value) for value in values)}"
            jobs.append(SweepJob(index, str(directory / RUNS_DIR / name), self.scene,
                                 self.fixed + tuple(f"{k}={v}" for k, v in zip(keys, values)),
                                 tuple(zip(keys, values)), self.frames))
        return jobs

    def document(self) -> dict:
        return {"scene": self.scene, "set": list(self.fixed),
                "grid": {key: list(values) for key, values in self.grid}, "frames": self.frames}


def split_values(text: str, flag: str) -> tuple[str, ...]:
    """The values of ``KEY=V1,V2,...``: split at the commas outside brackets and quotes (so
    ``[16,8],[32,14]`` is two values)."""
    values, depth, quote, current = [], 0, "", ""
    for character in text:
        if quote:
            quote = "" if character == quote else quote
        elif character in "\"'":
            quote = character
        elif character in "[{":
            depth += 1
        elif character in "]}":
            depth -= 1
        elif character == "," and depth == 0:
            values.append(current.strip())
            current = ""
            continue
        current += character
    values.append(current.strip())
    if depth != 0 or quote or not all(values):
        raise InputError(f"{flag} {text}: expected KEY=V1,V2,... with one value between commas "
                         f"(brackets and quotes closed)")
    return tuple(dict.fromkeys(values))


def grid_axis(text: str) -> tuple[str, tuple[str, ...]]:
    """``--grid KEY=V1,V2,...`` → (key, values)."""
    key, sep, values = text.partition("=")
    key = key.strip()
    if not sep or not key or any(not part for part in key.split(".")):
        raise InputError(f"--grid {text}: expected KEY=V1,V2,... with a dotted scene key, e.g. "
                         f"--grid cloth.material=silk,cotton")
    return key, split_values(values, f"--grid {key}=")


def value_text(value, inner: bool = False) -> str:
    """A plan file's TOML value as ``--set`` reads it, on one line: a string as its bare word
    (quoted inside an array, or when it is not a plain word), an array as [a, b], a table as
    {k = v}."""
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, str):
        plain = value and all(c.isalnum() or c in "-_." for c in value)
        return value if plain and not inner else json.dumps(value)
    if isinstance(value, list):
        return "[" + ", ".join(value_text(item, True) for item in value) + "]"
    if isinstance(value, dict):
        return "{" + ", ".join(f"{json.dumps(key)} = {value_text(item, True)}"
                               for key, item in value.items()) + "}"
    return repr(value)


def plan_from_file(path: Path) -> dict:
    """A plan file's ``[sweep]`` table: ``scene`` (a shipped name, or a path relative to the
    file), ``frames``, ``set`` (a list of KEY=VALUE texts) and ``grid`` (a table of dotted key →
    list of values), checked; InputError naming the file and key."""
    try:
        document = tomllib.loads(path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError, tomllib.TOMLDecodeError) as error:
        raise InputError(f"{path}: cannot read the sweep plan ({error})") from None
    table = document.get("sweep")
    if not isinstance(table, dict) or set(document) != {"sweep"}:
        raise InputError(f"{path}: a sweep plan has one table, [sweep]")
    unknown = set(table) - {"scene", "frames", "set", "grid"}
    if unknown:
        raise InputError(f"{path}: sweep.{sorted(unknown)[0]}: unknown key (scene, frames, "
                         f"set, grid)")
    scene = table.get("scene")
    if not isinstance(scene, str) or not scene:
        raise InputError(f"{path}: sweep.scene: the scene to sweep, a name or a .toml path")
    if scene.endswith(".toml"):
        scene = str((path.parent / scene).resolve())
    frames = table.get("frames")
    if frames is not None and (not isinstance(frames, int) or isinstance(frames, bool)
                               or frames < 1):
        raise InputError(f"{path}: sweep.frames: a whole number of frames, at least 1")
    fixed = table.get("set", [])
    if not isinstance(fixed, list) or not all(isinstance(item, str) for item in fixed):
        raise InputError(f"{path}: sweep.set: a list of \"KEY=VALUE\" texts")
    grid = table.get("grid", {})
    if not isinstance(grid, dict):
        raise InputError(f"{path}: sweep.grid: a table of dotted keys, each a list of values")
    axes = []
    for key, values in flatten(grid):
        if not isinstance(values, list) or not values:
            raise InputError(f"{path}: sweep.grid.{key}: a non-empty list of values")
        axes.append((key, tuple(dict.fromkeys(value_text(value) for value in values))))
    return {"scene": scene, "frames": frames, "set": tuple(fixed), "grid": tuple(axes)}


def flatten(table: dict, prefix: str = ""):
    """(dotted key, value) of a TOML table whose keys may be written dotted or nested."""
    for key, value in table.items():
        if isinstance(value, dict):
            yield from flatten(value, f"{prefix}{key}.")
        else:
            yield f"{prefix}{key}", value


def package_versions() -> dict:
    """This package's version and its runtime dependencies' (None: not installed)."""
    import taichi_cloth
    versions = {"taichi-cloth": taichi_cloth.__version__}
    for name in PACKAGES:
        try:
            versions[name] = metadata.version(name)
        except metadata.PackageNotFoundError:
            versions[name] = None
    return versions


def run_job(job: SweepJob) -> dict:
    """Run ``job`` where this is called (any executor's worker): ``simulate`` into its folder,
    a thumbnail of its last frame, and its row, also written to ``result.json``. Every error is
    the run's own result, never raised: the sweep goes on."""
    from taichi_cloth.output.replay import draw_cached_frame
    from taichi_cloth.output.run import run_scene
    from taichi_cloth.runtime import (field_trees, reset_taichi, start_taichi, taichi_started,
                                      taichi_threads)
    from taichi_cloth.studies.machine import machine_description
    started = time.perf_counter()
    folder = Path(job.folder)
    for name in (RESULT_FILE, THUMBNAIL):  # an earlier run's (a sweep run again into its folder)
        (folder / name).unlink(missing_ok=True)
    earlier_stats = file_stamp(folder / "stats.json")
    row = job_row(job, 0, "")
    try:
        scene = load_scene(job.scene, job.overrides)
        if taichi_started() and field_trees() > FIELD_TREES_BEFORE_RESET:
            reset_taichi()
        start_taichi(scene.simulation.arch, threads=WORKER_THREADS)
        frames = scene.frame_count if job.frames is None else job.frames
        run_scene(scene, frames, folder, quiet=True)
    except (InputError, UnstableError) as error:
        row.update(exit_code=error.exit_code, error=" ".join(str(error).split()))
    except Exception as error:  # a fault of the program: this run's row says which
        row.update(exit_code=1, error=f"{type(error).__name__}: {' '.join(str(error).split())}")
    row["status"] = STATUS[row["exit_code"]]
    # a run that stopped before its stats.json (an input error, a fault) left no run of its own
    ran = row["exit_code"] in (0, UnstableError.exit_code) and \
        file_stamp(folder / "stats.json") not in (None, earlier_stats)
    if ran:
        row.update(stats_columns(folder / "stats.json"))
    if ran and (folder / "cache").is_dir():
        try:
            from taichi_cloth.output.cache import read_cache
            _, cached = read_cache(folder)
            write_png(folder / THUMBNAIL, draw_cached_frame(folder, cached[-1], THUMBNAIL_SIZE))
            row["thumbnail"] = THUMBNAIL
        except (InputError, OSError, RuntimeError) as error:
            row["thumbnail_error"] = " ".join(str(error).split())
    row["run_seconds"] = time.perf_counter() - started
    machine = machine_description()
    row.update(host=machine["host"], threads=taichi_threads() if taichi_started() else None,
               machine=machine, versions=package_versions(), overrides=list(job.overrides))
    write_json(folder / RESULT_FILE, row)
    return row


def file_stamp(path: Path) -> tuple | None:
    """(inode, modification time [ns]) of ``path``, None when there is none: every output is
    renamed into place, so a file written again has a new stamp."""
    try:
        info = path.stat()
    except OSError:
        return None
    return info.st_ino, info.st_mtime_ns


def stats_columns(path: Path) -> dict:
    """The table's metrics and timings from a run's stats.json (blank when there is none)."""
    try:
        stats = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return {}
    columns = {key: stats.get(key) for key in METRICS}
    seconds = stats.get("wall_seconds", {})
    columns.update(compile_seconds=seconds.get("compile"), settle_seconds=seconds.get("settle"),
                   simulate_seconds=seconds.get("simulate"), stopped=stats.get("stopped"))
    return columns


def job_row(job: SweepJob, exit_code: int, error: str) -> dict:
    """A row's first columns: the run, its grid values, its exit status."""
    return {"index": job.index, "name": job.name, "folder": job.folder, **dict(job.parameters),
            "exit_code": exit_code, "error": error}


def lost_row(job: SweepJob, reason: str) -> dict:
    """The row of a run whose worker died under it."""
    return {**job_row(job, 1, reason), "status": "lost", "overrides": list(job.overrides)}


def finished_row(job: SweepJob) -> dict | None:
    """The row a finished run left in its folder, when it ran this job's overrides."""
    try:
        row = json.loads((Path(job.folder) / RESULT_FILE).read_text(encoding="utf-8"))
    except (OSError, ValueError):
        return None
    return row if row.get("overrides") == list(job.overrides) else None


def sweep(scene: str | None, grids: list[str], overrides: list[str], frames: int | None,
          out: str | None, workers: int | None, cluster: str | None, resume: bool,
          plan_path: str | None, quiet: bool) -> int:
    """The ``sweep`` command (module docstring). Exit 0 when every run ran (whatever its own
    exit status: the table has it)."""
    from tqdm import tqdm
    from taichi_cloth.studies.executors import Lost, make_executor
    from taichi_cloth.studies.sweep_sheet import write_contact_sheet
    plan = make_plan(scene, grids, overrides, frames, plan_path)
    # absolute, as every worker (a cluster's, on another machine) must find the same folder
    directory = (Path(out) if out else OUTPUT_ROOT / "sweep" /
                 safe_name(Path(plan.scene).stem)).resolve()
    check_writable(directory, "--out")
    jobs = plan.jobs(directory)
    recorded = {"format": FORMAT, **plan.document(), "runs": [asdict(job) for job in jobs]}
    if resume:
        check_same_plan(directory, recorded)
    done = {job.index: row for job in jobs if resume and (row := finished_row(job))}
    executor = make_executor(workers, cluster)
    try:
        with OwnedFolder(directory) as owned:
            write_json(directory / PLAN_FILE, recorded)
            rows = dict(done)
            todo = [job for job in jobs if job.index not in done]
            announce(f"sweep {plan.scene}", f"{len(todo)} runs to do ({len(done)} done) on "
                     f"{executor.workers} worker(s), {executor.kind}; each compiles its "
                     f"kernels first (about 1 s warm, 3 s cold: docs/scaling.md)", quiet)
            with tqdm(total=len(jobs), initial=len(done), desc=f"sweep {plan.scene}",
                      unit="run", disable=quiet) as bar:
                for job, outcome in executor.run(run_job, todo):
                    rows[job.index] = lost_row(job, outcome.reason) \
                        if isinstance(outcome, Lost) else outcome
                    bar.update(1)
            table = [rows[job.index] for job in jobs]
            write_table(directory, plan, table, executor)
            write_contact_sheet(directory / "contact_sheet.png", plan, table)
            owned.finish(resume)
    finally:
        executor.close()
    if not quiet:
        failed = sum(row["exit_code"] != 0 for row in table)
        print(f"sweep {plan.scene}: {len(table)} runs ({len(done)} already done), {failed} "
              f"failed; {executor.kind} executor, {executor.workers} worker(s) → {directory}")
    return 0


def make_plan(scene: str | None, grids: list[str], overrides: list[str], frames: int | None,
              plan_path: str | None) -> SweepPlan:
    """The plan from SCENE and --grid, or from --plan FILE (its grid extended by --grid, its
    set by --set, its frames replaced by --frames)."""
    base = {"scene": scene, "frames": None, "set": (), "grid": ()}
    if plan_path is not None:
        if scene is not None:
            raise InputError(f"--plan {plan_path}: the plan names its scene; drop SCENE")
        base = plan_from_file(Path(plan_path))
    elif scene is None:
        raise InputError("sweep: needs a SCENE with --grid, or --plan FILE")
    axes = dict(base["grid"])
    axes.update(grid_axis(text) for text in grids)
    if not axes:
        raise InputError("--grid: a sweep needs at least one --grid KEY=V1,V2,...")
    if frames is not None and frames < 1:
        raise InputError(f"--frames {frames}: must be at least 1")
    scene_path = base["scene"]
    refuse_lab_specimen(scene_path)
    if scene_path.endswith(".toml"):  # a worker elsewhere must find it whatever its directory
        scene_path = str(Path(scene_path).resolve())
    return SweepPlan(scene_path, tuple(base["set"]) + tuple(overrides), tuple(axes.items()),
                     frames if frames is not None else base["frames"])


def check_same_plan(directory: Path, recorded: dict) -> None:
    """--resume: the folder's sweep.json must hold this plan."""
    try:
        earlier = json.loads((directory / PLAN_FILE).read_text(encoding="utf-8"))
    except (OSError, ValueError):
        raise InputError(f"--resume: {directory} holds no sweep to continue "
                         f"({PLAN_FILE} missing or unreadable)") from None
    if earlier != json.loads(json.dumps(recorded)):
        raise InputError(f"--resume: {directory} holds another sweep (scene, --set, --grid or "
                         f"--frames differ); give the same arguments or another --out")


def write_table(directory: Path, plan: SweepPlan, rows: list[dict], executor) -> None:
    """results.csv (a row per run) and results.json (the rows with each run's machine and
    versions, the executor, and which machines ran several workers side by side)."""
    keys = [key for key, _ in plan.grid]
    columns = ["index", "name", *keys, "status", "exit_code", *METRICS, *TIMINGS, "host",
               "error"]
    write_csv(directory / "results.csv", [{key: row.get(key) for key in columns} for row in rows],
              columns)
    machines = executor.machines()
    shared = {host: count for host, count in machines.items() if count > 1}
    write_json(directory / "results.json", {
        "sweep": plan.document(), "executor": {"kind": executor.kind,
                                               "workers": executor.workers},
        "machines": machines, "threads_per_worker": WORKER_THREADS,
        "shared_machines": shared,
        "timing_note": (f"runs ran side by side on {', '.join(shared)} (workers per machine: "
                        f"{machines}): their timings include that contention") if shared
        else "one run at a time per machine", "runs": rows})
