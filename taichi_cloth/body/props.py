"""Bodies that are not dancers: a static towel bar or ball to drape cloth over, a flag's pole.
They offer the ``body.dancer.Body`` interface (capsules, waist height, ``pose(t)``) so the rig
treats them alike."""

import numpy as np

from taichi_cloth.body.dancer import BodyPose


PROPS = ("bar", "ball", "pole")  # body.capsules values that are props, not a dancer


class Bar:
    """A static capsule, for draping or holding cloth: the ``Body`` interface with one capsule,
    no display capsules and no motion. ``"bar"``: a towel bar along x (radius 4 cm, 1.2 m long,
    its centre at height ``waist_height`` = 1 m); ``"ball"``: a degenerate capsule of zero
    length (a sphere of radius 15 cm at that height); ``"pole"``: a vertical flagpole (radius
    2.5 cm) from the ground to 2.2 m. Lengths scale with ``scale``; ``offset`` [m] moves the
    prop (a pole beside the flag's edge)."""

    capsule_count = 1
    display_capsule_count = 0

    def __init__(self, shape: str = "bar", scale: float = 1.0, offset=(0.0, 0.0, 0.0)):
        radius, half_length, centre, axis = {
            "bar": (0.04, 0.6, 1.0, (1.0, 0.0, 0.0)), "ball": (0.15, 0.0, 1.0, (1.0, 0.0, 0.0)),
            "pole": (0.025, 1.1, 1.1, (0.0, 1.0, 0.0))}[shape]
        self.capsule_radius = np.array([radius * scale])
        self.display_capsule_radius = np.zeros(0)
        self.waist_height = centre * scale
        middle = np.array([0.0, self.waist_height, 0.0]) + np.asarray(offset, float)
        half = half_length * scale * np.array(axis)
        self.ends = np.array([middle - half, middle + half])

    def poses(self, times) -> list[BodyPose]:
        """The prop at each of ``times`` [s] (it never moves)."""
        return [self.pose(float(t)) for t in times]

    def pose(self, t: float) -> BodyPose:
        ends = self.ends
        still, none = np.zeros((1, 3)), np.zeros((0, 3))
        return BodyPose(time=t, capsule_a=ends[:1], capsule_b=ends[1:], capsule_velocity_a=still,
                        capsule_velocity_b=still, display_capsule_a=none, display_capsule_b=none,
                        pelvis_position=np.array([0.0, self.waist_height, 0.0]),
                        pelvis_rotation=np.eye(3), pelvis_velocity=np.zeros(3),
                        pelvis_angular_velocity=np.zeros(3),
                        chest_position=np.array([0.0, self.waist_height, 0.0]),
                        chest_rotation=np.eye(3), chest_velocity=np.zeros(3),
                        chest_angular_velocity=np.zeros(3))
