"""Tests of the kinematic dancer body (taichi_cloth.body): layouts, rest pose, motion, velocities."""

import dataclasses

import numpy as np
import pytest

from taichi_cloth.body.capsules import DISPLAY_CAPSULE_NAMES
from taichi_cloth.body.dancer import Body

# Default skirt rest shape (knee length): a cone from radius waist_radius at waist_height
# down to radius SKIRT_HEM_RADIUS at SKIRT_LENGTH below the waist, metres at scale 1.
SKIRT_HEM_RADIUS = 0.45
SKIRT_LENGTH = 0.55
# Bounds documented for the default dance (90 bpm, amplitude 1); measured values in brackets.
ACCELERATION_BOUND = 10.0  # m/s^2, capsule endpoints incl. the ease-in [4.9]
JERK_BOUND = 200.0  # m/s^3, capsule endpoints incl. the ease-in and the loop point [~60]
ANKLE_HEIGHT_BAND = (0.06, 0.10)  # m, ankle y while dancing [0.070 .. 0.090]
KNEE_FLEXION_BAND = (5.0, 50.0)  # degrees, while dancing [11 .. 43, swing leg highest]
SAMPLE_STEP = 2e-3  # s, sampling of the trajectories for second differences


def point_capsule_clearance(point, a, b, radius):
    """Distance (N,) from points (N, 3) to the surface of the capsule a-b of ``radius`` (<0 inside)."""
    ab = b - a
    along = np.clip((point - a) @ ab / (ab @ ab), 0.0, 1.0)
    return np.linalg.norm(point - (a + along[:, None] * ab), axis=1) - radius


def skirt_cone_points(body, theta_count=90, depth_count=56):
    """Points (N, 3) on the default skirt cone around the rest waist circle."""
    length, hem_radius = SKIRT_LENGTH * body.scale, SKIRT_HEM_RADIUS * body.scale
    theta, depth = np.meshgrid(np.linspace(0.0, 2.0 * np.pi, theta_count, endpoint=False),
                               np.linspace(0.0, length, depth_count))
    radius = body.waist_radius + (hem_radius - body.waist_radius) * depth / length
    return np.stack([radius * np.cos(theta), body.waist_height - depth, radius * np.sin(theta)], axis=-1).reshape(-1, 3)


def waist_ring_points(body, pose, count=90):
    """World points (N, 3) of the waist circle carried by the pelvis frame."""
    theta = np.linspace(0.0, 2.0 * np.pi, count, endpoint=False)
    local = body.waist_radius * np.stack([np.cos(theta), np.zeros_like(theta), np.sin(theta)], axis=1)
    return local @ pose.pelvis_rotation.T + pose.pelvis_position


def leg_capsule_index(body, bone):
    """Indices of the capsules of ``bone`` (e.g. "thigh_left") from hip to ankle."""
    return [i for i, name in enumerate(body.capsule_names) if name == bone or name.startswith(bone + "_")]


def knee_flexion(body, pose, side):
    """Knee flexion angle (degrees) of one leg: angle between thigh and shin directions."""
    thigh, shin = leg_capsule_index(body, f"thigh_{side}"), leg_capsule_index(body, f"shin_{side}")
    thigh_vector = pose.capsule_b[thigh[-1]] - pose.capsule_a[thigh[0]]
    shin_vector = pose.capsule_b[shin[-1]] - pose.capsule_a[shin[0]]
    cosine = thigh_vector @ shin_vector / np.linalg.norm(thigh_vector) / np.linalg.norm(shin_vector)
    return np.degrees(np.arccos(np.clip(cosine, -1.0, 1.0)))


@pytest.fixture(scope="module")
def dance():
    """Default dance sampled from t = 0 through one loop past the ease-in plus 0.5 s."""
    body = Body()
    time = np.arange(0.0, body.ease_in + body.loop_period + 0.5, SAMPLE_STEP)
    return body, time, [body.pose(t) for t in time]


