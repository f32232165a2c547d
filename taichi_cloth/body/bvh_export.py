"""The procedural dances written as BVH clips (``tools/export_dances.py`` makes the shipped
``scenes/motions/*.bvh``), so that the path procedural → BVH → capsules can be checked end to end
and other tools (Blender, motion libraries) can play the same dance.

The skeleton uses Mixamo's joint names (``mocap.MIXAMO``), centimetres, y up, facing +z (other
names, units and a z-up file can be asked for: the tests write CMU-named ones); its rest
pose is the dance's first frame, where every joint's global rotation is the identity and each
OFFSET is the bone vector of that frame. A frame's global rotation of each joint G_j takes its
rest bone vector(s) to the current one(s): the hips' is the pelvis frame's rotation since t = 0;
a joint with one child takes the shortest rotation between the two vectors (the bone's roll does
not move any joint); the neck, whose children (head, shoulders) are fixed in the chest, takes the
best rotation of its three (Kabsch 1976). Each channel holds the local rotation
L_j = G_parent⁻¹ G_j as Z, X, Y Euler angles; forward kinematics (any BVH reader) then puts every
joint back where the dance had it. pybvh writes the file.
"""

from pathlib import Path

import numpy as np

from taichi_cloth.body.dancer import Body
from taichi_cloth.body.mocap import MIXAMO

CHANNELS = ["Z", "X", "Y"]
# the file's axes from ours (y up, +z her front): "y" keeps them, "z" puts up on +z and her
# front on −y (Blender's convention), both right-handed
AXES = {"y": np.eye(3), "z": np.array([[1.0, 0.0, 0.0], [0.0, 0.0, -1.0], [0.0, 1.0, 0.0]])}
# (joint, parent): the hierarchy in file order; "spine" sits at the waist and carries the neck
HIERARCHY = (("hips", None), ("hip_left", "hips"), ("knee_left", "hip_left"),
             ("ankle_left", "knee_left"), ("toe_left", "ankle_left"), ("hip_right", "hips"),
             ("knee_right", "hip_right"), ("ankle_right", "knee_right"),
             ("toe_right", "ankle_right"), ("spine", "hips"), ("neck", "spine"),
             ("head", "neck"), ("shoulder_left", "neck"), ("elbow_left", "shoulder_left"),
             ("wrist_left", "elbow_left"), ("shoulder_right", "neck"),
             ("elbow_right", "shoulder_right"), ("wrist_right", "elbow_right"))
MIXAMO_NAMES = {"hips": "Hips", "spine": "Spine", **MIXAMO}
END_SITE = 0.05  # m: the end sites' bone length (head top, toes, hands)
OPPOSITE_COSINE = -1.0 + 1e-14  # below it, a and b count as opposite (shortest_rotation)


def dance_joints(body: Body, pose) -> dict:
    """Every ``JOINT_NAMES`` joint (and the spine's base) of the procedural ``body`` in ``pose``
    (a ``BodyPose`` of it) [m], and its pelvis rotation: the hips are between the hip joints,
    the head is the top of the neck."""
    start, end = body.layout.bones(pose.capsule_a, pose.capsule_b)
    display_a, display_b = pose.display_capsule_a, pose.display_capsule_b
    joints = {"hips": 0.5 * (start[2] + start[3]), "neck": end[1], "head": display_b[0]}
    for k, side in enumerate(("left", "right")):
        joints.update({f"hip_{side}": start[2 + k], f"knee_{side}": end[2 + k],
                       f"ankle_{side}": end[4 + k], f"toe_{side}": display_b[6 + k],
                       f"shoulder_{side}": display_a[2 + k], f"elbow_{side}": display_b[2 + k],
                       f"wrist_{side}": display_b[4 + k]})
    joints["spine"] = pose.pelvis_position  # the waist: fixed in the pelvis, a back's length
    return joints, pose.pelvis_rotation      # below the neck


