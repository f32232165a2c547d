"""The output folder is the run's own: it changes or removes nothing it did not write (files
that look like its outputs included), a second run into a folder being written is refused with
exit 2, a killed run's lock is taken over, and a run's manifest lists exactly what it wrote."""

import json
import os
import subprocess
import sys
from pathlib import Path

import pytest

from taichi_cloth import cli
from taichi_cloth.output.folder import LOCK_NAME, MANIFEST_NAME, OwnedFolder
from taichi_cloth.output.run import safe_name

REPO = Path(__file__).resolve().parent.parent
SMALL = ["cloth.resolution=[6,3]"]
# names like the outputs' that the runs below never write (a file with an output's very name is
# that output: a run writes it)
LOOK_ALIKES = ["frames/frame_00099.png", "frames/frame_00001.png.bak", "meshes/cloth_00009.ply",
               "meshes/cloth_00050.txt", "meshes/cloth_00003.obj", "stats.json.old", "notes.txt"]


def fill(folder: Path) -> dict:
    """Look-alike user files (and a folder named like a frame); their bytes by path."""
    for index, name in enumerate(LOOK_ALIKES):
        path = folder / name
        path.parent.mkdir(parents=True, exist_ok=True)
        path.write_bytes(f"user file {index}".encode())
    (folder / "frames" / "frame_00050.d").mkdir()
    return {name: (folder / name).read_bytes() for name in LOOK_ALIKES}


def test_a_run_leaves_every_file_it_did_not_write_alone(tmp_path):
    before = fill(tmp_path)
    for frames in (3, 1):  # the shorter second run removes the first one's extra frames only
        code = cli.render("skirt", SMALL, frames, str(tmp_path), None, True, 64, 48, "",
                          meshes=("ply",))
        assert code == 0
    assert {name: (tmp_path / name).read_bytes() for name in LOOK_ALIKES} == before
    assert (tmp_path / "frames" / "frame_00050.d").is_dir()
    manifest = json.loads((tmp_path / MANIFEST_NAME).read_text())["files"]
    assert "stats.json" in manifest and "frames/frame_00000.png" in manifest
    assert "frames/frame_00002.png" not in manifest
    assert not (tmp_path / "frames" / "frame_00002.png").exists()  # the longer run's, removed
    assert not set(LOOK_ALIKES) & set(manifest)
    assert not (tmp_path / LOCK_NAME).exists()


def test_a_second_run_into_a_locked_folder_exits_2(tmp_path):
    (tmp_path / LOCK_NAME).write_text(f"{os.getppid()}\n")  # a live process that is not us
    result = subprocess.run([sys.executable, "-m", "taichi_cloth", "simulate", "skirt",
                             "--set", SMALL[0], "--frames", "1", "--out", str(tmp_path)],
                            cwd=REPO, capture_output=True, text=True, timeout=120)
    assert result.returncode == 2
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and "--out" in lines[0] and "another run" in lines[0]
    assert sorted(p.name for p in tmp_path.iterdir()) == [LOCK_NAME]


def test_a_killed_runs_lock_is_taken_over(tmp_path):
    dead = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"],
                          capture_output=True, text=True).stdout.strip()
    (tmp_path / LOCK_NAME).write_text(f"{dead}\n")
    assert cli.simulate("skirt", SMALL, 1, str(tmp_path), None, True) == 0
    assert (tmp_path / "stats.json").exists() and not (tmp_path / LOCK_NAME).exists()


def test_the_manifest_is_what_changed(tmp_path):
    (tmp_path / "kept.txt").write_text("mine")
    with OwnedFolder(tmp_path) as folder:
        (tmp_path / "new.txt").write_text("run")
        folder.finish()
    assert json.loads((tmp_path / MANIFEST_NAME).read_text())["files"] == ["new.txt"]
    with OwnedFolder(tmp_path) as folder:
        folder.finish()  # wrote nothing: the earlier run's file goes, the user's stays
    assert sorted(p.name for p in tmp_path.iterdir()) == ["kept.txt", MANIFEST_NAME]


@pytest.mark.parametrize("resumed", [True, False])
def test_a_resumed_run_keeps_what_it_continues(tmp_path, resumed):
    with OwnedFolder(tmp_path) as folder:
        (tmp_path / "frame_00000.png").write_text("0")
        folder.finish()
    with OwnedFolder(tmp_path) as folder:
        (tmp_path / "frame_00001.png").write_text("1")
        folder.finish(resumed)
    names = json.loads((tmp_path / MANIFEST_NAME).read_text())["files"]
    expected = ["frame_00000.png", "frame_00001.png"] if resumed else ["frame_00001.png"]
    assert names == expected and (tmp_path / "frame_00000.png").exists() == resumed


@pytest.mark.parametrize("name, slug", [
    ("hula", "hula"), ("/abs/dir", "abs-dir"), ("../../x", "x"), ("a\x00b", "a-b"),
    ("My skirt: v2", "My-skirt-v2"), ("...", "scene"), ("x" * 5000, "x" * 80),
])
def test_a_scene_name_is_never_a_path(name, slug):
    assert safe_name(name) == slug