def test_capsule_counts_and_names():
    coarse, split = Body(capsules="coarse"), Body(capsules="split")
    assert coarse.capsule_count == 7 and split.capsule_count == 14
    assert coarse.capsule_names == ("pelvis", "back", "thigh_left", "thigh_right", "shin_left",
                                    "shin_right", "shoulders")
    assert split.capsule_names[:3] == ("pelvis", "back_lower", "back_upper")
    for body in (coarse, split):
        assert len(set(body.capsule_names)) == body.capsule_count
        assert body.capsule_radius.shape == (body.capsule_count,)
        pose = body.pose(2.0)
        assert pose.capsule_a.shape == pose.capsule_velocity_b.shape == (body.capsule_count, 3)
        assert pose.display_capsule_a.shape == (body.display_capsule_count, 3)
        assert body.display_capsule_radius.shape == (body.display_capsule_count,)
    thigh = split.capsule_radius[leg_capsule_index(split, "thigh_left")]
    assert np.all(np.diff(thigh) < 0.0) and 0.08 <= thigh[0] <= 0.09 and 0.05 <= thigh[-1] <= 0.06


@pytest.mark.parametrize("capsules", ["coarse", "split"])
@pytest.mark.parametrize("motion", ["hula", "walk"])
def test_the_torso_ends_in_shoulders_below_the_head(capsules, motion):
    """The shoulder capsule runs from one shoulder joint (where the arms start) to the other, and
    no collision capsule reaches the head: the back's domes end at the shoulders' height."""
    body = Body(motion=motion, capsules=capsules)
    shoulders = body.capsule_names.index("shoulders")
    head = DISPLAY_CAPSULE_NAMES.index("head")
    for t in (0.0, 1.3, 2.6):
        pose = body.pose(t)
        np.testing.assert_allclose([pose.capsule_a[shoulders], pose.capsule_b[shoulders]],
                                   pose.display_capsule_a[2:4], atol=1e-12)  # the upper arms'
        tops = np.maximum(pose.capsule_a[:, 1], pose.capsule_b[:, 1]) + body.capsule_radius
        head_bottom = (min(pose.display_capsule_a[head][1], pose.display_capsule_b[head][1])
                       - body.display_capsule_radius[head])
        assert tops.max() < head_bottom
        back = [i for i, name in enumerate(body.capsule_names) if name.startswith("back")]
        assert tops[back].max() == pytest.approx(tops[shoulders], abs=0.03)
    start, end = body.layout.bones(pose.capsule_a, pose.capsule_b)  # the back bone's end,
    np.testing.assert_allclose(end[1], pose.chest_position, atol=1e-12)  # past its capsules


@pytest.mark.parametrize("t", [0.0, 3.3])
def test_split_capsules_tile_each_bone(t):
    split, coarse = Body(capsules="split"), Body(capsules="coarse")
    split_pose, coarse_pose = split.pose(t), coarse.pose(t)
    for bone_index, bone in enumerate(coarse.capsule_names):
        tiles = [i for i, name in enumerate(split.capsule_names) if name.rsplit("_", 1)[0] == bone or name == bone]
        np.testing.assert_allclose(split_pose.capsule_b[tiles[:-1]], split_pose.capsule_a[tiles[1:]], atol=1e-12)
        np.testing.assert_allclose(split_pose.capsule_a[tiles[0]], coarse_pose.capsule_a[bone_index], atol=1e-12)
        np.testing.assert_allclose(split_pose.capsule_b[tiles[-1]], coarse_pose.capsule_b[bone_index], atol=1e-12)


@pytest.mark.parametrize("capsules", ["coarse", "split"])
def test_rest_pose_clears_skirt_cone_and_waist_ring(capsules):
    body = Body(capsules=capsules)
    pose = body.pose(0.0)
    np.testing.assert_allclose(pose.pelvis_position, [0.0, body.waist_height, 0.0])
    np.testing.assert_allclose(pose.pelvis_rotation, np.eye(3))
    cone, ring = skirt_cone_points(body), waist_ring_points(body, pose)
    for a, b, radius in zip(pose.capsule_a, pose.capsule_b, body.capsule_radius):
        assert point_capsule_clearance(cone, a, b, radius).min() > 0.005
        assert point_capsule_clearance(ring, a, b, radius).min() > 0.02