def shortest_rotation(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """The rotation by the smallest angle taking the direction of a to that of b (Rodrigues);
    for opposite directions (1 + cos θ → 0, where Rodrigues divides by it) the half turn
    2 n nᵀ − I about an axis n perpendicular to a."""
    a, b = a / np.linalg.norm(a), b / np.linalg.norm(b)
    axis, cosine = np.cross(a, b), float(a @ b)
    if cosine < OPPOSITE_COSINE:
        n = np.cross(a, np.eye(3)[np.argmin(np.abs(a))])
        n /= np.linalg.norm(n)
        return 2.0 * np.outer(n, n) - np.eye(3)
    cross = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    return np.eye(3) + cross + cross @ cross / (1.0 + cosine)


def best_rotation(rest: np.ndarray, now: np.ndarray) -> np.ndarray:
    """The rotation R minimising Σ |R rest_k − now_k|² (Kabsch), rest and now (K, 3)."""
    u, _, vt = np.linalg.svd(now.T @ rest)
    d = np.sign(np.linalg.det(u @ vt))
    return u @ np.diag([1.0, 1.0, d]) @ vt


def children_of(joint: str) -> list[str]:
    return [child for child, parent in HIERARCHY if parent == joint]


def global_rotations(joints: dict, rest: dict, pelvis, rest_pelvis) -> dict:
    """G_j of every joint in one frame (module docstring)."""
    rotations = {"hips": pelvis @ rest_pelvis.T}
    for joint, parent in HIERARCHY[1:]:
        children = children_of(joint)
        if not children:
            rotations[joint] = rotations[parent]
        elif len(children) == 1:
            child = children[0]
            rotations[joint] = shortest_rotation(rest[child] - rest[joint],
                                                 joints[child] - joints[joint])
        else:
            rotations[joint] = best_rotation(
                np.array([rest[c] - rest[joint] for c in children]),
                np.array([joints[c] - joints[joint] for c in children]))
    return rotations


def write_dance_bvh(body: Body, target: Path, seconds: float, fps: float,
                    names: dict = MIXAMO_NAMES, up: str = "y", unit: float = 0.01) -> None:
    """``body``'s dance from t = 0 to ``seconds`` at ``fps`` frames a second as a BVH file:
    joints named by ``names`` (ours → the file's; default Mixamo's), ``up`` the file's up axis
    ("y" or "z", ``AXES``), lengths in ``unit`` metres (default centimetres)."""
    import pybvh
    from pybvh.bvhnode import BvhEndSite, BvhJoint, BvhRoot
    from pybvh.rotations import rotmat_to_euler
    times = np.arange(round(seconds * fps) + 1) / fps
    axes = AXES[up]
    frames = []
    for pose in body.poses(times):  # into the file's axes and unit
        joints, pelvis = dance_joints(body, pose)
        frames.append(({joint: axes @ point / unit for joint, point in joints.items()},
                       axes @ pelvis @ axes.T))
    rest, rest_pelvis = frames[0]
    nodes, made = [], {}
    for joint, parent in HIERARCHY:
        offset = rest[joint] - rest[parent] if parent else np.zeros(3)
        node = BvhRoot(names[joint], offset, ["X", "Y", "Z"], CHANNELS) if parent is None \
            else BvhJoint(names[joint], offset, CHANNELS, parent=made[parent])
        made[joint] = node
        nodes.append(node)
        if parent is not None:
            made[parent].children.append(node)
        if not children_of(joint):
            tip = BvhEndSite(f"{names[joint]}_end", axes @ [0.0, END_SITE / unit, 0.0],
                             parent=node)
            node.children.append(tip)
            nodes.append(tip)
    angles = np.empty((len(times), len(HIERARCHY), 3))
    for f, (joints, pelvis) in enumerate(frames):
        rotations = global_rotations(joints, rest, pelvis, rest_pelvis)
        for j, (joint, parent) in enumerate(HIERARCHY):
            local = rotations[joint] if parent is None else rotations[parent].T @ rotations[joint]
            angles[f, j] = rotmat_to_euler(local, "".join(CHANNELS))
    root = np.array([joints["hips"] for joints, _ in frames])
    clip = pybvh.Bvh(nodes=nodes, root_pos=root, joint_angles=angles, frame_time=1.0 / fps,
                     world_up=f"+{up}")
    target.parent.mkdir(parents=True, exist_ok=True)
    pybvh.write_bvh_file(clip, target)

