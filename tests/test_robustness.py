"""Bad input everywhere, nothing lost, reproducible runs (through the command line, in-process).

Every bad input exits 2 with one line naming the file, key or flag (and the allowed values where
there is a list), no traceback, and no output folder created or altered. The same scene and
options give bit-identical stats and meshes. An interrupted run keeps its whole frames, a valid
stats.json and a checkpoint, and resuming it gives exactly the uninterrupted run.
"""

import json
import os
import subprocess
import sys

import numpy as np
import pytest

from taichi_cloth.cli import main
from taichi_cloth.physics.simulation import Simulation

SMALL = ["--set", "cloth.resolution=[6, 5]", "--frames", "2", "--quiet"]

BAD_INPUT = [
    # (argv, words the one line must contain)
    (["simulate", "sheet", "--set", "simulation.dt=0"], ["simulation.dt", "> 0"]),
    (["simulate", "sheet", "--set", "simulation.dt=-1e-3"], ["simulation.dt", "> 0"]),
    (["simulate", "sheet", "--set", "cloth.material.density=0"], ["cloth.material.density"]),
    (["simulate", "sheet", "--set", "cloth.material.thickness=-1"], ["cloth.material.thickness"]),
    (["simulate", "sheet", "--set", "cloth.resolution=[8, 0]"], ["cloth.resolution[1]"]),
    (["simulate", "sheet", "--set", "scene.fps=0"], ["scene.fps", ">= 1"]),
    (["simulate", "sheet", "--set", "scene.duration=nan"], ["scene.duration", "finite"]),
    (["simulate", "sheet", "--set", "effects.gravity.g=inf"], ["effects.gravity.g", "finite"]),
    (["simulate", "flag", "--set", "effects.wind.strength=-inf"], ["effects.wind.strength"]),
    (["simulate", "hula", "--set", "effects.collision.thickness=-0.01"],
     ["effects.collision.thickness"]),
    (["simulate", "sheet", "--set", "simulation.integrator=verlet"],
     ["simulation.integrator", "'implicit'"]),
    (["simulate", "sheet", "--set", "cloth.material=linen"], ["cloth.material", "'denim'"]),
    (["simulate", "sheet", "--set", "effects.magnetism=true"], ["effects.magnetism", "wind"]),
    (["simulate", "hula", "--set", "body.motion=salsa"], ["body.motion", "'hula'"]),
    (["simulate", "sheet", "--set", "output.meshes=['stl']"], ["output.meshes[0]", "'vtu'"]),
    (["simulate", "sheet", "--set", "output.video=avi"], ["output.video", "'mp4'"]),
    (["simulate", "sheet", "--meshes", "stl"], ["--meshes", "stl"]),
    (["simulate", "sheet", "--set", "cloth.resolutoin=[4, 4]"], ["did you mean 'resolution'"]),
    (["simulate", "sheet", "--set", "simulation.integrater=rk4"], ["did you mean 'integrator'"]),
    (["simulate", "sheet", "--set", "scene.fps='many'"], ["scene.fps", "integer"]),
    (["simulate", "sheet", "--set", "cloth.size=1.0"], ["cloth.size", "list"]),
    (["simulate", "sheet", "--set", "=2"], ["--set =2", "KEY=VALUE"]),
    (["simulate", "sheet", "--set", "cloth.size=[1.0,"], ["--set cloth.size", "TOML"]),
    (["simulate", "sheet", "--set", "cloth"], ["--set cloth", "KEY=VALUE"]),
    (["simulate", "no-such-scene"], ["no-such-scene", "shipped scenes"]),
    (["simulate", "missing/scene.toml"], ["missing/scene.toml", "not found"]),
    (["simulate", "sheet", "--frames", "-3"], ["--frames"]),
    (["simulate", "sheet", "--out", "/proc/taichi_cloth/out"], ["--out", "cannot write"]),
    (["render", "hula", "--set", "render.texture='missing.png'"], ["render.texture"]),
    (["render", "hula", "--width", "3"], ["--width"]),
    (["simulate", "sheet", "--resume"], ["--resume", "checkpoint"]),
]