def test_pelvis_and_upper_thighs_lie_below_the_waist_circle_inside_the_skirt():
    """The hips (0.36-0.38 m wide) are wider than the waist circle, so they lie below its plane
    and inside the cone: entirely below waist height, axis inside the cone."""
    body = Body(capsules="split")
    pose = body.pose(0.0)
    for name in ("pelvis", "thigh_left_0", "thigh_right_0"):
        i = body.capsule_names.index(name)
        a, b, radius = pose.capsule_a[i], pose.capsule_b[i], body.capsule_radius[i]
        assert max(a[1], b[1]) + radius < body.waist_height
        for point in (a, b):
            depth = body.waist_height - point[1]
            cone_radius = body.waist_radius + (SKIRT_HEM_RADIUS - body.waist_radius) * depth / SKIRT_LENGTH
            assert np.hypot(point[0], point[2]) < cone_radius
    hips = body.capsule_names.index("pelvis")
    assert 0.36 <= 2.0 * (pose.capsule_b[hips][0] + body.capsule_radius[hips]) <= 0.38


def test_waist_ring_stays_outside_the_body_while_dancing(dance):
    body, time, poses = dance
    for pose in poses[::50]:
        ring = waist_ring_points(body, pose)
        for a, b, radius in zip(pose.capsule_a, pose.capsule_b, body.capsule_radius):
            assert point_capsule_clearance(ring, a, b, radius).min() > 0.01


def test_rest_pose_proportions():
    body = Body()
    pose = body.pose(0.0)
    assert 0.98 <= body.waist_height <= 1.0 and body.waist_radius == pytest.approx(0.17)
    hip = pose.capsule_a[body.capsule_names.index("thigh_left_0")]
    assert 0.80 <= hip[1] <= 0.83
    scaled = Body(scale=1.1)
    assert scaled.waist_height == pytest.approx(1.1 * body.waist_height)
    np.testing.assert_allclose(scaled.pose(2.7).capsule_a, 1.1 * body.pose(2.7).capsule_a, atol=1e-12)


@pytest.mark.parametrize("capsules", ["coarse", "split"])
@pytest.mark.parametrize("t", [0.31, 0.77, 1.0, 2.345, 4.9, 7.123])
def test_velocities_match_central_differences(capsules, t):
    body, step = Body(capsules=capsules), 1e-5
    before, now, after = body.pose(t - step), body.pose(t), body.pose(t + step)
    for position, velocity in (("capsule_a", "capsule_velocity_a"), ("capsule_b", "capsule_velocity_b"),
                               ("pelvis_position", "pelvis_velocity"),
                               ("chest_position", "chest_velocity")):
        difference = (getattr(after, position) - getattr(before, position)) / (2.0 * step)
        np.testing.assert_allclose(getattr(now, velocity), difference, atol=1e-7)
    for frame in ("pelvis", "chest"):
        rotation = getattr(now, f"{frame}_rotation")
        spin = (getattr(after, f"{frame}_rotation") - getattr(before, f"{frame}_rotation")) \
            / (2.0 * step) @ rotation.T
        spin = 0.5 * (spin - spin.T)
        np.testing.assert_allclose(getattr(now, f"{frame}_angular_velocity"),
                                   [spin[2, 1], spin[0, 2], spin[1, 0]], atol=1e-7)
        np.testing.assert_allclose(rotation @ rotation.T, np.eye(3), atol=1e-12)
    shoulders = now.display_capsule_a[2:4]  # fixed in the chest frame
    local = (shoulders - now.chest_position) @ now.chest_rotation
    np.testing.assert_allclose(local, (body.pose(0.0).display_capsule_a[2:4]
                                       - body.pose(0.0).chest_position), atol=1e-12)


