"""Motion capture: a BVH clip driving the capsule body (``body.motion = "bvh"``).

The file is read with pybvh (numpy arrays, its own forward kinematics to joint positions, a
clear error for a wrong channel count or a truncated motion; bvhio was the other candidate, on
PyGLM objects per key frame). Its skeleton is mapped onto the rig's joints (``JOINT_NAMES``) by
name: the built-in maps cover the Mixamo names (``mixamorig:LeftUpLeg``, any prefix before the
colon) and the CMU names of the ASF skeleton (``lfemur``, ``ltibia``, ...); ``body.bvh.joints``
("ours=theirs") names the others. The root joint is the hips.

Then, in this order:

- units: ``body.bvh.units`` m, cm or inch, or "auto": the unit in which the leg (hip → knee →
  ankle) is 0.5–1.2 m long, an InputError when none is;
- axes: ``body.bvh.up`` y or z, or "auto" (the axis the hips → neck vector of the first frame
  runs along); the clip is turned so that up is +y, her left (left hip − right hip) +x and she
  faces +z, as the procedural dancer, centred over the origin with her lower ankle at the
  dancer's ankle height (times the body scale the leg length gives);
- time: the frames from ``start`` to ``end`` [s] are interpolated by a natural cubic spline
  (C², through every frame: ``spline.py``); a clip whose last frame repeats its first (within
  2 cm), or ``loop = "yes"``, loops; otherwise it holds its last frame. The dance eases in: clip
  time τ(t) = start + ease_in·G(t/ease_in) with G′ the quintic smoothstep, so the body starts
  still in the clip's first frame (where the garment settles) and reaches full speed at ease_in;
- capsules: the procedural dancer's bones (``capsules.BONES``: pelvis, back, thighs, shins,
  shoulders) and capsule layout between the file's joints, radii scaled by the leg length; the
  pelvis frame (the skirt's waist) is built from the hips (x: her left), the neck (y: up) and
  sits ``WAIST_ABOVE_HIPS`` above the hip joints: in the first frame its axes are her left (left
  hip − right hip) and up (hips → neck), after that it turns as the root joint does.
  Velocities are the spline's exact derivatives.

Bad files (unreadable, wrong channel counts, truncated motion, NaN, missing joints, a skeleton
whose size matches no unit) are an ``InputError`` naming the file.
"""

import warnings
from pathlib import Path

import numpy as np

from taichi_cloth.body.capsules import DISPLAY_CAPSULE_RADIUS, CapsuleLayout
from taichi_cloth.body.dancer import (ANKLE_HEIGHT, HIP_JOINT_LOCAL, PELVIS_CENTRE_LOCAL,
                                      PELVIS_HALF_WIDTH, SHIN_LENGTH, THIGH_LENGTH, BodyPose)
from taichi_cloth.body.frames import angular_velocity
from taichi_cloth.body.hula import smoothstep
from taichi_cloth.body.spline import CubicSpline
from taichi_cloth.errors import InputError

SIDES = ("left", "right")
LIMB_JOINTS = ("hip", "knee", "ankle", "toe", "shoulder", "elbow", "wrist")
JOINT_NAMES = ("hips", "neck", "head") + tuple(f"{joint}_{side}" for side in SIDES
                                                for joint in LIMB_JOINTS)
MIXAMO = {"neck": "Neck", "head": "Head",
          **{f"{joint}_{side}": f"{side.capitalize()}{name}" for side in SIDES
             for joint, name in zip(LIMB_JOINTS, ("UpLeg", "Leg", "Foot", "ToeBase", "Arm",
                                                  "ForeArm", "Hand"))}}
CMU = {"neck": "lowerneck", "head": "head",
       **{f"{joint}_{side}": f"{side[0]}{name}" for side in SIDES for joint, name in zip(
           LIMB_JOINTS, ("femur", "tibia", "foot", "toes", "humerus", "radius", "wrist"))}}
