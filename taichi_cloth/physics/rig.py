"""The dancer wired to the cloth: a body (``body/``) posed on the host a few times per frame,
written into the prescribed motion (``physics.control.Control``) that the kernels read.

Once per frame, ``prepare_frame`` poses the body at ``SAMPLES_PER_FRAME`` + 1 evenly spaced times
covering the frame (``Body.poses``: the dancer's skeleton evaluated once, over all of them) and
uploads (i) the capsule endpoints with their velocities to the control's capsule track, which the
contact effect reads, and (ii) the garment's pins (a skirt's waist ring, a mesh garment's pins, a
dress's straps), each carried by the pelvis frame or, above the middle of the back in the rest
pose, the chest frame (x = R·p_local + origin, v = v_origin + ω × R·p_local), to its pin track.
The kernels interpolate both at every substep and RK4 stage (``physics.control``); nothing runs on
the host inside the substep loop.
"""

import dataclasses
from pathlib import Path

import numpy as np

from taichi_cloth.body.dancer import Body
from taichi_cloth.body.mocap import MocapBody
from taichi_cloth.body.props import PROPS, Bar
from taichi_cloth.config.scene import Scene
from taichi_cloth.errors import InputError
from taichi_cloth.physics.control import Control
from taichi_cloth.uploads import upload

SAMPLES_PER_FRAME = 8
PEAK_SAMPLE_RATE = 60.0  # 1/s: poses a second sampled for the pins' peak acceleration
PEAK_WINDOW = 10.0  # s: the longest stretch of the dance sampled for it (a dance loops)


def bvh_path(scene: Scene) -> Path:
    """body.bvh.file, relative to the scene file; InputError when it is not a file."""
    name = scene.body.bvh.file
    if not name:
        raise InputError(f"{scene.path}: body.bvh: motion = \"bvh\" needs a clip, e.g. "
                         f"body.bvh = \"dance.bvh\"")
    path = Path(name) if Path(name).is_absolute() else Path(scene.path).parent / name
    if not path.is_file():
        raise InputError(f"{scene.path}: body.bvh: {path} is not a file")
    return path


