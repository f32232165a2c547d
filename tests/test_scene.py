"""Scene files: every shipped scene loads and runs; every kind of bad input is one clear line
naming the file, key or flag, with exit code 2."""

import dataclasses
import json
import subprocess
import sys
from pathlib import Path

import pytest

from taichi_cloth.errors import InputError
from taichi_cloth.cli import main
from taichi_cloth.config.scene import SCENES_DIR, load_scene, shipped_scene_names
from taichi_cloth.physics.simulation import Simulation

REPO = Path(__file__).resolve().parent.parent


# Scenes whose runs another test makes (each compile of self-collision costs seconds): fold runs
# with and without self-collision and pile for 30 frames in tests/test_self_collision.py, mocap
# in tests/test_mocap.py, hilo (a mesh file: cloth.resolution does not shrink it) in
# tests/test_mesh_garment.py.
RUN_ELSEWHERE = {"fold", "pile", "mocap", "hilo"}


def test_scenes_run_elsewhere_are_shipped():
    assert RUN_ELSEWHERE <= set(shipped_scene_names())


@pytest.mark.parametrize("name", sorted(set(shipped_scene_names()) - RUN_ELSEWHERE))
def test_every_shipped_scene_loads_and_runs_a_few_frames(name):
    scene = load_scene(name, ("cloth.resolution=[8, 6]",))
    simulation = Simulation(scene)
    record = simulation.run(2)
    stats = simulation.stats(record)
    assert stats["finite"] and stats["frames"] == 3  # frame 0 (the start) and 2 simulated
    json.dumps(stats, allow_nan=False)
    assert set(stats["effects"]) <= set(scene.effects)


def test_overrides_parse_as_toml_with_bare_words_as_strings():
    scene = load_scene("sheet", ("simulation.integrator=rk4", "cloth.resolution=[12, 9]",
                                 "cloth.material=silk", "effects.drag=false", "simulation.dt=0.001"))
    assert scene.simulation.integrator == "rk4"
    assert scene.cloth.resolution == (12, 9)
    assert scene.material.name == "silk"
    assert "drag" not in scene.effects
    assert scene.simulation.dt == 0.001
    assert "wind" not in load_scene("sheet", ("effects.wind=false",)).effects  # a no-op
    dense = load_scene("sheet", ("cloth.material.density=0.5",))
    assert dense.material.density == 0.5 and dense.material.name == "cotton"


BAD_INPUT = [
    # (overrides, words the one-line message must contain)
    (("cloth.resolutoin=[3, 3]",), ["--set cloth.resolutoin", "did you mean 'resolution'"]),
    (("simulation.integrator=verlet",), ["simulation.integrator", "'euler'", "'rk4'"]),
    (("cloth.material=linen",), ["cloth.material", "'cotton'", "'silk'"]),
    (("effects.magnetism=true",), ["effects.magnetism", "valid: gravity"]),
    (("simulation.dt=0",), ["simulation.dt", "> 0"]),
    (("simulation.dt=-0.01",), ["simulation.dt", "> 0"]),
    (("simulation.dt=fast",), ["simulation.dt", "auto"]),
    (("cloth.resolution=[1, 8]",), ["cloth.resolution[0]", ">= 2"]),
    (("cloth.resolution=[8]",), ["cloth.resolution", "list of 2"]),
    (("cloth.material.density=0",), ["cloth.material.density", ">= 0.001", "kg/m²"]),
    (("cloth.material.density=1e-6",), ["cloth.material.density", ">= 0.001"]),
    (("cloth.material.density=130",), ["cloth.material.density", "<= 20", "g/m²"]),
    (("cloth.material.density=nan",), ["cloth.material.density", "finite"]),
    (("scene.fps='thirty'",), ["scene.fps", "integer"]),
    (("scene.duration=inf",), ["scene.duration", "finite"]),
    (("cloth.springs=['stretch', 'twist']",), ["cloth.springs[1]", "'shear'"]),
    (("cloth.springs=['stretch', 'bend']",), ["cloth.springs", "cloth.bending = \"springs\""]),
    (("cloth.bending=springs", "effects.bending.scale=2"), ["effects.bending", "curvature"]),
    (("output.meshes=['stl']",), ["output.meshes[0]", "'obj'"]),
    (("effects.gravity.g=1e39",), ["effects.gravity.g", "float32", "f64"]),
    (("scene.duration=1e308", "simulation.precision=f64"), ["scene.duration", "<= 1000000"]),
    (("cloth.material.bend_stiffness=1e-300",), ["cloth.material.bend_stiffness", "float32"]),
    (("cloth.size=[1e-300, 1e-300]",), ["cloth.size[0]", "float32"]),
    (("cloth.resolution",), ["--set cloth.resolution", "KEY=VALUE"]),
    (("cloth.resolution=[1,",), ["--set cloth.resolution", "not a valid TOML"]),
    (("colth.shape=sheet",), ["colth", "did you mean 'cloth'"]),
]


@pytest.mark.parametrize("overrides, words", BAD_INPUT)
def test_bad_input_is_one_line_naming_the_key(overrides, words):
    with pytest.raises(InputError) as caught:
        load_scene("sheet", overrides)
    message = str(caught.value)
    assert "\n" not in message
    for word in words:
        assert word in message


