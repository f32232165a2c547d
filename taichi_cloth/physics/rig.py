"""The dancer wired to the cloth: a ``body.Body`` posed on the host a few times per frame.

Once per frame, ``prepare_frame`` poses the body at ``SAMPLES_PER_FRAME`` + 1 evenly spaced times
covering the frame and uploads (i) the capsule endpoints with their velocities to the capsule
track that the contact force reads, and (ii) the skirt's pinned waist ring, carried by the pelvis
frame (x = R·p_local + origin, v = v_origin + ω × R·p_local), to the model's pin track. The kernels
interpolate both at every substep and RK4 stage (``kinematics.py``); nothing runs on the host
inside the substep loop.
"""

import numpy as np

from taichi_cloth.body.dancer import Body, BodyPose
from taichi_cloth.effects.contact import CapsuleContact, max_capsule_penetration
from taichi_cloth.physics.control import KinematicTrack
from taichi_cloth.physics.model import Model
from taichi_cloth.config.scene import Scene

SAMPLES_PER_FRAME = 8


class Bar:
    """A static horizontal capsule along x, for draping: the ``Body`` interface with one capsule,
    no display capsules and no motion. ``"bar"``: a towel bar (radius 4 cm, 1.2 m long);
    ``"ball"``: a degenerate capsule of zero length (a sphere of radius 15 cm). Lengths scale
    with ``scale``; the capsule's centre is at height ``waist_height``."""

    capsule_count = 1
    display_capsule_count = 0

    def __init__(self, shape: str = "bar", scale: float = 1.0):
        radius, self.half_length = {"bar": (0.04, 0.6), "ball": (0.15, 0.0)}[shape]
        self.capsule_radius = np.array([radius * scale])
        self.half_length *= scale
        self.display_capsule_radius = np.zeros(0)
        self.waist_height = 1.0 * scale

    def pose(self, t: float) -> BodyPose:
        ends = np.array([[-self.half_length, self.waist_height, 0.0],
                         [self.half_length, self.waist_height, 0.0]])
        still, none = np.zeros((1, 3)), np.zeros((0, 3))
        return BodyPose(time=t, capsule_a=ends[:1], capsule_b=ends[1:], capsule_velocity_a=still,
                        capsule_velocity_b=still, display_capsule_a=none, display_capsule_b=none,
                        pelvis_position=np.array([0.0, self.waist_height, 0.0]),
                        pelvis_rotation=np.eye(3), pelvis_velocity=np.zeros(3),
                        pelvis_angular_velocity=np.zeros(3))


class BodyRig:
    """A scene's body: its capsules for contact and its pelvis frame for the skirt's waist."""

    sample_count = SAMPLES_PER_FRAME + 1

    def __init__(self, scene: Scene):
        config = scene.body
        if config.capsules in ("bar", "ball"):
            self.body = Bar(config.capsules, config.scale)
        else:
            self.body = Body(config.motion, config.tempo, config.amplitude, config.capsules,
                             config.scale, config.ease_in)
        self.frame_time = 1.0 / scene.scene.fps
        self.carries_pins = scene.cloth.pin == "waist"  # other pins stay where they are
        self.capsule_count = self.body.capsule_count
        self.waist_height = self.body.waist_height
        self.model = None
        self.contact = None
        self.capsule_track = None
        self.pin_local = None
        self.pose_at_frame_end = self.body.pose(0.0)

    def attach(self, model: Model, declared_effects: dict) -> dict:
        """Connect to the model (a skirt pinned at the waist follows the pelvis) and return the
        contact effect, if the scene declares collision, as {"collision": CapsuleContact}."""
        self.model = model
        rest = self.body.pose(0.0)
        pinned = model.garment.positions[model.pinned_particles]
        self.pin_local = (pinned - rest.pelvis_position) @ rest.pelvis_rotation
        self.capsule_track = KinematicTrack(2 * self.capsule_count, self.sample_count, model.real)
        effects = {}
        if "collision" in declared_effects:
            self.contact = CapsuleContact(declared_effects["collision"], self.body.capsule_radius,
                                          self.capsule_track, model)
            effects["collision"] = self.contact
        return effects

    def prepare_frame(self, frame: int) -> None:
        """Pose the body across ``frame`` (t from frame/fps to (frame+1)/fps) and upload it."""
        first_time = frame * self.frame_time
        interval = self.frame_time / SAMPLES_PER_FRAME
        poses = [self.body.pose(first_time + k * interval) for k in range(self.sample_count)]
        capsule_positions = np.stack([np.stack([p.capsule_a, p.capsule_b], axis=1).reshape(-1, 3)
                                      for p in poses])
        capsule_velocities = np.stack([
            np.stack([p.capsule_velocity_a, p.capsule_velocity_b], axis=1).reshape(-1, 3)
            for p in poses])
        self.capsule_track.upload(first_time, interval, capsule_positions, capsule_velocities)
        if self.carries_pins and len(self.model.pinned_particles):
            arms = np.stack([self.pin_local @ p.pelvis_rotation.T for p in poses])
            pin_positions = arms + np.stack([p.pelvis_position for p in poses])[:, None, :]
            pin_velocities = np.stack([p.pelvis_velocity + np.cross(p.pelvis_angular_velocity, arm)
                                       for p, arm in zip(poses, arms)])
            self.model.pin_track.upload(first_time, interval, pin_positions, pin_velocities)
        self.pose_at_frame_end = poses[-1]

    def max_penetration(self, positions: np.ndarray) -> float:
        """Metres inside any capsule at the end of the prepared frame."""
        pose = self.pose_at_frame_end
        return max_capsule_penetration(positions, pose.capsule_a, pose.capsule_b,
                                       self.body.capsule_radius)
