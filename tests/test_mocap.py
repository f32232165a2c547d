"""Motion capture: the natural cubic spline, BVH files written from the procedural dances and
read back (Mixamo names in cm with y up, CMU names in m with z up), the capsule body they drive
against the procedural one, clip times, loops and ease-in, and bad files as one-line errors."""

import dataclasses
import math
from pathlib import Path

import numpy as np
import pytest

from taichi_cloth import cli
from taichi_cloth.body.bvh_export import (MIXAMO_NAMES, dance_joints, shortest_rotation,
                                          write_dance_bvh)
from taichi_cloth.body.dancer import Body
from taichi_cloth.body.mocap import CMU, JOINT_NAMES, MocapBody, leg_length, read_clip, unit_of
from taichi_cloth.body.spline import CubicSpline
from taichi_cloth.config.tables import BvhConfig
from taichi_cloth.errors import InputError

REPO = Path(__file__).resolve().parent.parent
FPS = 30
CMU_NAMES = {"hips": "root", "spine": "lowerback", **CMU}


def test_the_spline_passes_through_the_samples_and_is_twice_differentiable():
    t = np.arange(9) * 0.1
    samples = np.stack([np.sin(3 * t), t ** 3], axis=1)
    spline = CubicSpline(samples, 0.1)
    for k in range(9):
        np.testing.assert_allclose(spline(t[k])[0], samples[k], atol=1e-14)
    h = 1e-6
    for s in (0.05, 0.23, 0.4, 0.61):  # the derivative is the value's slope
        slope = (spline(s + h)[0] - spline(s - h)[0]) / (2 * h)
        np.testing.assert_allclose(spline(s)[1], slope, rtol=1e-6, atol=1e-8)
    for knot in t[1:-1]:  # the slope's slope is continuous across every sample
        left = (spline(knot)[1] - spline(knot - 1e-4)[1]) / 1e-4
        right = (spline(knot + 1e-4)[1] - spline(knot)[1]) / 1e-4
        np.testing.assert_allclose(left, right, atol=1e-2)  # O(h): no kink of size O(1)
    assert math.isclose(spline(0.31)[0][0], math.sin(0.93), abs_tol=5e-3)  # and close to sin


@pytest.fixture(scope="module")
def clips(tmp_path_factory):
    """The twirl (two whole turns, looping) in each naming, unit and up axis, and a 2 s hula."""
    folder = tmp_path_factory.mktemp("bvh")
    twirl = Body("twirl", 90.0, 1.0, "split", 1.0, 0.0)
    hula = Body("hula", 90.0, 1.0, "split", 1.0, 0.0)
    for names, label in ((MIXAMO_NAMES, "mixamo"), (CMU_NAMES, "cmu")):
        for up, unit, unit_name in (("y", 1.0, "m"), ("z", 0.01, "cm"), ("y", 0.0254, "inch")):
            write_dance_bvh(twirl, folder / f"twirl_{label}_{up}_{unit_name}.bvh",
                            twirl.loop_period, FPS, names, up, unit)
    write_dance_bvh(hula, folder / "hula.bvh", 2.0, FPS)
    return folder, twirl, hula


def test_a_bvh_written_from_a_dance_reads_back_to_its_joints(clips):
    folder, twirl, hula = clips
    for name, body, metres in (("hula.bvh", hula, 0.01), ("twirl_mixamo_y_m.bvh", twirl, 1.0)):
        joints, _, frame_time = read_clip(folder / name, ())
        assert math.isclose(frame_time, 1 / FPS)
        for frame in range(0, len(joints), 7):
            expected, _ = dance_joints(body, body.pose(frame / FPS))
            for k, joint in enumerate(JOINT_NAMES):
                np.testing.assert_allclose(joints[frame, k] * metres, expected[joint], atol=1e-6)