BUILT_IN_MAPS = {"mixamo": MIXAMO, "cmu": CMU}
UNIT_METRES = {"m": 1.0, "cm": 0.01, "inch": 0.0254}
ADULT_LEG = (0.5, 1.2)  # m, hip joint → knee → ankle joint: what units = "auto" accepts
LOOP_TOLERANCE = 0.02  # m: a clip whose last frame is this close to its first loops
LOOP_PADDING = 12  # frames wrapped around each end of a looping clip's spline
WAIST_ABOVE_HIPS = -HIP_JOINT_LOCAL[1]  # m at scale 1: the waist circle above the hip joints
HEAD_SEGMENT = (0.06, 0.09)  # m at scale 1: the head capsule along neck → head, past the head
CHEST_RATE_STEP = 1e-4  # s: the central difference of the chest frame's turning


def plain_name(name: str) -> str:
    """A joint name without its namespace prefix (``mixamorig:``), lower case."""
    return name.rsplit(":", 1)[-1].lower()


def joint_map(names: list[str], custom: tuple, path: str) -> list[int]:
    """The index in ``names`` (the file's joints, root first) of each of ``JOINT_NAMES``: the
    built-in map that finds them all, with ``custom`` ("ours=theirs") pairs taking precedence;
    InputError naming the joints no map finds."""
    where = {plain_name(name): index for index, name in enumerate(names)}
    chosen = {}
    for pair in custom:
        ours, _, theirs = pair.partition("=")
        if ours.strip() not in JOINT_NAMES or plain_name(theirs.strip()) not in where:
            raise InputError(f"{path}: body.bvh.joints: {pair!r} must be ours=theirs with ours "
                             f"one of {', '.join(JOINT_NAMES)} and theirs a joint of the file")
        chosen[ours.strip()] = where[plain_name(theirs.strip())]
    best = None
    for convention in BUILT_IN_MAPS.values():
        found = {"hips": 0, **{ours: where[theirs.lower()] for ours, theirs in convention.items()
                               if theirs.lower() in where}, **chosen}
        missing = [joint for joint in JOINT_NAMES if joint not in found]
        if best is None or len(missing) < len(best[1]):
            best = (found, missing)
    found, missing = best
    if missing:
        raise InputError(f"{path}: no joint for {', '.join(missing)} (neither Mixamo nor CMU "
                         f"names); name them with body.bvh.joints = [\"ours=theirs\", ...]")
    return [found[joint] for joint in JOINT_NAMES]


def read_clip(path: Path, custom: tuple) -> tuple[np.ndarray, np.ndarray, float]:
    """(joint positions (F, len(JOINT_NAMES), 3) in the file's units and axes, the root's
    global rotation (F, 3, 3), frame time [s]) of the BVH file at ``path``."""
    import pybvh
    from pybvh.rotations import euler_to_rotmat
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # pybvh's notes on facing and lr guesses
            clip = pybvh.read_bvh_file(path)
            positions = clip.joint_positions()
            root = euler_to_rotmat(clip.joint_angles[:, 0], "".join(clip.root.rot_channels))
    except (OSError, ValueError, IndexError, KeyError, TypeError) as error:
        raise InputError(f"{path}: not a readable BVH file "
                         f"({' '.join(str(error).split())})") from None
    names = [node.name for node in clip.nodes if not node.is_end_site()]
    if len(positions) < 2 or not clip.frame_time > 0:
        raise InputError(f"{path}: a BVH clip needs at least 2 frames and a frame time > 0")
    if not (np.isfinite(positions).all() and np.isfinite(root).all()):
        raise InputError(f"{path}: the motion holds values that are not finite numbers")
    return positions[:, joint_map(names, custom, str(path))], root, float(clip.frame_time)


def index(joint: str) -> int:
    return JOINT_NAMES.index(joint)


def leg_length(joints: np.ndarray) -> float:
    """Hip → knee → ankle of the left leg in one frame (J, 3)."""
    hip, knee, ankle = (joints[index(f"{j}_left")] for j in ("hip", "knee", "ankle"))
    return float(np.linalg.norm(knee - hip) + np.linalg.norm(ankle - knee))


