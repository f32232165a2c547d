"""Kinematic dancer body: a capsule skeleton performing a procedural hula or twirl.

The body is a set of bones, each modelled for collision as capsules (a
segment a-b plus a radius r), after Sakoma et al., "Attempt of Cloth
Animation by Considering the Collision with the Object II": the layout
``"coarse"`` (their Fig. 3) uses one capsule per bone, ``"split"`` (their
Fig. 4) splits the back in 2, each thigh in 3 and each shin in 2, with the
sub-capsules of one bone tiling its segment and their radii tapering.  Both
add a shoulder capsule from shoulder joint to shoulder joint, which the
paper's skirt never reaches, for garments that hang from the shoulders.

Coordinates: SI metres and seconds, y up, the dancer stands at the origin
on the ground plane y = 0, faces +z, her left is +x.  All lengths below are
for an adult woman of 1.6 m and are multiplied by ``Body.scale``.

Skeleton (rest pose, ``scale = 1``)::

    head top          1.59 m      (display only)
    neck base         1.33 m      back bone: waist centre -> neck base (its
                                  capsules cover the lower 3/4 of it)
    shoulder joints   1.30 m      x = +-0.17 m, the shoulder bone between them
    waist centre      0.99 m      pelvis frame origin, skirt waist circle
    hip joints        0.82 m      x = +-0.09 m
    knees             ~0.43 m     thigh 0.39 m, shin 0.365 m, knees bent 13 deg
    ankles            0.07 m

Motion ``"hula"``: the kaholo (step right, close left, step right, touch
left, then the mirror to the left; the hips sway over the weight-bearing
foot and tilt so that the weight-side hip is higher) plus the 'ami hip
circle, the pelvis sinking into the bent-knee hula stance.  Each leg follows
its foot target by analytic two-bone inverse kinematics with the knee
pointing forward, so a lower pelvis bends the knees.  Every channel is a
finite sum of sinusoids of the beat phase, so the dance is C-infinity and
repeats exactly every ``LOOP_BEATS`` beats; a quintic smoothstep envelope
eases it in from the rest pose.

Motion ``"sway"``: the hula's stance with the feet planted, the weight
rocking from side to side every ``SWAY_BEATS`` beats (the pelvis shifting
and tilting over the weight foot, the knees bending with the sink), no
steps and no hip circle: slow and calm at a low tempo.

Motion ``"twirl"``: the rest pose turned about the vertical through her
feet by the spin-and-stop angle of ``body.twirl`` (for a circle skirt).

Motion ``"walk"``: walking on the spot, as on a treadmill: with the stride
phase phi = 2 pi beat / WALK_BEATS the left foot is at z = WALK_STRIDE/2 sin phi
(the right opposite), lifted by WALK_LIFT ((1 + cos phi)/2)^4 while it swings
forward (the right by ((1 - cos phi)/2)^4); the pelvis sinks WALK_SINK so the
legs reach, bobs WALK_BOB (1 - cos 2 phi)/2, sways WALK_SWAY over the stance
foot (-cos phi) with the hula's hip roll, and turns -WALK_YAW sin phi with the
stride.  All sinusoids of the beat: C-infinity and periodic.

Velocities are exact derivatives computed by the complex step: for a
function f analytic in t, f'(t) = Im f(t + i h) / h + O(h^2) with no
subtractive cancellation, so h = 1e-20 s gives them to machine precision.
The pose code therefore uses only complex-analytic operations (no abs, no
norms, branches only on real parts).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from taichi_cloth.body.capsules import (CAPSULE_LAYOUT_NAMES, DISPLAY_CAPSULE_NAMES,
                                        DISPLAY_CAPSULE_RADIUS, CapsuleLayout)
from taichi_cloth.body.frames import (angular_velocity, rotation_x, rotation_y, rotation_z,
                                      row_dot, turned, turned_vector, vector)
from taichi_cloth.body.twirl import twirl_turns
from taichi_cloth.body.hula import (BACK_COUNTER, COMPLEX_STEP, FOOT_LIFT, HIP_CIRCLE_BEATS,
                                   HIP_CIRCLE_RADIUS, HIP_SWAY, KAHOLO_HARMONICS, LOOP_BEATS,
                                   PELVIS_DIP, PELVIS_PITCH, PELVIS_ROLL, PELVIS_SINK, PELVIS_YAW,
                                   STEP_LENGTH, kaholo_series, smoothstep)

MOTION_NAMES = ("still", "hula", "sway", "twirl", "walk")
SWAY_BEATS = 4  # a sway: the weight over the left foot, then the right, in this many beats
# walk (on the spot, as on a treadmill): a stride (a step with each foot) every WALK_BEATS beats
WALK_BEATS = 2
WALK_STRIDE = 0.24  # m: each foot travels ± half of it forward and back
WALK_LIFT = 0.06  # m: the swinging foot's highest lift
WALK_SINK = 0.03  # m: the pelvis lower than at rest, so that the legs reach the stride
WALK_BOB = 0.012  # m: the pelvis dips this much at double support
WALK_SWAY = 0.03  # m: the pelvis over the stance foot
WALK_YAW = np.radians(6.0)  # rad: the pelvis turns with the stride

# --- rest skeleton, metres at scale 1 ---------------------------------------
WAIST_HEIGHT = 0.99  # y of the waist circle centre = pelvis frame origin
WAIST_RADIUS = 0.17  # radius of the circle the skirt's top ring is pinned on
HIP_JOINT_LOCAL = (0.09, -0.17, 0.0)  # left hip joint in the pelvis frame (right: x negated)
THIGH_LENGTH = 0.39  # hip joint -> knee
SHIN_LENGTH = 0.365  # knee -> ankle
ANKLE_HEIGHT = 0.07  # y of the ankle joints with the feet flat
BACK_LENGTH = 0.34  # waist centre -> neck base
PELVIS_HALF_WIDTH = 0.07  # half length of the horizontal pelvis segment
PELVIS_CENTRE_LOCAL = (0.0, -0.12, -0.015)  # pelvis segment midpoint in the pelvis frame
KNEE_FLEXION_MIN = np.radians(3.0)  # the legs never straighten beyond this, rad
LEG_REACH_SOFTNESS = 0.001  # width of the soft reach limit, m

# --- display capsules (rendering only, not collided) --------------------------
_NECK_TOP_LOCAL = (0.0, 0.08, 0.0)  # chest frame, origin at the neck base
_HEAD_SEGMENT_LOCAL = ((0.0, 0.14, 0.01), (0.0, 0.17, 0.01))
_SHOULDER_LOCAL = (0.17, -0.03, 0.0)  # left shoulder in the chest frame
_UPPER_ARM_LOCAL = (0.17, -0.20, 0.08)  # left shoulder -> elbow, arms held out (hula)
_FOREARM_LOCAL = (0.13, -0.03, 0.20)  # left elbow -> wrist
_FOOT_WORLD = (0.0, -0.04, 0.14)  # ankle -> toe, feet face +z

_MIRROR = np.array([-1.0, 1.0, 1.0])  # left -> right
_HIP_JOINTS = np.array([HIP_JOINT_LOCAL, _MIRROR * HIP_JOINT_LOCAL])  # pelvis frame, (2, 3)
_PELVIS_SEGMENT_LOCAL = np.array(PELVIS_CENTRE_LOCAL) + np.array(
    [[-PELVIS_HALF_WIDTH, 0.0, 0.0], [PELVIS_HALF_WIDTH, 0.0, 0.0]])  # pelvis frame, (2, 3)
_SHOULDERS = np.array([_SHOULDER_LOCAL, _MIRROR * _SHOULDER_LOCAL])  # chest frame, (2, 3)
_ELBOWS = _SHOULDERS + np.array([_UPPER_ARM_LOCAL, _MIRROR * _UPPER_ARM_LOCAL])
_WRISTS = _ELBOWS + np.array([_FOREARM_LOCAL, _MIRROR * _FOREARM_LOCAL])
# the display capsules carried by the chest frame: neck, head, both upper arms, both forearms
_CHEST_DISPLAY_A = np.array([(0.0, 0.0, 0.0), _HEAD_SEGMENT_LOCAL[0], *_SHOULDERS, *_ELBOWS])
_CHEST_DISPLAY_B = np.array([_NECK_TOP_LOCAL, _HEAD_SEGMENT_LOCAL[1], *_ELBOWS, *_WRISTS])


def _leg_reach() -> float:
    """Longest hip-ankle distance allowed, m (scale 1): knee flexed by ``KNEE_FLEXION_MIN``.

    D_max^2 = L1^2 + L2^2 + 2 L1 L2 cos(flexion_min).
    """
    return float(np.sqrt(THIGH_LENGTH**2 + SHIN_LENGTH**2
                         + 2.0 * THIGH_LENGTH * SHIN_LENGTH * np.cos(KNEE_FLEXION_MIN)))


def _leg_inverse_kinematics(hip, foot_target, knee_direction):
    """Two-bone IK: knees and ankles (..., N, 3) for hips and ankle targets (..., N, 3), metres
    at scale 1.

    With d = target - hip, D = |d| softly limited to the reach D_max
        D' = D_max - w softplus((D_max - D) / w),   softplus(x) = log(1 + e^x),
    the knee lies a = (L1^2 - L2^2 + D'^2) / (2 D') along d/D and h = sqrt(L1^2 - a^2)
    towards ``knee_direction`` (..., 3) made perpendicular to d; the ankle is hip + D' d/D.
    The thigh |knee - hip| = L1 and shin |ankle - knee| = L2 hold exactly.
    """
    offset = foot_target - hip
    distance = np.sqrt(row_dot(offset, offset))
    axis = offset / distance[..., None]
    reach = _leg_reach()
    slack = (reach - distance) / LEG_REACH_SOFTNESS
    shift = np.maximum(slack.real, 0.0)  # log(1 + e^x) = m + log(e^-m + e^(x-m)) for any m
    reach_distance = reach - LEG_REACH_SOFTNESS * (shift + np.log(np.exp(-shift) + np.exp(slack - shift)))
    along = (THIGH_LENGTH**2 - SHIN_LENGTH**2 + reach_distance**2) / (2.0 * reach_distance)
    across = np.sqrt(THIGH_LENGTH**2 - along**2)
    direction = knee_direction[..., None, :]
    bend = direction - row_dot(axis, direction)[..., None] * axis
    bend = bend / np.sqrt(row_dot(bend, bend))[..., None]
    knee = hip + along[..., None] * axis + across[..., None] * bend
    ankle = hip + reach_distance[..., None] * axis
    return knee, ankle


@dataclass(frozen=True)
class BodyPose:
    """The body at one instant.  Positions in metres, velocities in m/s, angular velocity in rad/s.

    ``capsule_*`` rows follow ``Body.capsule_names``; ``display_capsule_*`` rows follow
    ``DISPLAY_CAPSULE_NAMES``.  The pelvis frame maps local to world points by
    world = pelvis_rotation @ local + pelvis_position; a point p fixed in it moves with
    pelvis_velocity + pelvis_angular_velocity x (p - pelvis_position). The chest frame (origin
    at the base of the neck, turning with the upper body) does the same for the chest: a
    dress's straps ride on it.
    """

    time: float
    capsule_a: np.ndarray  # (C, 3) segment start points, m
    capsule_b: np.ndarray  # (C, 3) segment end points, m
    capsule_velocity_a: np.ndarray  # (C, 3) d/dt capsule_a, m/s
    capsule_velocity_b: np.ndarray  # (C, 3) d/dt capsule_b, m/s
    display_capsule_a: np.ndarray  # (D, 3) m
    display_capsule_b: np.ndarray  # (D, 3) m
    pelvis_position: np.ndarray  # (3,) centre of the waist circle, m
    pelvis_rotation: np.ndarray  # (3, 3) local -> world rotation
    pelvis_velocity: np.ndarray  # (3,) m/s
    pelvis_angular_velocity: np.ndarray  # (3,) world frame, rad/s
    chest_position: np.ndarray  # (3,) the base of the neck, m
    chest_rotation: np.ndarray  # (3, 3) the upper body's local -> world rotation
    chest_velocity: np.ndarray  # (3,) m/s
    chest_angular_velocity: np.ndarray  # (3,) world frame, rad/s


class Body:
    """A kinematic dancer whose collision capsules the cloth is pushed out of.

    Parameters
    ----------
    motion : ``"still"`` (rest pose forever), ``"hula"`` (kaholo steps with hip sway and
        'ami hip circles), ``"sway"`` (the weight rocking side to side, feet planted),
        ``"twirl"`` (the rest pose spinning on the spot and stopping, ``body.twirl``) or
        ``"walk"`` (walking on the spot).
    tempo : beats per minute of the dance (> 0).
    amplitude : dimensionless size of the motion (>= 0); twirl: 2 turns per loop at 1; hula: 1 is
        natural: pelvis sway 6 cm,
        hip circle radius 3.5 cm, hip tilt 5 deg, yaw 4 deg, pitch 3 deg; the pelvis sinks
        (1.5 cm + 1 cm dips) as amplitude^2.  The kaholo steps (12 cm, feet lifted 2 cm) do
        not scale with it.
    capsules : collision layout, ``"coarse"`` (7 capsules, one per bone) or ``"split"``
        (14 capsules: back 2, pelvis 1, thighs 3 each, shins 2 each, shoulders 1).
    scale : multiplies every length (1 = a 1.6 m tall woman).
    ease_in : seconds over which the dance fades in from the rest pose (>= 0), by the C2
        envelope E(s) = 6 s^5 - 15 s^4 + 10 s^3, s = clamp(t / ease_in, 0, 1).

    Attributes
    ----------
    capsule_count, capsule_names, capsule_radius (C,) m : collision capsules.
    display_capsule_count, display_capsule_radius (D,) m : neck, head, arms, feet.
    waist_height : m, y of the waist circle (pelvis frame origin) in the rest pose.
    waist_radius : m, radius of the circle in the pelvis frame the skirt is pinned on.
    loop_period : s, the dance repeats after this (for t >= ease_in): LOOP_BEATS * 60 / tempo.
    """

    def __init__(self, motion: str = "hula", tempo: float = 90.0, amplitude: float = 1.0,
                 capsules: str = "split", scale: float = 1.0, ease_in: float = 1.0):
        if motion not in MOTION_NAMES:
            raise ValueError(f"motion={motion!r} is unknown; valid motions: {', '.join(MOTION_NAMES)}")
        if capsules not in CAPSULE_LAYOUT_NAMES:
            raise ValueError(
                f"capsules={capsules!r} is unknown; valid layouts: {', '.join(CAPSULE_LAYOUT_NAMES)}")
        if not tempo > 0.0:
            raise ValueError(f"tempo={tempo!r} must be > 0 beats per minute")
        if not amplitude >= 0.0:
            raise ValueError(f"amplitude={amplitude!r} must be >= 0")
        if not scale > 0.0:
            raise ValueError(f"scale={scale!r} must be > 0")
        if not ease_in >= 0.0:
            raise ValueError(f"ease_in={ease_in!r} must be >= 0 seconds")
        self.motion = motion
        self.tempo = float(tempo)
        self.amplitude = float(amplitude)
        self.capsule_layout = capsules
        self.scale = float(scale)
        self.ease_in = float(ease_in)
        self._dance_gain = 1.0 if motion in ("hula", "sway", "walk") else 0.0

        self.layout = CapsuleLayout(capsules, self.scale)
        self.capsule_names = self.layout.names
        self.capsule_count = len(self.capsule_names)
        self.capsule_radius = self.layout.radius

        self.display_capsule_count = len(DISPLAY_CAPSULE_NAMES)
        self.display_capsule_radius = self.scale * np.array(DISPLAY_CAPSULE_RADIUS)
        self.waist_height = self.scale * WAIST_HEIGHT
        self.waist_radius = self.scale * WAIST_RADIUS
        self.loop_period = LOOP_BEATS * 60.0 / self.tempo
        self._kaholo_constant, self._kaholo_cosine, self._kaholo_sine = kaholo_series()

    def pose(self, t: float) -> BodyPose:
        """The body at time ``t`` (s), with exact (complex-step) velocities."""
        return self.poses([t])[0]

    def poses(self, times) -> list[BodyPose]:
        """The body at each of ``times`` (s), evaluated together (one skeleton of arrays over
        the times), with exact (complex-step) velocities."""
        times = np.asarray(times, dtype=float)
        (capsule_a, capsule_b, display_a, display_b, pelvis_position, pelvis_rotation,
         chest_position, chest_rotation) = self._skeleton(times + 1j * COMPLEX_STEP)
        scale, step = self.scale, COMPLEX_STEP
        pelvis_spin = angular_velocity(pelvis_rotation.real, pelvis_rotation.imag / step)
        chest_spin = angular_velocity(chest_rotation.real, chest_rotation.imag / step)
        parts = {"capsule_a": scale * capsule_a.real, "capsule_b": scale * capsule_b.real,
                 "capsule_velocity_a": scale * capsule_a.imag / step,
                 "capsule_velocity_b": scale * capsule_b.imag / step,
                 "display_capsule_a": scale * display_a.real,
                 "display_capsule_b": scale * display_b.real,
                 "pelvis_position": scale * pelvis_position.real,
                 "pelvis_rotation": pelvis_rotation.real,
                 "pelvis_velocity": scale * pelvis_position.imag / step,
                 "pelvis_angular_velocity": pelvis_spin,
                 "chest_position": scale * chest_position.real,
                 "chest_rotation": chest_rotation.real,
                 "chest_velocity": scale * chest_position.imag / step,
                 "chest_angular_velocity": chest_spin}
        return [BodyPose(time=float(t), **{name: part[k] for name, part in parts.items()})
                for k, t in enumerate(times)]

    def _envelope(self, t):
        """Ease-in factor E(t) of the dance: 0 at t <= 0, 1 at t >= ease_in, C2 quintic between."""
        if self.ease_in == 0.0:
            return np.ones_like(t)
        return np.where(t.real >= self.ease_in, 1.0,
                        np.where(t.real <= 0.0, 0.0, smoothstep(t / self.ease_in)))

    def _kaholo(self, beat):
        """Unscaled kaholo channels at each ``beat`` (see ``hula.kaholo_series``): steps of the
        left and right foot (towards her right), their lifts (0..1) and the weight side (+1
        left), each shaped like ``beat``."""
        harmonic = np.multiply.outer(2.0 * np.pi * beat / LOOP_BEATS,
                                     np.arange(1, KAHOLO_HARMONICS + 1))
        channels = (self._kaholo_constant + np.cos(harmonic) @ self._kaholo_cosine.T
                    + np.sin(harmonic) @ self._kaholo_sine.T)
        return tuple(np.moveaxis(channels, -1, 0))

    def _skeleton(self, t):
        """Capsule, display, pelvis and chest (neck base, R_back) geometry at (complex) times
        ``t`` (T,), metres at scale 1, each with a leading axis of T.

        With the beat count beat = tempo t / 60, the loop phase phi = 2 pi beat / LOOP_BEATS,
        the circle phase psi = 2 pi beat / HIP_CIRCLE_BEATS, the step gain s = E(t) and the
        sway gain g = amplitude E(t) (both 0 for ``"still"``):
            feet:   x = +-0.09 - s STEP_LENGTH step_side(phi),  y = ANKLE_HEIGHT + s FOOT_LIFT lift_side(phi)
            pelvis: x = mean feet x + dx,  dx = g (HIP_SWAY weight(phi) + HIP_CIRCLE_RADIUS cos psi)
                    y = WAIST_HEIGHT - g amplitude (PELVIS_SINK + PELVIS_DIP (1 - cos 2 pi beat) / 2)
                    z = dz = g HIP_CIRCLE_RADIUS sin psi
                    R = Ry(g PELVIS_YAW sin psi) Rz(g PELVIS_ROLL weight(phi)) Rx(-g PELVIS_PITCH sin psi)
            back:   from the pelvis origin, R_back = Rz(asin(k dx / L)) Rx(asin(-k dz / L)) with
                    k = BACK_COUNTER, so the chest moves only (1 - k) of the hip sway and circle.
        The sway lengthens the legs by ~ dx^2 / (2 leg), so the sink grows as amplitude^2 to
        keep the knees bent at any amplitude.
        """
        step_gain = self._dance_gain * self._envelope(t)
        sway_gain = self.amplitude * step_gain
        beat = self.tempo * t / 60.0
        circle_phase = 2.0 * np.pi * beat / HIP_CIRCLE_BEATS
        stride = 0.0 * beat  # walk: the feet's travel forward (+z), the pelvis's bob and turn
        bob = turn = 0.0 * beat
        sink = PELVIS_SINK + PELVIS_DIP * 0.5 * (1.0 - np.cos(2.0 * np.pi * beat))
        reach_sink = 0.0  # walk: lower by this (× the step gain) to reach the stride
        sway = HIP_SWAY
        if self.motion == "sway":  # feet planted, the weight rocking side to side, no circle
            step_left = step_right = lift_left = lift_right = 0.0 * beat
            weight_side = np.sin(2.0 * np.pi * beat / SWAY_BEATS)
            circle_phase = 0.0 * beat
            circle = 0.0
        elif self.motion == "walk":  # the left foot swings forward while phi runs -pi/2..pi/2
            phase = 2.0 * np.pi * beat / WALK_BEATS
            step_left = step_right = 0.0 * beat
            stride = 0.5 * WALK_STRIDE * np.sin(phase)
            lift_left = (WALK_LIFT / FOOT_LIFT) * (0.5 * (1.0 + np.cos(phase))) ** 4
            lift_right = (WALK_LIFT / FOOT_LIFT) * (0.5 * (1.0 - np.cos(phase))) ** 4
            weight_side = -np.cos(phase)  # over the stance foot: the left at phase = pi
            bob = WALK_BOB * 0.5 * (1.0 - np.cos(2.0 * phase))  # lowest at double support
            turn = -WALK_YAW * np.sin(phase)  # the left hip forward with the left foot
            sink, reach_sink, sway = 0.0, WALK_SINK, WALK_SWAY
            circle_phase = 0.0 * beat
            circle = 0.0
        else:
            step_left, step_right, lift_left, lift_right, weight_side = self._kaholo(beat)
            circle = 1.0

        hip_x = HIP_JOINT_LOCAL[0]
        foot_target = np.stack([
            vector(hip_x - step_gain * STEP_LENGTH * step_left,
                    ANKLE_HEIGHT + step_gain * FOOT_LIFT * lift_left, step_gain * stride),
            vector(-hip_x - step_gain * STEP_LENGTH * step_right,
                    ANKLE_HEIGHT + step_gain * FOOT_LIFT * lift_right, -step_gain * stride),
        ], axis=-2)
        pelvis_shift_x = sway_gain * (sway * weight_side
                                      + circle * HIP_CIRCLE_RADIUS * np.cos(circle_phase))
        pelvis_shift_z = sway_gain * circle * HIP_CIRCLE_RADIUS * np.sin(circle_phase)
        pelvis_sink = sway_gain * (self.amplitude * sink + bob) + step_gain * reach_sink
        pelvis_position = vector(
            0.5 * (foot_target[..., 0, 0] + foot_target[..., 1, 0]) + pelvis_shift_x,
            WAIST_HEIGHT - pelvis_sink,
            pelvis_shift_z,
        )
        pelvis_rotation = (rotation_y(sway_gain * (PELVIS_YAW * np.sin(circle_phase) + turn))
                           @ rotation_z(sway_gain * PELVIS_ROLL * weight_side)
                           @ rotation_x(-sway_gain * PELVIS_PITCH * np.sin(circle_phase)))

        hip = pelvis_position[..., None, :] + turned(_HIP_JOINTS, pelvis_rotation)
        knee, ankle = _leg_inverse_kinematics(hip, foot_target, pelvis_rotation[..., :, 2])

        back_rotation = (rotation_z(np.arcsin(BACK_COUNTER * pelvis_shift_x / BACK_LENGTH))
                         @ rotation_x(np.arcsin(-BACK_COUNTER * pelvis_shift_z / BACK_LENGTH)))
        neck_base = pelvis_position + BACK_LENGTH * back_rotation[..., :, 1]
        pelvis_segment = pelvis_position[..., None, :] + turned(_PELVIS_SEGMENT_LOCAL,
                                                                 pelvis_rotation)
        shoulder_world = neck_base[..., None, :] + turned(_SHOULDERS, back_rotation)
        bone_start = np.stack([pelvis_segment[..., 0, :], pelvis_position, hip[..., 0, :],
                               hip[..., 1, :], knee[..., 0, :], knee[..., 1, :],
                               shoulder_world[..., 0, :]], axis=-2)
        bone_end = np.stack([pelvis_segment[..., 1, :], neck_base, knee[..., 0, :],
                             knee[..., 1, :], ankle[..., 0, :], ankle[..., 1, :],
                             shoulder_world[..., 1, :]], axis=-2)
        capsule_a, capsule_b = self.layout.tile(bone_start, bone_end)

        chest_display_a, chest_display_b = (neck_base[..., None, :] + turned(local, back_rotation)
                                            for local in (_CHEST_DISPLAY_A, _CHEST_DISPLAY_B))
        display_a = np.concatenate([chest_display_a, ankle], axis=-2)
        display_b = np.concatenate([chest_display_b, ankle + _FOOT_WORLD], axis=-2)
        if self.motion == "twirl":
            spin = rotation_y(2.0 * np.pi * twirl_turns(beat, self.amplitude))
            capsule_a, capsule_b = turned(capsule_a, spin), turned(capsule_b, spin)
            display_a, display_b = turned(display_a, spin), turned(display_b, spin)
            pelvis_position = turned_vector(pelvis_position, spin)
            neck_base = turned_vector(neck_base, spin)
            pelvis_rotation, back_rotation = spin @ pelvis_rotation, spin @ back_rotation
        return (capsule_a, capsule_b, display_a, display_b, pelvis_position, pelvis_rotation,
                neck_base, back_rotation)
