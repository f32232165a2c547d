"""``sweep``: plans, executors (in-process, local processes, a Dask LocalCluster), identical
stats.json whichever ran them, failed runs as rows, a killed sweep resumed."""

import importlib.util
import json
import os
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

import pytest

from taichi_cloth.cli import main
from taichi_cloth.errors import InputError
from taichi_cloth.studies import executors
from taichi_cloth.studies.executors import LocalExecutor, Lost, SerialExecutor, make_executor
from taichi_cloth.studies.sweep import grid_axis, make_plan, plan_from_file, split_values
from worker_jobs import square_or_die

ROOT = Path(__file__).resolve().parent.parent
# a 2 × 1 sweep of a small sheet: two fabrics at one resolution, 2 frames each
SMALL = ["sweep", "sheet", "--grid", "cloth.material=silk,denim",
         "--grid", "cloth.resolution=[6,6]", "--frames", "2", "--quiet"]


def physics_of(directory: Path) -> dict:
    """Run folder name → its stats.json without wall_seconds (the one part that measures the
    machine, not the physics)."""
    stats = {}
    for path in sorted((directory / "runs").glob("*/stats.json")):
        document = json.loads(path.read_text())
        document.pop("wall_seconds")
        stats[path.parent.name] = document
    return stats


def test_values_split_at_commas_outside_brackets_and_quotes():
    assert split_values("silk,cotton", "--grid") == ("silk", "cotton")
    assert split_values("[16,8], [32,14]", "--grid") == ("[16,8]", "[32,14]")
    assert split_values('"a,b",c', "--grid") == ('"a,b"', "c")
    assert grid_axis("simulation.dt=0.001,0.002") == ("simulation.dt", ("0.001", "0.002"))
    for bad in ("cloth.material", "=silk", "a..b=1", "x=[1,2", "x=1,,2", "x='a"):
        with pytest.raises(InputError, match="--grid"):
            grid_axis(bad)


def test_plan_file_and_command_line_make_the_same_runs(tmp_path):
    plan_file = tmp_path / "plan.toml"
    plan_file.write_text('[sweep]\nscene = "sheet"\nframes = 4\nset = ["scene.fps = 20"]\n'
                         '[sweep.grid]\n"cloth.material" = ["silk", "denim"]\n'
                         '"cloth.resolution" = [[5, 5], [6, 6]]\n')
    from_file = make_plan(None, [], [], None, str(plan_file))
    from_flags = make_plan("sheet", ["cloth.material=silk,denim",
                                     "cloth.resolution=[5, 5],[6, 6]"], ["scene.fps = 20"], 4,
                           None)
    assert from_file == from_flags
    jobs = from_file.jobs(tmp_path)
    assert [job.name for job in jobs] == ["000-silk_5-5", "001-silk_6-6", "002-denim_5-5",
                                          "003-denim_6-6"]
    assert jobs[1].overrides == ("scene.fps = 20", "cloth.material=silk",
                                 "cloth.resolution=[6, 6]")
    bad = {"[sweep]\n": "scene", '[sweep]\nscene = "sheet"\ncolour = 1\n': "colour",
           '[sweep]\nscene = "sheet"\n[sweep.grid]\n"cloth.material" = []\n': "cloth.material",
           '[other]\n': r"\[sweep\]", '[sweep]\nscene = "sheet"\nframes = 1.5\n': "frames",
           '[sweep]\nscene = "sheet"\nframes = 0\n': "frames"}
    for text, named in bad.items():
        plan_file.write_text(text)
        with pytest.raises(InputError, match=named):
            plan_from_file(plan_file)
    with pytest.raises(InputError, match="--grid"):
        make_plan("sheet", [], [], None, None)


def test_executors_run_every_job_and_record_a_dead_worker(monkeypatch):
    assert sorted(SerialExecutor().run(square_or_die, [2, 3])) == [(2, 4), (3, 9)]
    results = dict(LocalExecutor(2).run(square_or_die, [2, 13, 3]))
    assert results[2] == 4 and results[3] == 9
    assert isinstance(results[13], Lost) and "died" in results[13].reason
    with pytest.raises(InputError, match="--workers"):
        make_executor(0, None)
    if importlib.util.find_spec("distributed") is not None:
        monkeypatch.setattr(executors, "CONNECT_SECONDS", 0.5)  # nobody listens there
        with pytest.raises(InputError, match="--cluster tcp://127.0.0.1:9"):
            make_executor(None, "tcp://127.0.0.1:9")


def test_a_sweep_gives_identical_stats_serially_locally_and_on_a_dask_cluster(tmp_path,
                                                                             monkeypatch):
    distributed = pytest.importorskip("distributed", reason="the cluster extra is not installed")
    monkeypatch.setenv("PYTHONPATH", str(ROOT))  # the workers import taichi_cloth from here
    assert main([*SMALL, "--workers", "1", "--out", str(tmp_path / "serial")]) == 0
    assert main([*SMALL, "--workers", "2", "--out", str(tmp_path / "local")]) == 0
    with distributed.LocalCluster(n_workers=1, threads_per_worker=1, processes=True,
                                  dashboard_address=None) as cluster:  # a worker process
        assert main([*SMALL, "--cluster", cluster.scheduler_address,
                     "--out", str(tmp_path / "dask")]) == 0
    serial = physics_of(tmp_path / "serial")
    assert len(serial) == 2
    assert physics_of(tmp_path / "local") == serial
    assert physics_of(tmp_path / "dask") == serial
    table = json.loads((tmp_path / "dask" / "results.json").read_text())
    assert table["executor"] == {"kind": "dask", "workers": 1}
    assert sum(table["machines"].values()) == 1 and not table["shared_machines"]
    local = json.loads((tmp_path / "local" / "results.json").read_text())
    assert local["shared_machines"] == {socket.gethostname(): 2}  # two runs side by side
    run = table["runs"][1]
    assert (run["cloth.material"], run["cloth.resolution"], run["status"]) == \
        ("denim", "[6,6]", "done")
    assert run["threads"] == 1 and run["versions"]["taichi"] == "1.7.4"
    assert run["particles"] == 36 and run["frames"] == 3
    scene = json.loads((tmp_path / "dask" / "runs" / run["name"] / "cache" / "scene.json")
                       .read_text())
    assert scene["document"]["cloth"]["material"] == "denim"  # the resolved scene is kept
    csv = (tmp_path / "local" / "results.csv").read_text().splitlines()
    assert len(csv) == 3 and csv[0].startswith("index,name,cloth.material,cloth.resolution")
    for name in ("serial", "local", "dask"):
        assert (tmp_path / name / "contact_sheet.png").stat().st_size > 0
        assert len(list((tmp_path / name / "runs").glob("*/thumbnail.png"))) == 2