@pytest.mark.parametrize("motion", ["still", "hula", "sway", "twirl", "walk"])
def test_poses_at_many_times_are_each_time_posed_alone(motion):
    """``poses`` evaluates the skeleton over all its times at once (the rig's samples of a
    frame): each pose is the one ``pose`` gives at its time alone, before the dance, during the
    ease-in and in every piece of the twirl's spin, whatever the other times."""
    body = Body(motion=motion, tempo=97.0, amplitude=1.3, scale=1.1, ease_in=1.0)
    times = np.concatenate([[-0.2, 0.0, 0.5, 1.0], np.linspace(1.1, 6.3, 23)])
    together = body.poses(times[::-1])[::-1]
    for t, pose in zip(times, together):
        alone = body.pose(t)
        assert pose.time == t
        for field in dataclasses.fields(pose):
            np.testing.assert_allclose(getattr(pose, field.name), getattr(alone, field.name),
                                       rtol=1e-12, atol=1e-12, err_msg=f"{field.name} at {t}")


@pytest.mark.parametrize("t", [1.0, 1.37, 2.9, 4.44, 6.0])
def test_dance_repeats_after_loop_period(t):
    body = Body()
    now, later = body.pose(t), body.pose(t + body.loop_period)
    for field in ("capsule_a", "capsule_b", "capsule_velocity_a", "capsule_velocity_b", "display_capsule_a",
                  "pelvis_position", "pelvis_rotation", "pelvis_velocity", "pelvis_angular_velocity"):
        np.testing.assert_allclose(getattr(later, field), getattr(now, field), atol=1e-9)


def test_accelerations_are_bounded_and_continuous(dance):
    """Second differences of all capsule endpoints from t = 0 across the loop point: bounded
    acceleration, and bounded jerk (third differences), i.e. no acceleration jumps (C2)."""
    body, time, poses = dance
    endpoint = np.array([np.concatenate([pose.capsule_a, pose.capsule_b]) for pose in poses])
    acceleration = (endpoint[2:] - 2.0 * endpoint[1:-1] + endpoint[:-2]) / SAMPLE_STEP**2
    jerk = np.diff(acceleration, axis=0) / SAMPLE_STEP
    assert time[-1] > body.ease_in + body.loop_period
    assert np.linalg.norm(acceleration, axis=-1).max() < ACCELERATION_BOUND
    assert np.linalg.norm(jerk, axis=-1).max() < JERK_BOUND


def test_ease_in_starts_from_rest():
    body, rest = Body(), Body(motion="still").pose(0.0)
    start = body.pose(0.0)
    for field in ("capsule_a", "capsule_b", "display_capsule_a", "display_capsule_b",
                  "pelvis_position", "pelvis_rotation"):
        np.testing.assert_allclose(getattr(start, field), getattr(rest, field), atol=1e-15)
    for field in ("capsule_velocity_a", "capsule_velocity_b", "pelvis_velocity", "pelvis_angular_velocity"):
        assert np.abs(getattr(start, field)).max() < 1e-12
    assert np.abs(body.pose(1e-3).capsule_velocity_b).max() < 1e-3


def test_still_never_moves():
    body = Body(motion="still")
    rest = body.pose(0.0)
    for t in (0.5, 3.0, 17.25):
        pose = body.pose(t)
        np.testing.assert_array_equal(pose.capsule_a, rest.capsule_a)
        np.testing.assert_array_equal(pose.capsule_b, rest.capsule_b)
        np.testing.assert_array_equal(pose.pelvis_rotation, rest.pelvis_rotation)
        for field in ("capsule_velocity_a", "capsule_velocity_b", "pelvis_velocity", "pelvis_angular_velocity"):
            assert not np.any(getattr(pose, field))


def test_dancing_legs_stay_on_the_ground_and_rigid(dance):
    body, time, poses = dance
    ankle = [leg_capsule_index(body, "shin_left")[-1], leg_capsule_index(body, "shin_right")[-1]]
    ankle_height = np.array([pose.capsule_b[ankle, 1] for pose in poses])
    assert ANKLE_HEIGHT_BAND[0] <= ankle_height.min() and ankle_height.max() <= ANKLE_HEIGHT_BAND[1]
    length = np.array([np.linalg.norm(pose.capsule_b - pose.capsule_a, axis=1) for pose in poses])
    np.testing.assert_allclose(length, np.broadcast_to(length[0], length.shape), atol=1e-12)