def unit_of(joints: np.ndarray, units: str, path: str) -> float:
    """Metres per file unit: ``units``, or "auto": the one unit in which the leg (hip → knee →
    ankle) is as long as an adult's, ``ADULT_LEG`` (the ranges of m, inch and cm do not
    overlap); a leg that fits none (a child, a scaled export such as the CMU cgspeed files) is
    an InputError asking for ``body.bvh.units``."""
    if units != "auto":
        return UNIT_METRES[units]
    leg = leg_length(joints)
    for unit, metres in UNIT_METRES.items():
        if ADULT_LEG[0] <= leg * metres <= ADULT_LEG[1]:
            return metres
    readings = ", ".join(f"{leg * metres:.3g} m in {unit}" for unit, metres in UNIT_METRES.items())
    raise InputError(f"{path}: the leg is {leg:g} units long ({readings}): no unit gives an "
                     f"adult's {ADULT_LEG[0]:g}–{ADULT_LEG[1]:g} m; set body.bvh.units (the "
                     f"dancer is sized from the leg, so any unit gives a whole body)")


def up_of(joints: np.ndarray, up: str) -> np.ndarray:
    """The file's unit up vector: ``up`` y or z, or "auto" along hips → neck."""
    if up != "auto":
        return np.eye(3)[{"y": 1, "z": 2}[up]]
    spine = joints[index("neck")] - joints[index("hips")]
    axis = int(np.argmax(np.abs(spine)))
    return np.eye(3)[axis] * np.sign(spine[axis])


def ease_time(t: float, ease_in: float) -> tuple[float, float]:
    """(clip seconds played by time t, their rate dτ/dt): the rate is the quintic smoothstep of
    t/ease_in, so τ = ease_in·(u⁶ − 3u⁵ + 5u⁴/2) up to u = 1, then grows as t."""
    if ease_in <= 0.0:
        return t, 1.0
    u = t / ease_in
    if u >= 1.0:
        return ease_in * (0.5 + u - 1.0), 1.0
    u = max(u, 0.0)
    return ease_in * (u ** 6 - 3 * u ** 5 + 2.5 * u ** 4), smoothstep(u)