@pytest.mark.parametrize("names", ["mixamo", "cmu"])
@pytest.mark.parametrize("axes", ["y_m", "z_cm", "y_inch"])
def test_both_conventions_drive_the_capsules_of_the_dance(clips, names, axes):
    """Mixamo and CMU names, in m with y up, cm with z up or inches, map onto the same capsules,
    along the same bones, as the procedural dance they were written from (the clip loops: its
    last frame is its first), with its velocities and pelvis frame; units and up found alone."""
    name = f"twirl_{names}_{axes}.bvh"
    folder, twirl, _ = clips
    mocap = MocapBody(folder / name, BvhConfig(), "split", 1.0, ease_in=0.0)
    assert mocap.loops and math.isclose(mocap.period, twirl.loop_period)
    assert mocap.capsule_names == twirl.capsule_names
    np.testing.assert_allclose(mocap.capsule_radius, twirl.capsule_radius, rtol=1e-5)
    for t in (0.0, 0.4, 1.17, 2.5, twirl.loop_period + 0.4):
        want, got = twirl.pose(t), mocap.pose(t)
        for field in ("capsule_a", "capsule_b", "pelvis_position", "pelvis_rotation",
                      "chest_position", "chest_rotation"):
            np.testing.assert_allclose(getattr(got, field), getattr(want, field), atol=1e-4)
        for field in ("capsule_velocity_a", "pelvis_velocity", "pelvis_angular_velocity",
                      "chest_velocity", "chest_angular_velocity"):
            np.testing.assert_allclose(getattr(got, field), getattr(want, field), atol=2e-3)
        np.testing.assert_allclose(got.display_capsule_a[2:], want.display_capsule_a[2:],
                                   atol=1e-4)  # shoulders, elbows, ankles


def test_velocities_are_the_derivatives_of_the_pose(clips):
    folder = clips[0]
    mocap = MocapBody(folder / "hula.bvh", BvhConfig(), "coarse", 1.0, ease_in=0.5)
    h = 1e-5
    for t in (0.2, 0.7, 1.3):
        ahead, behind, now = mocap.pose(t + h), mocap.pose(t - h), mocap.pose(t)
        np.testing.assert_allclose(now.capsule_velocity_b,
                                   (ahead.capsule_b - behind.capsule_b) / (2 * h), atol=1e-5)
        np.testing.assert_allclose(now.pelvis_velocity,
                                   (ahead.pelvis_position - behind.pelvis_position) / (2 * h),
                                   atol=1e-5)
        spin = (ahead.chest_rotation - behind.chest_rotation) / (2 * h) @ now.chest_rotation.T
        np.testing.assert_allclose(now.chest_angular_velocity,
                                   [spin[2, 1], spin[0, 2], spin[1, 0]], atol=1e-4)


def test_clip_times_ease_in_and_a_clip_that_ends(clips):
    folder, _, hula = clips
    settings = BvhConfig(start=0.5, end=1.5)
    mocap = MocapBody(folder / "hula.bvh", settings, "split", 1.0, ease_in=0.0)
    assert not mocap.loops and math.isclose(mocap.period, 1.0)
    # centred on its first frame (its pelvis frame from the hips and the neck there: the back's
    # tilt against the pelvis moves the pelvis capsule and the waist by under a millimetre)
    shift = hula.pose(0.5).capsule_a - mocap.pose(0.0).capsule_a
    np.testing.assert_allclose(shift, np.broadcast_to(shift[0], shift.shape), atol=1e-3)
    assert abs(shift[0, 1]) < 1e-3  # the lower ankle on the dancer's ankle height
    np.testing.assert_allclose(hula.pose(1.2).capsule_a - mocap.pose(0.7).capsule_a, shift,
                               atol=1e-4)  # 0.5 s into the clip: the same shift
    held = mocap.pose(3.0)  # past its end: the last frame, still
    np.testing.assert_allclose(held.capsule_a, mocap.pose(1.0).capsule_a, atol=1e-9)
    assert np.abs(held.capsule_velocity_a).max() == 0.0
    eased = MocapBody(folder / "hula.bvh", BvhConfig(), "split", 1.0, ease_in=1.0)
    assert np.abs(eased.pose(0.0).capsule_velocity_a).max() == 0.0  # starts still ...
    np.testing.assert_allclose(eased.pose(0.01).capsule_a, eased.pose(0.0).capsule_a,
                               atol=1e-6)  # ... and barely moves at first
    with pytest.raises(InputError, match="leave no motion"):
        MocapBody(folder / "hula.bvh", BvhConfig(start=1.5, end=1.0), "split")


def write_text(folder: Path, name: str, text: str) -> Path:
    (folder / name).write_text(text)
    return folder / name