@pytest.mark.parametrize("argv, words", BAD_INPUT, ids=[" ".join(a[1:]) for a, _ in BAD_INPUT])
def test_bad_input_exits_2_with_one_line_and_touches_nothing(argv, words, tmp_path, capsys):
    out = tmp_path / "out"
    if "--out" not in argv:
        argv = argv + ["--out", str(out)]
    if "--resume" in argv:  # an earlier, finished run is there: it must stay as it is
        out.mkdir()
        (out / "stats.json").write_text("{\"frames\": 1}\n")
    assert run_cli(argv) == 2
    error = capsys.readouterr().err.strip()
    assert len(error.splitlines()) == 1 and "Traceback" not in error
    for word in words:
        assert word in error
    if "--resume" in argv:
        assert (out / "stats.json").read_text() == "{\"frames\": 1}\n"
        assert sorted(p.name for p in out.iterdir()) == ["stats.json"]
    else:
        assert not out.exists()


def run_cli(argv) -> int:
    """The exit code of ``python -m taichi_cloth ARGV``, run in this process (argparse's own
    errors arrive as SystemExit)."""
    try:
        return main(argv)
    except SystemExit as exit_:
        return exit_.code


def interrupt_at(frame_to_stop: int):
    """A ``Simulation.measure`` that raises KeyboardInterrupt (Ctrl-C) when it reaches
    ``frame_to_stop``, after the frames before it were whole."""
    measure = Simulation.measure

    def measure_or_stop(self, frame, x, v, *counted, **taken):
        if frame == frame_to_stop:
            raise KeyboardInterrupt
        return measure(self, frame, x, v, *counted, **taken)

    return measure_or_stop


def comparable(stats: dict) -> dict:
    """stats.json without what depends on the machine's speed."""
    return {key: value for key, value in stats.items() if key != "wall_seconds"}


@pytest.mark.parametrize("scene, extra", [
    ("hula", ["--set", "cloth.resolution=[12, 6]"]),
    ("flag", ["--set", "cloth.resolution=[8, 5]", "--set", "simulation.integrator=implicit",
              "--set", "simulation.dt=0.0166667"]),
])
def test_identical_runs_are_bit_identical(scene, extra, tmp_path):
    """Once in this process, once in a fresh one on a single CPU thread: the same bytes."""
    argv = ["simulate", scene, "--frames", "3", "--quiet", "--meshes", "obj,ply,vtu", *extra]
    outputs = [tmp_path / "here", tmp_path / "one_thread"]
    assert run_cli(argv + ["--out", str(outputs[0])]) == 0
    single = subprocess.run([sys.executable, "-m", "taichi_cloth", *argv, "--out",
                             str(outputs[1])], capture_output=True, text=True, timeout=300,
                            env={**os.environ, "TI_CPU_MAX_NUM_THREADS": "1"})
    assert single.returncode == 0, single.stderr
    first, second = (json.loads((o / "stats.json").read_text()) for o in outputs)
    assert comparable(first) == comparable(second)
    meshes = sorted(p.name for p in (outputs[0] / "meshes").iterdir())
    assert len(meshes) >= 9
    for name in meshes:
        assert (outputs[0] / "meshes" / name).read_bytes() == \
            (outputs[1] / "meshes" / name).read_bytes(), name


@pytest.mark.parametrize("integrator", ["symplectic", "implicit"])  # implicit: warm start kept
def test_interrupted_run_keeps_its_frames_and_resumes_to_the_same_result(tmp_path, monkeypatch,
                                                                          capsys, integrator):
    argv = ["simulate", "hula", "--set", "cloth.resolution=[12, 6]", "--frames", "5", "--quiet",
            "--set", f"simulation.integrator={integrator}", "--meshes", "vtu",
            "--set", "simulation.settle=0.2"]  # settled briefly: the resume keeps its report
    whole = tmp_path / "whole"
    assert run_cli(argv + ["--out", str(whole)]) == 0

    stopped = tmp_path / "stopped"
    with monkeypatch.context() as patch:
        patch.setattr(Simulation, "measure", interrupt_at(3))
        assert run_cli(argv + ["--out", str(stopped)]) == 130
    message = capsys.readouterr().err
    assert "stopped after frame 2" in message and "--resume" in message
    partial = json.loads((stopped / "stats.json").read_text())
    assert partial["stopped"] == "interrupted" and partial["frames"] == 3
    assert (stopped / "checkpoint.npz").exists()

    assert run_cli(argv + ["--out", str(stopped), "--resume"]) == 0
    resumed = json.loads((stopped / "stats.json").read_text())
    assert resumed.pop("resumed_at_frame") == 3
    assert comparable(resumed) == comparable(json.loads((whole / "stats.json").read_text()))
    assert not (stopped / "checkpoint.npz").exists()
    for name in ("cloth.pvd", "cloth_00001.vtu", "cloth_00005.vtu"):  # the series made whole
        assert (stopped / "meshes" / name).read_bytes() == (whole / "meshes" / name).read_bytes()
    for frame in range(6):  # and the simulation cache: every frame, as the whole run's
        for path in (stopped, whole):
            assert (path / "cache" / f"frame_{frame:05d}.npz").is_file()
        with np.load(stopped / "cache" / f"frame_{frame:05d}.npz") as resumed_frame, \
                np.load(whole / "cache" / f"frame_{frame:05d}.npz") as whole_frame:
            np.testing.assert_array_equal(resumed_frame["positions"], whole_frame["positions"])