def test_knees_bend_when_the_pelvis_drops(dance):
    body, time, poses = dance
    dancing = [pose for t, pose in zip(time, poses) if t >= body.ease_in]
    flexion = np.array([[knee_flexion(body, pose, side) for side in ("left", "right")] for pose in dancing])
    pelvis_height = np.array([pose.pelvis_position[1] for pose in dancing])
    assert KNEE_FLEXION_BAND[0] <= flexion.min() and flexion.max() <= KNEE_FLEXION_BAND[1]
    assert np.corrcoef(pelvis_height, flexion.mean(axis=1))[0, 1] < -0.8
    sway = np.array([pose.pelvis_position[0] for pose in dancing])
    assert 0.05 <= 0.5 * (sway.max() - sway.min()) <= 0.25


@pytest.mark.parametrize("amplitude", [0.5, 2.0])
def test_other_amplitudes_keep_knees_bent(amplitude):
    body = Body(amplitude=amplitude)
    time = np.linspace(body.ease_in, body.ease_in + body.loop_period, 200)
    flexion = np.array([[knee_flexion(body, body.pose(t), side) for side in ("left", "right")] for t in time])
    assert flexion.min() > 5.0


@pytest.mark.parametrize("arguments, message", [
    (dict(motion="salsa"), "motion='salsa'.*still, hula"),
    (dict(capsules="fine"), "capsules='fine'.*coarse, split"),
    (dict(tempo=0.0), "tempo"),
    (dict(scale=-1.0), "scale"),
    (dict(ease_in=-1.0), "ease_in"),
    (dict(amplitude=-0.1), "amplitude"),
])
def test_bad_arguments_raise(arguments, message):
    with pytest.raises(ValueError, match=message):
        Body(**arguments)


@pytest.mark.parametrize("t", [0.2, 0.5, 1.3, 2.2, 2.5, 4.0, 6.1])
def test_twirl_velocities_match_central_differences(t):
    body, step = Body(motion="twirl"), 1e-6
    before, now, after = body.pose(t - step), body.pose(t), body.pose(t + step)
    for position, velocity in (("capsule_a", "capsule_velocity_a"), ("pelvis_position", "pelvis_velocity")):
        difference = (getattr(after, position) - getattr(before, position)) / (2.0 * step)
        np.testing.assert_allclose(getattr(now, velocity), difference, atol=1e-6)
    yaw_rate = (after.pelvis_rotation - before.pelvis_rotation) / (2.0 * step) @ now.pelvis_rotation.T
    np.testing.assert_allclose(now.pelvis_angular_velocity, [0.0, yaw_rate[0, 2], 0.0], atol=1e-6)


def test_twirl_spins_on_the_spot_then_stands_and_repeats():
    """At 90 bpm one loop (8 beats, 5.33 s) turns the rest pose by two whole turns about the
    vertical through the feet: one turn a second at full speed (beats 1-3), still from beat 4 to
    8, the same pose a loop later, and every point keeps its height and distance to the axis."""
    body, rest = Body(motion="twirl"), Body(motion="still").pose(0.0)
    beat = 60.0 / body.tempo
    full_speed = body.pose(2.0 * beat)
    assert full_speed.pelvis_angular_velocity[1] == pytest.approx(2.0 * np.pi)
    for t in (4.0 * beat, 6.5 * beat, body.loop_period):
        pose = body.pose(t)
        np.testing.assert_allclose(pose.capsule_a, rest.capsule_a, atol=1e-9)
        assert np.abs(pose.capsule_velocity_b).max() < 1e-9
    quarter = body.pose(1.5 * beat)  # mid-spin: the rest pose turned about the vertical
    np.testing.assert_allclose(np.hypot(quarter.capsule_b[:, 0], quarter.capsule_b[:, 2]),
                               np.hypot(rest.capsule_b[:, 0], rest.capsule_b[:, 2]), atol=1e-12)
    np.testing.assert_allclose(quarter.capsule_b[:, 1], rest.capsule_b[:, 1], atol=1e-12)
    later = body.pose(1.5 * beat + body.loop_period)
    np.testing.assert_allclose(later.capsule_b, quarter.capsule_b, atol=1e-9)