class MocapBody:
    """The capsule body following a BVH clip: the ``dancer.Body`` interface (capsules, pelvis
    frame, ``pose(t)``) for the rig. Settings as ``config.tables.BvhConfig``; ``capsules``,
    ``scale``, ``ease_in`` as for the procedural dancer."""

    display_capsule_count = 8

    def __init__(self, path: Path, settings, capsules: str = "split", scale: float = 1.0,
                 ease_in: float = 1.0):
        joints, root, frame_time = read_clip(path, settings.joints)
        metres = unit_of(joints[0], settings.units, str(path))
        up = up_of(joints[0], settings.up)
        left = joints[0, index("hip_left")] - joints[0, index("hip_right")]
        left = left - (left @ up) * up
        if np.linalg.norm(left) == 0.0:
            raise InputError(f"{path}: the hips are on top of each other in the first frame")
        left /= np.linalg.norm(left)
        turn = np.stack([left, up, np.cross(left, up)])  # rows: her left, up, forward
        joints = joints * metres @ turn.T
        self.body_scale = leg_length(joints[0]) / (THIGH_LENGTH + SHIN_LENGTH) * scale
        joints *= scale
        first, last = self._frames(settings, frame_time, len(joints), str(path))
        joints, root = joints[first:last + 1], turn @ root[first:last + 1] @ turn.T
        # the pelvis frame: the first frame's from the joints, then turning with the root joint
        rotations = root @ root[0].T @ pelvis_rotations(joints[:1])[0]
        ankles = joints[0, [index("ankle_left"), index("ankle_right")], 1]
        joints += [-joints[0, 0, 0], ANKLE_HEIGHT * self.body_scale - ankles.min(),
                   -joints[0, 0, 2]]
        closes = np.abs(joints[-1] - joints[0]).max() < LOOP_TOLERANCE * self.body_scale
        self.loops = settings.loop == "yes" or (settings.loop == "auto" and closes)
        if self.loops and closes and len(joints) > 2:
            joints, rotations = joints[:-1], rotations[:-1]  # the last frame is the first
        self.frame_time = frame_time
        self.period = len(joints) * frame_time if self.loops else (len(joints) - 1) * frame_time
        self.padding = min(LOOP_PADDING, len(joints)) if self.loops else 0
        wrapped = self._wrapped(joints)
        self.joint_spline = CubicSpline(wrapped.reshape(len(wrapped), -1), frame_time)
        self.rotation_spline = CubicSpline(self._wrapped(rotations).reshape(-1, 9), frame_time)
        self.ease_in = ease_in
        self.layout = CapsuleLayout(capsules, self.body_scale)
        self.capsule_names = self.layout.names
        self.capsule_count = len(self.capsule_names)
        self.capsule_radius = self.layout.radius
        self.display_capsule_radius = self.body_scale * np.array(DISPLAY_CAPSULE_RADIUS)
        self.waist_height = float(self.pose(0.0).pelvis_position[1])

    def _wrapped(self, samples: np.ndarray) -> np.ndarray:
        """A looping clip's samples with ``padding`` frames wrapped around each end (and the
        first again after the last), so that its spline runs smoothly through the loop."""
        if not self.loops:
            return samples
        return np.concatenate([samples[-self.padding:], samples, samples[:self.padding + 1]])

    @staticmethod
    def _frames(settings, frame_time: float, count: int, path: str) -> tuple[int, int]:
        """The first and last frame of body.bvh.start … end (end 0: the clip's last)."""
        first = round(settings.start / frame_time)
        last = count - 1 if settings.end == 0.0 else round(settings.end / frame_time)
        if not 0 <= first < last < count:
            raise InputError(f"{path}: body.bvh.start {settings.start:g} s and end "
                             f"{settings.end:g} s leave no motion in a clip of "
                             f"{(count - 1) * frame_time:g} s")
        return first, last

    def _sample(self, t: float):
        """(joints (J, 3), their velocities, pelvis rotation, its derivative) at time t."""
        tau, rate = ease_time(t, self.ease_in)
        tau = (tau % self.period if self.loops else min(tau, self.period)) \
            + self.padding * self.frame_time
        moving = self.loops or tau < self.period
        joints, joint_rate = self.joint_spline(tau)
        elements, element_rate = self.rotation_spline(tau)
        u, _, vt = np.linalg.svd(elements.reshape(3, 3))
        rotation = u @ vt  # the nearest rotation to the interpolated matrix
        scale = rate if moving else 0.0
        return (joints.reshape(-1, 3), scale * joint_rate.reshape(-1, 3), rotation,
                scale * element_rate.reshape(3, 3))

    def _bones(self, joints, rotation):
        """(bone start, bone end), each (len(BONES), 3), linear in the joints and the pelvis
        rotation (so the same map of their rates gives the bones' velocities)."""
        hip = joints[[index("hip_left"), index("hip_right")]]
        waist = hip.mean(axis=0) + rotation @ np.array([0.0, WAIST_ABOVE_HIPS, 0.0]) \
            * self.body_scale
        centre = np.array(PELVIS_CENTRE_LOCAL) * self.body_scale
        half = np.array([PELVIS_HALF_WIDTH * self.body_scale, 0.0, 0.0])
        pelvis = waist + np.array([centre - half, centre + half]) @ rotation.T
        knee = joints[[index("knee_left"), index("knee_right")]]
        ankle = joints[[index("ankle_left"), index("ankle_right")]]
        shoulder = joints[[index("shoulder_left"), index("shoulder_right")]]
        start = np.stack([pelvis[0], waist, hip[0], hip[1], knee[0], knee[1], shoulder[0]])
        end = np.stack([pelvis[1], joints[index("neck")], knee[0], knee[1], ankle[0], ankle[1],
                        shoulder[1]])
        return start, end, waist

    def poses(self, times) -> list[BodyPose]:
        """The body at each of ``times`` [s] (``pose`` at each)."""
        return [self.pose(float(t)) for t in times]

    def pose(self, t: float) -> BodyPose:
        """The body at time ``t`` [s], velocities from the spline's derivatives."""
        joints, joint_rate, rotation, rotation_rate = self._sample(t)
        start, end, waist = self._bones(joints, rotation)
        start_rate, end_rate, waist_rate = self._bones(joint_rate, rotation_rate)
        capsule_a, capsule_b = self.layout.tile(start, end)
        velocity_a, velocity_b = self.layout.tile(start_rate, end_rate)
        display_a, display_b = self._display(joints)
        chest_rotation = chest_frame(joints)
        chest_rate = (chest_frame(joints + CHEST_RATE_STEP * joint_rate)
                      - chest_frame(joints - CHEST_RATE_STEP * joint_rate)) / (2 * CHEST_RATE_STEP)
        return BodyPose(time=float(t), capsule_a=capsule_a, capsule_b=capsule_b,
                        capsule_velocity_a=velocity_a, capsule_velocity_b=velocity_b,
                        display_capsule_a=display_a, display_capsule_b=display_b,
                        pelvis_position=waist, pelvis_rotation=rotation,
                        pelvis_velocity=waist_rate,
                        pelvis_angular_velocity=angular_velocity(rotation, rotation_rate),
                        chest_position=joints[index("neck")],
                        chest_rotation=chest_rotation,
                        chest_velocity=joint_rate[index("neck")],
                        chest_angular_velocity=angular_velocity(chest_rotation, chest_rate))

    def _display(self, joints):
        """Neck, head, upper arms, forearms and feet (``dancer.DISPLAY_CAPSULE_NAMES``)."""
        neck, head = joints[index("neck")], joints[index("head")]
        along = (head - neck) / max(np.linalg.norm(head - neck), 1e-9) * self.body_scale
        a = [neck, head + HEAD_SEGMENT[0] * along]
        b = [head, head + HEAD_SEGMENT[1] * along]
        for first, second in (("shoulder", "elbow"), ("elbow", "wrist")):
            a += [joints[index(f"{first}_{side}")] for side in SIDES]
            b += [joints[index(f"{second}_{side}")] for side in SIDES]
        a += [joints[index(f"ankle_{side}")] for side in SIDES]
        b += [joints[index(f"toe_{side}")] for side in SIDES]
        return np.array(a), np.array(b)