def test_bad_file_names_the_file(tmp_path):
    broken = tmp_path / "broken.toml"
    broken.write_text("[cloth\nshape = 'sheet'\n")
    with pytest.raises(InputError, match="broken.toml: not valid TOML"):
        load_scene(str(broken))
    typo = tmp_path / "typo.toml"
    typo.write_text("[cloth]\nshape = 'sheet'\nmaterail = 'silk'\n")
    with pytest.raises(InputError, match=r"typo.toml: cloth.materail: .*did you mean 'material'"):
        load_scene(str(typo))
    with pytest.raises(InputError, match="missing.toml: scene file not found"):
        load_scene(str(tmp_path / "missing.toml"))
    with pytest.raises(InputError, match="no such scene"):
        load_scene("no-such-scene")


def run_cli(*args, cwd=REPO):
    return subprocess.run([sys.executable, "-m", "taichi_cloth", *args], cwd=cwd,
                          capture_output=True, text=True, timeout=120)


@pytest.mark.parametrize("args, flag", [
    (["simulate", "sheet", "--set", "cloth.shape=cone"], "cloth.shape"),
    (["simulate", "sheet", "--frames", "0"], "--frames"),
    (["simulate", "sheet", "--arch", "tpu"], "--arch"),
    (["simulate", "fold", "--arch", "cuda"], "--arch cuda: self-collision"),  # CPU only
    (["compare", "fold", "--arch", "cuda"], "--arch cuda: self-collision"),
    (["simulate", "nowhere.toml"], "nowhere.toml"),
])
def test_cli_bad_input_exits_2_with_one_line_and_no_traceback(tmp_path, args, flag):
    result = run_cli(*args, "--out", str(tmp_path / "out"))
    assert result.returncode == 2
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and flag in lines[0]
    assert "Traceback" not in result.stderr
    assert not (tmp_path / "out").exists()


def test_cli_simulate_writes_stats(tmp_path):
    result = run_cli("simulate", "sheet", "--frames", "2", "--set", "cloth.resolution=[6, 6]",
                     "--out", str(tmp_path), "--quiet")
    assert result.returncode == 0, result.stderr
    stats = json.loads((tmp_path / "stats.json").read_text())
    assert stats["frames"] == 3 and stats["particles"] == 36 and stats["finite"]
    assert stats["effects"] == ["gravity", "damping", "bending", "drag"]
    assert [f["frame"] for f in stats["per_frame"]] == [0, 1, 2]
    assert [f["t"] for f in stats["per_frame"]] == pytest.approx([0, 1 / 30, 2 / 30])


def test_cli_unstable_run_exits_3_without_writing_nan(tmp_path):
    result = run_cli("simulate", "sheet", "--frames", "5", "--set", "simulation.integrator=euler",
                     "--set", "simulation.dt=0.01", "--set", "effects.damping=false",
                     "--out", str(tmp_path))
    assert result.returncode == 3
    message = result.stderr.strip()
    assert "frame 1" in message and "euler" in message and "after 4 halvings" in message
    assert "dt = 0.000520833 s" in message  # 1/30 s / 4 substeps, halved 4 times
    assert "Traceback" not in result.stderr
    stats = json.loads((tmp_path / "stats.json").read_text(),
                       parse_constant=lambda name: pytest.fail(f"{name} in stats.json"))
    assert stats["stopped"] == "unstable" and [f["frame"] for f in stats["per_frame"]] == [0]


def test_a_simulation_allocates_its_fields_in_few_snode_trees():
    """Taichi closes an SNode tree at every kernel launch (a field copy is one) and a process
    holds only about 500 (then it crashes): objects allocate all their fields before copying into
    them, so a whole dancer simulation costs 4 trees (model, states, contact, and the implicit
    integrator's, which fills its Gauss–Seidel lists at once; otherwise its first step closes it)."""
    import taichi as ti
    program = ti.lang.impl.get_runtime().prog
    scene = load_scene("hula", ("cloth.resolution=[8, 6]",))
    before = program.get_snode_tree_size()
    Simulation(scene)
    assert program.get_snode_tree_size() - before <= 4


@pytest.mark.parametrize("position", ["[0.0, 0.8, 0.0]", "[0.0, 3.0, 0.0]"])
def test_a_camera_that_cannot_see_is_refused(position):
    with pytest.raises(InputError, match="render.camera_position"):
        load_scene("hula", ("render.camera_lookat=[0.0, 0.8, 0.0]",
                            f"render.camera_position={position}"))


ALL_SCENES = sorted(p.relative_to(SCENES_DIR).with_suffix("").as_posix()
                    for p in SCENES_DIR.rglob("*.toml"))


@pytest.mark.parametrize("name", ALL_SCENES)
def test_show_prints_a_scene_that_loads_back_as_the_same_scene(name, tmp_path, capsys):
    """`show` spells out every key (defaults, the preset's values, --set applied): the printed
    TOML, loaded as a scene file, is the same Scene."""
    overrides = ("cloth.material.bend_stiffness=2e-5", "simulation.max_retries=2")
    assert main(["show", name, *(f"--set={o}" for o in overrides)]) == 0
    printed = capsys.readouterr().out
    copy = tmp_path / "shown.toml"
    copy.write_text(printed)
    original = load_scene(name, overrides)
    shown = load_scene(str(copy))
    # the fabric is spelled out in full, so its override table differs but not the fabric
    assert shown.material == original.material and shown.material.bend_stiffness == 2e-5
    assert dataclasses.replace(shown, path=original.path, cloth=dataclasses.replace(
        shown.cloth, material=original.cloth.material)) == original