def test_a_scene_named_like_a_path_writes_under_output(tmp_path, monkeypatch):
    monkeypatch.chdir(tmp_path)
    scene_file = tmp_path / "evil.toml"
    scene_file.write_text((REPO / "scenes" / "skirt.toml").read_text().replace(
        "[scene]", "[scene]\nname = \"../../escaped\"", 1))
    assert cli.simulate(str(scene_file), SMALL, 1, None, None, True) == 0
    assert (tmp_path / "output" / "escaped" / "stats.json").exists()
    assert not (tmp_path.parent.parent / "escaped").exists()


@pytest.mark.parametrize("argv, words", [
    (["simulate", "sheet", "--set", "cloth.resolution=[4000, 4000]"],
     ["cloth.resolution", "GB", "--max-memory"]),
    (["simulate", "hula-paper", "--set", "simulation.dt=1e-9"],
     ["simulation.dt", "h", "--max-hours"]),
    (["simulate", "sheet", "--max-hours", "nan"], ["--max-hours"]),
    (["simulate", "sheet", "--max-hours", "1e-6"],  # FB Euler, "auto": its longest stable step
     ["simulation.dt", "use integrator = \"implicit\"", "--max-hours 1 "]),
])
def test_a_run_past_the_machine_or_the_time_bound_is_refused_before_the_work(argv, words,
                                                                             tmp_path, capsys):
    out = tmp_path / "out"
    try:
        code = cli.main(argv + ["--out", str(out)])
    except SystemExit as stop:
        code = stop.code
    error = capsys.readouterr().err.strip()
    assert code == 2 and len(error.splitlines()) == 1
    assert all(word in error for word in words)
    assert not out.exists()


@pytest.mark.parametrize("argv, test", [
    (["simulate", "lab/drape"], "drape"), (["render", "lab/cantilever"], "cantilever"),
    (["compare", "lab/drape"], "drape"),
    (["sweep", "lab/cantilever", "--grid", "cloth.material=silk,denim"], "cantilever"),
    (["bench", "--scene", "lab/drape"], "drape"),
])
def test_a_lab_specimen_is_sent_to_fabric_test(argv, test, tmp_path, capsys):
    """The lab's scenes step 0.5 s at a time, Newton steps from rest that ``fabric-test``
    takes: any command that would run one frame by frame refuses it in a one-line error naming
    that command (``simulate`` blew up in its first frame, exit 3), and writes nothing."""
    out = tmp_path / "out"
    code, error = run_main(argv + ([] if argv[0] == "bench" else ["--out", str(out)]), capsys)
    assert code == 2 and len(error.splitlines()) == 1
    assert f"lab/{test}" in error and f"fabric-test {test}" in error
    assert not out.exists()


def run_main(argv, capsys) -> tuple[int, str]:
    try:
        code = cli.main(argv)
    except SystemExit as stop:
        code = stop.code
    return code, capsys.readouterr().err.strip()


@pytest.mark.parametrize("obstacle", ["file named frames", "folder named stats.json",
                                      "out is a symlink loop"])
def test_obstacles_in_the_output_folder_are_one_line_exit_2(obstacle, tmp_path, capsys):
    out = tmp_path / "out"
    if obstacle == "out is a symlink loop":
        out.symlink_to(out)
    else:
        out.mkdir()
        if obstacle == "file named frames":
            (out / "frames").write_text("not a folder")
        else:
            (out / "stats.json").mkdir()
    argv = ["skirt", "--set", SMALL[0], "--frames", "1", "--out", str(out)]
    argv = ["render", *argv, "--width", "64", "--height", "48"] \
        if obstacle == "file named frames" else ["simulate", *argv]
    code, error = run_main(argv, capsys)
    assert code == 2 and len(error.splitlines()) == 1 and "Traceback" not in error, error
    if obstacle == "file named frames":
        assert (out / "frames").read_text() == "not a folder"


def test_the_resume_hint_names_this_interpreter_and_resume_once(monkeypatch):
    from taichi_cloth.output.run import resume_command
    monkeypatch.setattr(sys, "argv", ["x", "simulate", "hula", "--resume", "--frames", "3"])
    command = resume_command()
    assert command.count("--resume") == 1 and "-m taichi_cloth simulate hula" in command
    assert command.split()[0].endswith("python") or "python" in command.split()[0]


def test_the_resume_hint_names_the_console_command_when_started_by_it(monkeypatch):
    from taichi_cloth.output.run import resume_command
    monkeypatch.setattr(sys, "argv", ["/opt/env/bin/taichi-cloth", "render", "hula", "--resume"])
    assert resume_command() == "/opt/env/bin/taichi-cloth render hula --resume"


def test_a_bad_output_dir_from_the_scene_is_named_as_such(tmp_path, capsys):
    blocker = tmp_path / "file"
    blocker.write_text("")
    code, error = run_main(["simulate", "sheet", "--set", f"output.dir='{blocker / 'sub'}'",
                            "--frames", "1"], capsys)
    assert code == 2 and error.startswith("error: output.dir ") and len(error.splitlines()) == 1