def chest_frame(joints: np.ndarray) -> np.ndarray:
    """The chest frame's rotation (3, 3) of one frame's joints (J, 3), columns her left, up and
    forward: y along the spine (hips' midpoint → neck), x along the shoulders (left − right)
    made orthogonal to y. Its rate is the central difference along the joints' velocities
    (``CHEST_RATE_STEP`` s each way: exact for the frame's linear parts, O(h²) for the
    normalising)."""
    spine = joints[index("neck")] - joints[[index("hip_left"), index("hip_right")]].mean(0)
    y = spine / np.linalg.norm(spine)
    x = joints[index("shoulder_left")] - joints[index("shoulder_right")]
    x = x - (x @ y) * y
    x /= np.linalg.norm(x)
    return np.stack([x, y, np.cross(x, y)], axis=1)


def pelvis_rotations(joints: np.ndarray) -> np.ndarray:
    """The pelvis frame (F, 3, 3) of each frame's joints (F, J, 3), columns her left, up and
    forward: x along left hip − right hip, y along hips → neck made orthogonal to x."""
    x = joints[:, index("hip_left")] - joints[:, index("hip_right")]
    x /= np.linalg.norm(x, axis=1, keepdims=True)
    spine = joints[:, index("neck")] - joints[:, [index("hip_left"), index("hip_right")]].mean(1)
    y = spine - np.einsum("fk,fk->f", spine, x)[:, None] * x
    y /= np.linalg.norm(y, axis=1, keepdims=True)
    return np.stack([x, y, np.cross(x, y)], axis=2)