def test_bad_files_are_one_line_exit_2(clips, tmp_path, capsys):
    good = (clips[0] / "hula.bvh").read_text()
    motion = good.index("MOTION")
    bad = {
        "missing": good.replace("LeftFoot", "LeftPaw"),
        "channels": good.replace("CHANNELS 3 Zrotation Xrotation Yrotation",
                                 "CHANNELS 2 Zrotation Xrotation", 1),
        "truncated": good[:motion] + good[motion:].replace("Frames: 61", "Frames: 90"),
        "nan": good[:motion] + good[motion:].replace("0.000000", "nan", 3),
        "empty": "HIERARCHY\nROOT Hips\n{\n",
    }
    for name, text in bad.items():
        path = write_text(tmp_path, f"{name}.bvh", text)
        scene = write_text(tmp_path, f"{name}.toml", f'[scene]\nduration = 0.1\n[cloth]\nshape = '
                           f'"skirt"\nresolution = [8, 4]\npin = "waist"\n[body]\nmotion = "bvh"\n'
                           f'bvh = "{path.name}"\n')
        assert cli.main(["simulate", str(scene), "--quiet", "--out",
                         str(tmp_path / "out")]) == 2, name
        error = capsys.readouterr().err.strip()
        assert "\n" not in error and f"{name}.bvh" in error, error
    with pytest.raises(InputError, match="ankle_left"):
        read_clip(tmp_path / "missing.bvh", ())
    joints, _, _ = read_clip(tmp_path / "missing.bvh", ("ankle_left=LeftPaw",))  # named by hand
    assert joints.shape[1] == len(JOINT_NAMES)


def test_the_shortest_rotation_turns_a_bone_onto_any_direction_even_the_opposite():
    rng = np.random.default_rng(3)
    for a, b in [(v, rng.normal(size=3)) for v in rng.normal(size=(4, 3))] + \
            [(np.array([0.0, 1.0, 0.0]), np.array([0.0, -2.0, 0.0])),
             (np.array([0.3, -0.2, 0.9]), np.array([-0.3, 0.2, -0.9]))]:
        rotation = shortest_rotation(a, b)
        np.testing.assert_allclose(rotation @ rotation.T, np.eye(3), atol=1e-12)
        assert np.isclose(np.linalg.det(rotation), 1.0)
        np.testing.assert_allclose(rotation @ a / np.linalg.norm(a), b / np.linalg.norm(b),
                                   atol=1e-12)


def test_a_leg_of_no_adult_length_in_any_unit_asks_for_the_unit(clips):
    """"auto" takes the unit in which the leg is an adult's; a clip scaled as the CMU cgspeed
    exports are (a leg ~14.6 units: 0.37 m in inches, 14.6 m in metres) is refused, naming the
    setting, and read in the unit the scene gives."""
    joints, _, _ = read_clip(clips[0] / "twirl_cmu_z_cm.bvh", ())
    leg = leg_length(joints[0])
    assert unit_of(joints[0], "auto", "clip.bvh") == 0.01 and 0.5 < leg / 100 < 1.2
    cgspeed = joints[0] * 14.6 / leg
    with pytest.raises(InputError, match=r"clip\.bvh: the leg is 14\.6 units.*body\.bvh\.units"):
        unit_of(cgspeed, "auto", "clip.bvh")
    assert unit_of(cgspeed, "inch", "clip.bvh") == 0.0254


def test_the_mocap_scene_runs_on_its_shipped_clip():
    """``mocap``: the cotton skirt on scenes/motions/hula.bvh, coarse and short: finite, within
    the contact margin and the strain limit."""
    from taichi_cloth.config.scene import load_scene
    from taichi_cloth.physics.simulation import Simulation
    from taichi_cloth.physics.settling import settle
    from taichi_cloth.physics.metrics import RunRecord
    scene = load_scene("mocap", ("cloth.resolution=[16, 8]", "simulation.settle=0.3"))
    simulation = Simulation(scene)
    settle(simulation, RunRecord())
    stats = simulation.stats(simulation.run(8))
    assert stats["finite"] and stats["max_strain"] < 0.05
    assert stats["max_penetration"] < scene.effects["collision"].thickness
    assert dataclasses.asdict(scene.body.bvh)["file"] == "motions/hula.bvh"
