"""The hula's choreography at amplitude 1: the kaholo step pattern and the 'ami hip circle as
keyframes, fitted by a finite Fourier series so the dance is C-infinity and repeats exactly every
``LOOP_BEATS`` beats (``body.dancer`` poses the skeleton from these channels)."""

import numpy as np

# --- dance, at amplitude 1 ---------------------------------------------------
LOOP_BEATS = 8  # the kaholo right-and-back; the dance repeats after this many beats
HIP_CIRCLE_BEATS = 4  # one 'ami circle takes this many beats
STEP_LENGTH = 0.12  # kaholo side step, m
FOOT_LIFT = 0.02  # ankle rise of the stepping foot, m
HIP_SWAY = 0.06  # lateral pelvis shift over the weight foot, m
HIP_CIRCLE_RADIUS = 0.035  # 'ami circle of the pelvis, m
PELVIS_SINK = 0.015  # the pelvis settles this much into the bent-knee stance, m
PELVIS_DIP = 0.01  # extra drop of the pelvis between beats (weight transfer), m
PELVIS_ROLL = np.radians(5.0)  # hip tilt, weight-side hip up, rad
PELVIS_YAW = np.radians(4.0)  # pelvis twist with the hip circle, rad
PELVIS_PITCH = np.radians(3.0)  # pelvic tuck with the hip circle, rad
BACK_COUNTER = 0.6  # the chest moves only (1 - this) of the pelvis's sideways shift

# kaholo keyframes at beats 0..7 (beat 8 = beat 0): foot positions in steps
# towards her right (-x) and the weight side (+1 left, -1 right).
#   beat: 1 step R, 2 close L, 3 step R, 4 touch L, 5 step L, 6 close R, 7 step L, 8 touch R
KAHOLO_STEP_LEFT = (0, 0, 1, 1, 2, 1, 1, 0)
KAHOLO_STEP_RIGHT = (0, 1, 1, 2, 2, 2, 1, 1)
KAHOLO_WEIGHT_SIDE = (1, -1, 1, -1, -1, 1, -1, 1)
KAHOLO_SAMPLES_PER_BEAT = 64  # sampling of the keyframed channels for the Fourier fit
KAHOLO_HARMONICS = 40  # sinusoids kept per channel (5 per beat)

COMPLEX_STEP = 1e-20  # s, imaginary time step of the complex-step derivative


def smoothstep(s):
    """Quintic smoothstep S(s) = 6 s^5 - 15 s^4 + 10 s^3: S, S', S'' = 0, 0, 0 at s = 0 and 1, 0, 0 at s = 1."""
    return s * s * s * (10.0 - 15.0 * s + 6.0 * s * s)


def kaholo_series() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Fourier coefficients of the kaholo channels over one loop of ``LOOP_BEATS`` beats.

    Channels (dimensionless, scaled later): 0 left-foot step, 1 right-foot step (steps to
    her right), 2 left-foot lift, 3 right-foot lift (0..1), 4 weight side (+1 left).  Each is
    keyframed at whole beats and eased between keys by the C2 quintic smoothstep; a foot
    whose key changes lifts by 4 S (1 - S).  The sampled channels are fitted by
        f(phi) = c0 + sum_k a_k cos(k phi) + b_k sin(k phi),   phi = 2 pi beat / LOOP_BEATS,
    truncated at ``KAHOLO_HARMONICS`` (exact discrete Fourier coefficients of the samples),
    so the fitted dance is C-infinity and exactly periodic.  The step channels are shifted
    so the dancer's mean position over a loop is the origin.

    Returns (c0 (5,), a (5, K), b (5, K)).
    """
    sample_count = LOOP_BEATS * KAHOLO_SAMPLES_PER_BEAT
    beat = np.arange(sample_count) / KAHOLO_SAMPLES_PER_BEAT
    beat_index = np.floor(beat).astype(int)
    ease = smoothstep(beat - beat_index)

    def keyed(keys):
        key = np.asarray(keys, dtype=float)
        return key[beat_index] + (np.roll(key, -1) - key)[beat_index] * ease

    def lift(keys):
        key = np.asarray(keys, dtype=float)
        return (np.roll(key, -1) != key)[beat_index] * 4.0 * ease * (1.0 - ease)

    channels = np.stack([
        keyed(KAHOLO_STEP_LEFT), keyed(KAHOLO_STEP_RIGHT),
        lift(KAHOLO_STEP_LEFT), lift(KAHOLO_STEP_RIGHT),
        keyed(KAHOLO_WEIGHT_SIDE),
    ])
    spectrum = np.fft.rfft(channels, axis=1) / sample_count
    constant = spectrum[:, 0].real.copy()
    constant[:2] -= 0.5 * (constant[0] + constant[1])
    harmonics = spectrum[:, 1:KAHOLO_HARMONICS + 1]
    return constant, 2.0 * harmonics.real, -2.0 * harmonics.imag