def test_sway_rocks_the_hips_over_planted_feet_and_loops():
    """sway: the feet never move, the pelvis swings HIP_SWAY·amplitude to each side over a
    SWAY_BEATS cycle, velocities are the positions' derivatives, and it repeats every loop."""
    from taichi_cloth.body.dancer import SWAY_BEATS
    from taichi_cloth.body.hula import HIP_SWAY
    body = Body(motion="sway")
    beat = 60.0 / body.tempo
    shin = [i for i, name in enumerate(body.capsule_names) if name.startswith("shin")]
    times = body.ease_in + np.linspace(0.0, SWAY_BEATS * beat, 41)
    poses = [body.pose(t) for t in times]
    for pose in poses:
        np.testing.assert_allclose(pose.capsule_b[shin[-1]], poses[0].capsule_b[shin[-1]],
                                   atol=1e-6)  # planted (the soft reach limit: ~2e-8 m)
    sideways = np.array([pose.pelvis_position[0] for pose in poses])
    assert sideways.max() == pytest.approx(HIP_SWAY, rel=0.02)
    assert sideways.min() == pytest.approx(-HIP_SWAY, rel=0.02)
    step = 1e-6
    for t in (1.3, 2.7):
        before, now, after = body.pose(t - step), body.pose(t), body.pose(t + step)
        np.testing.assert_allclose(now.pelvis_velocity,
                                   (after.pelvis_position - before.pelvis_position) / (2 * step),
                                   atol=1e-6)
        later = body.pose(t + body.loop_period)
        np.testing.assert_allclose(later.capsule_a, now.capsule_a, atol=1e-9)


def test_walk_steps_on_the_spot_left_and_right_in_turn_and_loops():
    """walk: each ankle travels ±WALK_STRIDE/2 forward and back, the two in opposition, lifted
    up to WALK_LIFT while it swings forward and on the ground while it carries the weight back;
    the velocities are the positions' derivatives and the walk repeats every loop."""
    from taichi_cloth.body.dancer import ANKLE_HEIGHT, WALK_BEATS, WALK_LIFT, WALK_STRIDE
    body = Body(motion="walk")
    ankle = [body.capsule_names.index("shin_left_1"), body.capsule_names.index("shin_right_1")]
    stride = WALK_BEATS * 60.0 / body.tempo
    times = body.ease_in + np.linspace(0.0, stride, 65)
    ends = np.array([body.pose(t).capsule_b[ankle] for t in times])  # (T, 2, 3)
    forward, height = ends[:, :, 2], ends[:, :, 1]
    assert forward.max() == pytest.approx(WALK_STRIDE / 2, abs=2e-3)
    assert forward.min() == pytest.approx(-WALK_STRIDE / 2, abs=2e-3)
    np.testing.assert_allclose(forward[:, 0], -forward[:, 1], atol=1e-6)  # in opposition
    assert height.min() >= ANKLE_HEIGHT - 1e-6
    assert height.max() == pytest.approx(ANKLE_HEIGHT + WALK_LIFT, abs=2e-3)
    moving_back = np.gradient(forward[:, 0]) < 0
    assert np.all(height[moving_back, 0] < ANKLE_HEIGHT + 0.01)  # the stance foot stays low
    step = 1e-6
    for t in (1.3, 2.2):
        before, now, after = body.pose(t - step), body.pose(t), body.pose(t + step)
        np.testing.assert_allclose(now.capsule_velocity_b,
                                   (after.capsule_b - before.capsule_b) / (2 * step), atol=1e-6)
        np.testing.assert_allclose(body.pose(t + body.loop_period).capsule_a, now.capsule_a,
                                   atol=1e-9)
