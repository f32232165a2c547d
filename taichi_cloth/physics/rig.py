"""The dancer wired to the cloth: a body (``body/``) posed on the host a few times per frame,
written into the prescribed motion (``physics.control.Control``) that the kernels read.

Once per frame, ``prepare_frame`` poses the body at ``SAMPLES_PER_FRAME`` + 1 evenly spaced times
covering the frame and uploads (i) the capsule endpoints with their velocities to the control's
capsule track, which the contact effect reads, and (ii) the skirt's pinned waist ring, carried by
the pelvis frame (x = R·p_local + origin, v = v_origin + ω × R·p_local), to its pin track. The
kernels interpolate both at every substep and RK4 stage (``physics.control``); nothing runs on the
host inside the substep loop.
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

SAMPLES_PER_FRAME = 8


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
        # A skirt's waist and a mesh garment's pins ride on the pelvis; other pins stay put.
        self.carries_pins = scene.cloth.pin == "waist" or (
            scene.cloth.pin in ("group", "vertices") and config.capsules not in PROPS)
        self.capsule_count = self.body.capsule_count
        self.waist_height = self.body.waist_height
        self.control = None
        self.pin_local = None
        self.pose_at_frame_end = self.body.pose(0.0)  # the body where the last frame ended

    def make_control(self, pinned: np.ndarray, rest_positions: np.ndarray, real) -> Control:
        """The prescribed motion for a cloth with these pins (N,) bool at ``rest_positions``
        (N, 3) [m], which this rig then writes every frame; the body at rest until the first
        ``prepare_frame``."""
        self.control = Control(pinned, rest_positions, real, self.body.capsule_radius,
                               self.sample_count)
        rest = self.pose_at_frame_end
        pinned_rest = rest_positions[self.control.pinned_particles]
        self.pin_local = (pinned_rest - rest.pelvis_position) @ rest.pelvis_rotation
        self.control.capsule_ends_at_frame_end = (rest.capsule_a, rest.capsule_b)
        return self.control

    def prepare_frame(self, frame: int, still: bool = False) -> None:
        """Pose the body across the frame interval ``frame`` (t from frame/fps to
        (frame+1)/fps) and upload it; ``still``: held motionless in its pose at t = 0 (the
        garment settles on it before the dance)."""
        control = self.control
        first_time = frame * self.frame_duration
        interval = self.frame_duration / SAMPLES_PER_FRAME
        if still:
            start = self.body.pose(0.0)
            zero = np.zeros_like(start.capsule_velocity_a)
            poses = [dataclasses.replace(
                start, capsule_velocity_a=zero, capsule_velocity_b=zero,
                pelvis_velocity=np.zeros(3), pelvis_angular_velocity=np.zeros(3))] \
                * self.sample_count
        else:
            poses = [self.body.pose(first_time + k * interval) for k in range(self.sample_count)]
        capsule_positions = np.stack([np.stack([p.capsule_a, p.capsule_b], axis=1).reshape(-1, 3)
                                      for p in poses])
        capsule_velocities = np.stack([
            np.stack([p.capsule_velocity_a, p.capsule_velocity_b], axis=1).reshape(-1, 3)
            for p in poses])
        control.capsule_track.upload(first_time, interval, capsule_positions, capsule_velocities)
        if self.carries_pins and len(control.pinned_particles):
            arms = np.stack([self.pin_local @ p.pelvis_rotation.T for p in poses])
            pin_positions = arms + np.stack([p.pelvis_position for p in poses])[:, None, :]
            pin_velocities = np.stack([p.pelvis_velocity + np.cross(p.pelvis_angular_velocity, arm)
                                       for p, arm in zip(poses, arms)])
            control.pin_track.upload(first_time, interval, pin_positions, pin_velocities)
        self.pose_at_frame_end = poses[-1]
        control.capsule_ends_at_frame_end = (poses[-1].capsule_a, poses[-1].capsule_b)