def test_resume_refuses_a_checkpoint_of_other_settings(tmp_path, monkeypatch, capsys):
    argv = ["simulate", "sheet", *SMALL, "--frames", "3", "--out", str(tmp_path)]
    with monkeypatch.context() as patch:
        patch.setattr(Simulation, "measure", interrupt_at(1))
        assert run_cli(argv) == 130
    before = {p: p.read_bytes() for p in tmp_path.rglob("*") if p.is_file()}
    assert run_cli(argv + ["--set", "cloth.material=silk", "--resume"]) == 2
    assert "other scene settings" in capsys.readouterr().err
    assert {p: p.read_bytes() for p in tmp_path.rglob("*") if p.is_file()} == before


def test_serial_launches_are_bounded_so_interrupts_are_honoured():
    """A frame of many substeps on small cloth runs as several launches, each at most
    SERIAL_LAUNCH_WORK particle-substeps (Ctrl-C waits for the launch running), in order."""
    from taichi_cloth.physics.integrators.base import SERIAL_LAUNCH_WORK
    simulation = Simulation.from_scene("sheet", ("cloth.resolution=[10, 10]",
                                                 "simulation.dt=1e-7"))
    integrator = simulation.integrator
    assert integrator.serial
    substeps = simulation.time_step.substeps_per_frame
    counts = integrator.launch_counts(substeps)
    assert sum(counts) == substeps and len(counts) > 1
    assert max(counts) * simulation.model.particle_count <= SERIAL_LAUNCH_WORK
    assert integrator.launch_counts(7) == [7]


def test_a_texture_that_is_not_an_image_is_one_line(tmp_path, capsys):
    fake = tmp_path / "fake.png"
    fake.write_text("not an image")
    assert run_cli(["render", "hula", "--set", f"render.texture='{fake}'", "--frames", "1",
                    "--out", str(tmp_path / "out")]) == 2
    error = capsys.readouterr().err.strip()
    assert len(error.splitlines()) == 1 and "render.texture" in error


def test_arch_cuda_without_cuda_is_one_line_in_a_fresh_process(tmp_path):
    result = subprocess.run([sys.executable, "-m", "taichi_cloth", "simulate", "sheet", "--arch",
                             "cuda", "--frames", "1", "--out", str(tmp_path / "out")],
                            capture_output=True, text=True, timeout=120)
    if result.returncode == 0:
        pytest.skip("this machine has CUDA")
    assert result.returncode == 2
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and "--arch cuda" in lines[0]


def test_a_kernel_compile_error_still_names_its_file_line_and_function(tmp_path, monkeypatch):
    """``runtime.short_position_info`` drops Taichi's source excerpt from compile errors, not
    where the error is."""
    import taichi as ti
    source = tmp_path / "broken_kernel.py"
    source.write_text("import taichi as ti\n\n\n@ti.kernel\ndef broken() -> ti.i32:\n"
                      "    return undefined_name\n")
    monkeypatch.syspath_prepend(str(tmp_path))
    import broken_kernel
    with pytest.raises(ti.TaichiNameError) as error:
        broken_kernel.broken()
    assert f'File "{source}", line 6, in broken:' in str(error.value)
    assert "undefined_name" in str(error.value)
