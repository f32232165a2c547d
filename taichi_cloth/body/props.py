"""Bodies that are not dancers: a static towel bar or ball to drape cloth over. They offer the
``body.dancer.Body`` interface (capsules, waist height, ``pose(t)``) so the rig treats them alike."""

import numpy as np

from taichi_cloth.body.dancer import BodyPose


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