def test_a_failed_run_is_a_row_and_the_others_complete(tmp_path):
    assert main(["sweep", "sheet", "--grid", "cloth.material=silk,nylon",
                 "--grid", "cloth.resolution=[5,5]", "--frames", "2", "--workers", "1",
                 "--quiet", "--out", str(tmp_path)]) == 0
    rows = json.loads((tmp_path / "results.json").read_text())["runs"]
    assert [(row["status"], row["exit_code"]) for row in rows] == [("done", 0),
                                                                    ("bad input", 2)]
    assert "nylon" in rows[1]["error"] and rows[0]["max_strain"] is not None
    # the same runs again into that folder, unstable before their first frame (while settling):
    # their rows and the contact sheet show nothing of the earlier runs' stats or thumbnails
    assert (tmp_path / "runs" / rows[0]["name"] / "thumbnail.png").is_file()
    assert main(["sweep", "sheet", "--grid", "cloth.material=silk,nylon",
                 "--grid", "cloth.resolution=[5,5]", "--frames", "2", "--workers", "1",
                 "--set", "simulation.settle=0.5", "--set", "simulation.integrator=euler",
                 "--set", "simulation.dt=0.05", "--set", "simulation.max_retries=0", "--quiet",
                 "--out", str(tmp_path)]) == 0
    again = json.loads((tmp_path / "results.json").read_text())["runs"]
    assert [row["status"] for row in again] == ["unstable", "bad input"]
    assert again[0].get("max_strain") is None and "thumbnail" not in again[0]
    assert not (tmp_path / "runs" / rows[0]["name"] / "thumbnail.png").exists()


def test_a_worker_resets_its_runtime_before_it_runs_out_of_field_trees(tmp_path):
    """In a process of its own (a reset drops this session's fields): three runs with a reset
    due before each give the same stats as the first, and the runtime never holds more trees
    than a run needs."""
    script = f"""
import json
from pathlib import Path
from taichi_cloth.runtime import field_trees
from taichi_cloth.studies import sweep
sweep.FIELD_TREES_BEFORE_RESET = 1
plan = sweep.make_plan("sheet", ["render.width=100,110,120"], ["cloth.resolution=[5,5]"],
                       2, None)
trees, stats = [], []
for job in plan.jobs(Path({str(tmp_path)!r})):
    row = sweep.run_job(job)
    assert row["status"] == "done", row
    trees.append(field_trees())
    document = json.loads((Path(job.folder) / "stats.json").read_text())
    document.pop("wall_seconds")
    stats.append(document)
assert len(set(trees)) == 1, trees
assert stats[0] == stats[1] == stats[2]
"""
    subprocess.run([sys.executable, "-c", script], cwd=ROOT, check=True, timeout=300)


def test_a_killed_sweep_resumed_runs_only_what_is_missing(tmp_path):
    arguments = ["sweep", "sheet", "--grid", "cloth.material=silk,denim,wool",
                 "--grid", "cloth.resolution=[5,5]", "--frames", "12", "--workers", "1",
                 "--quiet", "--out", str(tmp_path)]
    sweep = subprocess.Popen([sys.executable, "-m", "taichi_cloth", *arguments], cwd=ROOT)
    results = tmp_path / "runs"
    deadline = time.monotonic() + 120
    while not list(results.glob("*/result.json")) and sweep.poll() is None \
            and time.monotonic() < deadline:
        time.sleep(0.05)
    sweep.send_signal(signal.SIGKILL)
    sweep.wait()
    finished = {path.parent.name: os.stat(path).st_mtime_ns
                for path in results.glob("*/result.json")}
    assert 1 <= len(finished) < 3
    # the same folder with another plan: refused (exit 2), nothing touched
    assert main([*arguments[:3], "cloth.material=silk", *arguments[4:], "--resume"]) == 2
    assert main([*arguments, "--resume"]) == 0
    after = {path.parent.name: os.stat(path).st_mtime_ns
             for path in results.glob("*/result.json")}
    assert len(after) == 3
    assert {name: after[name] for name in finished} == finished  # not run again
    rows = json.loads((tmp_path / "results.json").read_text())["runs"]
    assert [row["status"] for row in rows] == ["done"] * 3


def test_a_cluster_of_threaded_workers_is_refused():
    distributed = pytest.importorskip("distributed", reason="the cluster extra is not installed")
    with distributed.LocalCluster(n_workers=1, threads_per_worker=2, processes=False,
                                  dashboard_address=None) as cluster:
        with pytest.raises(InputError, match="--nthreads 1"):
            make_executor(None, cluster.scheduler_address)