def test_a_full_disk_is_one_line_exit_1_and_keeps_the_whole_frames(tmp_path, capsys,
                                                                     monkeypatch):
    """The disk fills up while frame 2 is written: exit 1 with one line; frames 0 and 1,
    stats.json for them and a checkpoint remain (there was room for those)."""
    import errno as errno_codes

    from taichi_cloth.output import run as run_module
    real_write = run_module.write_png

    def write_until_full(target, image):
        if target.name == "frame_00002.png":
            raise OSError(errno_codes.ENOSPC, "No space left on device", str(target))
        real_write(target, image)

    monkeypatch.setattr(run_module, "write_png", write_until_full)
    out = tmp_path / "out"
    code, error = run_main(["render", "skirt", "--set", SMALL[0], "--frames", "3", "--out",
                            str(out), "--width", "64", "--height", "48"], capsys)
    assert code == 1 and len(error.splitlines()) == 1 and "disk is full" in error
    assert sorted(p.name for p in (out / "frames").iterdir()) == ["frame_00000.png",
                                                                  "frame_00001.png"]
    stats = json.loads((out / "stats.json").read_text())
    assert stats["stopped"] == "file-system error" and len(stats["per_frame"]) == 2
    assert (out / "checkpoint.npz").exists() and not (out / LOCK_NAME).exists()


def test_the_summary_fits_in_100_columns():
    """The run's summary at its longest (a long scene name, halvings, the auto step, six
    phases): every line but the folder's path within 100 columns."""
    from taichi_cloth.output.run import summary
    stats = {"scene": "x" * 24, "frames": 100000, "integrator": "symplectic", "dt": 1.23456e-05,
             "substeps_per_frame": 27000, "retries": 12,
             "time_step": {"requested": "auto", "stable_dt": 1.2345e-05, "omega_max": 1.2345e5},
             "max_strain": 0.12345, "max_penetration": 0.012345, "max_self_intersections": 123456,
             "wall_seconds": {name: 12345.678 for name in ("compile", "settle", "simulate",
                                                           "render", "export", "other")}}
    text = summary(stats, Path("/a/long/output/folder"))
    assert text.endswith(" → /a/long/output/folder") and "symplectic" in text
    lines = text.removesuffix(" → /a/long/output/folder").splitlines()
    assert len(lines) <= 6 and all(len(line) <= 100 for line in lines)
    assert sum(line.count("12345.68 s") for line in lines) == 6
    for settled, said in (({"at_rest": True, "step_halvings": 2}, "settled at 1/4 of the "),
                          ({"at_rest": False, "step_halvings": 0, "simulated_seconds": 3.0,
                            "mean_speed": 0.3}, "not at rest after 3.00 s"),
                          ({"at_rest": True, "step_halvings": 0}, None)):
        lines = summary(stats | {"settle": settled}, Path("out")).splitlines()
        settling = [line for line in lines if line.startswith(("  settled", "  settling"))]
        assert len(settling) == (0 if said is None else 1)
        assert said is None or said in settling[0]
        assert all(len(line) <= 100 for line in lines[:-1])


def test_the_summary_says_when_a_given_step_was_split_for_self_collision():
    from taichi_cloth.output.run import summary
    stats = {"scene": "hula-paper", "frames": 150, "integrator": "symplectic", "dt": 3.3e-4,
             "substeps_per_frame": 101, "retries": 0, "max_strain": 0.1, "max_penetration": 0.0,
             "max_self_intersections": 0, "effects": ["gravity", "self_collision"],
             "wall_seconds": {"simulate": 2.0}}
    for stable, shown in ((4.142e-4, True), (None, False)):
        text = summary(stats | {"time_step": {"requested": 0.002, "stable_dt": stable}},
                       Path("out"))
        said = [line for line in text.splitlines() if "split below the scene's 0.002 s" in line]
        assert len(said) == shown and all(len(line) <= 100 for line in said)
        assert not shown or "0.000414 s" in said[0]
        advice = [line for line in text.splitlines() if "simulation.integrator=implicit" in line]
        assert len(advice) == shown and all(len(line) <= 100 for line in advice)


def test_the_summary_says_how_to_add_self_collision_only_where_the_cloth_crossed_without_it():
    from taichi_cloth.output.run import summary
    stats = {"scene": "hula", "frames": 150, "integrator": "implicit", "dt": 1 / 60,
             "substeps_per_frame": 2, "retries": 0, "time_step": {"requested": 1 / 60},
             "max_strain": 0.02, "max_penetration": 0.0, "wall_seconds": {"simulate": 2.0}}
    hint = "--set effects.self_collision=true"
    for effects, crossings, shown in ((["gravity", "collision"], 313, True),
                                      (["gravity", "collision"], 0, False),
                                      (["gravity", "self_collision"], 2, False)):
        text = summary(stats | {"effects": effects, "max_self_intersections": crossings},
                       Path("out"))
        assert (hint in text) == shown
        assert all(len(line) <= 100 for line in text.removesuffix(" → out").splitlines())