class BodyRig:
    """A scene's body: its capsules for contact and its pelvis frame for the skirt's waist."""

    sample_count = SAMPLES_PER_FRAME + 1

    def __init__(self, scene: Scene):
        config = scene.body
        if config.capsules in PROPS:
            self.body = Bar(config.capsules, config.scale, config.offset)
        elif config.motion == "bvh":
            self.body = MocapBody(bvh_path(scene), config.bvh, config.capsules, config.scale,
                                  config.ease_in)
        else:
            self.body = Body(config.motion, config.tempo, config.amplitude, config.capsules,
                             config.scale, config.ease_in)
        self.frame_duration = 1.0 / scene.scene.fps  # [s]
        # A skirt's waist, a mesh garment's pins and a dress's straps ride on the body.
        self.carries_pins = scene.cloth.pin == "waist" or (
            scene.cloth.pin in ("group", "vertices", "shoulders") and config.capsules not in PROPS)
        self.capsule_count = self.body.capsule_count
        self.waist_height = self.body.waist_height
        self.control = None
        self.pin_local = None  # each pin in its carrying frame, m
        self.pin_on_chest = None  # whether the chest (not the pelvis) carries it
        self.rest_pose = self.body.pose(0.0)  # where the garment settles, held still
        self.pose_at_frame_end = self.rest_pose  # the body where the last frame ended

    def make_control(self, pinned: np.ndarray, rest_positions: np.ndarray, real) -> Control:
        """The prescribed motion for a cloth with these pins (N,) bool at ``rest_positions``
        (N, 3) [m], which this rig then writes every frame; the body at rest until the first
        ``prepare_frame``."""
        self.control = Control(pinned, rest_positions, real, self.body.capsule_radius,
                               self.sample_count)
        rest = self.pose_at_frame_end
        pinned_rest = rest_positions[self.control.pinned_particles]
        self.pin_on_chest = pinned_rest[:, 1] > 0.5 * (rest.pelvis_position[1]
                                                       + rest.chest_position[1])
        origin, rotation, _, _ = (frame[0] for frame in self.pin_frames([rest]))
        self.pin_local = np.einsum("pk,pkj->pj", pinned_rest - origin, rotation)
        self.control.capsule_ends_at_frame_end = (rest.capsule_a, rest.capsule_b)
        return self.control

    def pin_frames(self, poses):
        """Each pin's carrying frame in each of ``poses`` (T of them): origins (T, P, 3) [m],
        rotations (T, P, 3, 3), velocities (T, P, 3) [m/s], angular velocities (T, P, 3)
        [rad/s]."""
        def per_pin(quantity: str) -> np.ndarray:
            """Each pose's chest_… or pelvis_… ``quantity`` (T, ...) for each pin: (T, P, ...)."""
            chest, pelvis = (np.stack([getattr(pose, f"{frame}_{quantity}") for pose in poses])
                             for frame in ("chest", "pelvis"))
            on_chest = self.pin_on_chest.reshape((-1,) + (1,) * (chest.ndim - 1))  # (P, 1, ...)
            return np.where(on_chest, chest[:, None], pelvis[:, None])

        return tuple(per_pin(quantity)
                     for quantity in ("position", "rotation", "velocity", "angular_velocity"))

    def carried_pins(self, poses) -> tuple[np.ndarray, np.ndarray]:
        """The pins' positions (T, P, 3) [m] and velocities (T, P, 3) [m/s] in each of the T
        ``poses``."""
        origin, rotation, velocity, angular_velocity = self.pin_frames(poses)
        arm = np.einsum("tpjk,pk->tpj", rotation, self.pin_local)
        return origin + arm, velocity + np.cross(angular_velocity, arm)

    def peak_pin_acceleration(self, duration: float) -> float:
        """The largest acceleration [m/s²] of the carried pins over the first ``duration`` s
        (at most ``PEAK_WINDOW``) of the motion: the differences of their velocities sampled
        ``PEAK_SAMPLE_RATE`` times a second over the interval; 0 when the body carries no pins."""
        if not self.carries_pins or self.pin_local is None or not len(self.pin_local):
            return 0.0
        times = np.arange(0.0, min(duration, PEAK_WINDOW) + 1e-9, 1.0 / PEAK_SAMPLE_RATE)
        if len(times) < 2:
            return 0.0
        velocities = self.carried_pins(self.body.poses(times))[1]
        return float(np.linalg.norm(np.diff(velocities, axis=0), axis=2).max()
                     * PEAK_SAMPLE_RATE)

    def prepare_frame(self, frame: int, still: bool = False) -> None:
        """Pose the body across the frame interval ``frame`` (t from frame/fps to
        (frame+1)/fps) and upload it; ``still``: held motionless in its pose at t = 0 (the
        garment settles on it before the dance)."""
        control = self.control
        first_time = frame * self.frame_duration
        interval = self.frame_duration / SAMPLES_PER_FRAME
        if still:
            start = self.rest_pose
            zero = np.zeros_like(start.capsule_velocity_a)
            poses = [dataclasses.replace(
                start, capsule_velocity_a=zero, capsule_velocity_b=zero,
                pelvis_velocity=np.zeros(3), pelvis_angular_velocity=np.zeros(3),
                chest_velocity=np.zeros(3), chest_angular_velocity=np.zeros(3))] \
                * self.sample_count
        else:
            poses = self.body.poses(first_time + np.arange(self.sample_count) * interval)
        capsule_positions = np.stack([np.stack([p.capsule_a, p.capsule_b], axis=1).reshape(-1, 3)
                                      for p in poses])
        capsule_velocities = np.stack([
            np.stack([p.capsule_velocity_a, p.capsule_velocity_b], axis=1).reshape(-1, 3)
            for p in poses])
        tracks = control.capsule_track.pairs(first_time, interval, capsule_positions,
                                             capsule_velocities)
        if self.carries_pins and len(control.pinned_particles):
            pin_positions, pin_velocities = self.carried_pins(poses)
            tracks += control.pin_track.pairs(first_time, interval, pin_positions,
                                              pin_velocities)
        upload(tracks)  # one launch (one kernel to compile) for both tracks
        self.pose_at_frame_end = poses[-1]
        control.capsule_ends_at_frame_end = (poses[-1].capsule_a, poses[-1].capsule_b)
