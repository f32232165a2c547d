"""The body's capsules (seed §2.6.1, Figs. 3–4): the bones they lie on, the two collision
layouts (``"coarse"``: one capsule per bone; ``"split"``: the back in 2, each thigh in 3 and each
shin in 2, radii tapering) and the display capsules that are drawn but not collided. The
procedural dancer (``dancer.py``) and a motion capture clip (``mocap.py``) pose the same bones.

Beyond the paper's bones (pelvis, back, legs: all a skirt meets) the body has shoulders, a bone
from the left shoulder joint to the right one, so that a garment hanging from them (a dress's
straps) has something to lie on; the back's capsules end ``BONE_EXTENT["back"]`` of the way
from the waist to the neck base, their domes meeting the shoulders instead of rising beside the
head."""

from types import MappingProxyType

import numpy as np

CAPSULE_LAYOUT_NAMES = ("coarse", "split")

# --- collision capsules: per bone kind, the tiles (name suffix, radius in m) --
CAPSULE_TILES = MappingProxyType({
    "coarse": MappingProxyType({
        "pelvis": (("", 0.115),),
        "back": (("", 0.115),),
        "thigh": (("", 0.072),),
        "shin": (("", 0.045),),
        "shoulders": (("", 0.04),),
    }),
    "split": MappingProxyType({
        "pelvis": (("", 0.115),),
        "back": (("lower", 0.11), ("upper", 0.12)),
        "thigh": (("0", 0.085), ("1", 0.07), ("2", 0.057)),
        "shin": (("0", 0.05), ("1", 0.037)),
        "shoulders": (("", 0.04),),
    }),
})
# bones in capsule order: (bone name, bone kind); the bone index is the position here
BONES = (
    ("pelvis", "pelvis"),
    ("back", "back"),
    ("thigh_left", "thigh"),
    ("thigh_right", "thigh"),
    ("shin_left", "shin"),
    ("shin_right", "shin"),
    ("shoulders", "shoulders"),  # left shoulder joint -> right shoulder joint
)
# the part of a bone its capsules cover, from its start: the back's (waist -> neck base, 0.34 m
# at scale 1) end 8.5 cm below the neck base, so the upper capsule's dome (r = 12 cm) tops out
# by the shoulder capsule (1.365 m against 1.34 m) and below the head (1.38 m), not at 1.45 m
BONE_EXTENT = MappingProxyType({"back": 0.75})

# --- display capsules (rendering only, not collided), in this order -----------
DISPLAY_CAPSULE_NAMES = (
    "neck", "head", "upper_arm_left", "upper_arm_right",
    "forearm_left", "forearm_right", "foot_left", "foot_right",
)
DISPLAY_CAPSULE_RADIUS = (0.05, 0.09, 0.04, 0.04, 0.032, 0.032, 0.03, 0.03)

class CapsuleLayout:
    """The collision capsules of a layout (``"coarse"`` or ``"split"``) on the bones ``BONES``:
    each bone tiled by its kind's capsules, their radii [m] times ``scale``."""

    def __init__(self, capsules: str, scale: float):
        names, bone, fraction, radius = [], [], [], []
        for bone_index, (bone_name, bone_kind) in enumerate(BONES):
            tiles = CAPSULE_TILES[capsules][bone_kind]
            for tile_index, (suffix, tile_radius) in enumerate(tiles):
                names.append(f"{bone_name}_{suffix}" if suffix else bone_name)
                bone.append(bone_index)
                extent = BONE_EXTENT.get(bone_kind, 1.0)
                fraction.append((extent * tile_index / len(tiles),
                                 extent * (tile_index + 1) / len(tiles)))
                radius.append(tile_radius)
        self.names = tuple(names)
        self.radius = scale * np.array(radius)
        self.bone = np.array(bone)  # (C,) index into BONES
        self.fraction = np.array(fraction)  # (C, 2) tile ends along the bone, 0..1

    def bones(self, capsule_a, capsule_b):
        """(bone start, bone end), each (len(BONES), 3): the first tile's start and the last
        tile's end of each bone, that end taken on to the bone's length where the tiles cover
        only part of it (the inverse of ``tile``)."""
        first = np.searchsorted(self.bone, np.arange(len(BONES)), side="left")
        last = np.searchsorted(self.bone, np.arange(len(BONES)), side="right") - 1
        start, covered_end = np.asarray(capsule_a)[first], np.asarray(capsule_b)[last]
        return start, start + (covered_end - start) / self.fraction[last, 1:]

    def tile(self, bone_start, bone_end):
        """(capsule_a, capsule_b), each (..., C, 3), of bones from ``bone_start`` to ``bone_end``
        (each (..., len(BONES), 3), in ``BONES`` order; complex values pass through)."""
        vector = (bone_end - bone_start)[..., self.bone, :]
        start = bone_start[..., self.bone, :]
        return start + self.fraction[:, :1] * vector, start + self.fraction[:, 1:] * vector
