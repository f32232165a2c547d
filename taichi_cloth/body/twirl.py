"""The twirl's choreography: the dancer spins on the spot about the vertical through her feet,
then stops and stands, and does it again (``body.dancer`` turns the rest skeleton by the angle).

One loop lasts ``LOOP_BEATS`` beats. Within it, with b the beat within the loop, the spin rate
(turns per beat) is

    ω(b) = W·S(b)                 0 ≤ b < 1     spin up
    ω(b) = W                      1 ≤ b < 3     full speed
    ω(b) = W·(1 − S(b − 3))       3 ≤ b < 4     stop
    ω(b) = 0                      4 ≤ b < 8     stand (the skirt swings round and wraps the legs)

with S the quintic smoothstep, so ω is C² and the angle, its integral, C³ everywhere (ω and its
first two derivatives vanish at the loop's start and end). With ∫₀ˢ S = s⁶ − 3s⁵ + 5s⁴/2 (½ at
s = 1) one loop turns the dancer 3·W turns; at amplitude 1 that is ``TURNS_PER_LOOP`` whole
turns, so the pose repeats exactly every loop (at 90 beats per minute: 1 turn per second at full
speed, a loop of 5.3 s). The angle uses only complex-analytic operations (branches on real
parts), as the complex-step velocities of ``body.dancer`` need.
"""

import numpy as np


LOOP_BEATS = 8
SPIN_UP_BEATS = 1.0
FULL_SPEED_BEATS = 2.0
STOP_BEATS = 1.0
TURNS_PER_LOOP = 2.0  # at amplitude 1
FULL_SPEED = TURNS_PER_LOOP / (0.5 * SPIN_UP_BEATS + FULL_SPEED_BEATS + 0.5 * STOP_BEATS)


def smoothstep_integral(s):
    """∫₀ˢ S(u) du = s⁶ − 3 s⁵ + 5 s⁴ / 2 (½ at s = 1)."""
    return s ** 4 * (2.5 - 3.0 * s + s * s)


def twirl_turns(beat, amplitude: float = 1.0):
    """The dancer's yaw [turns] at each (complex) ``beat``: ``amplitude`` × the module's profile,
    counter-clockwise seen from above; 0 at beat ≤ 0. Every piece is evaluated and the one each
    beat's real part falls in is kept."""
    loops = np.floor(beat.real / LOOP_BEATS)
    b = beat - loops * LOOP_BEATS
    stop_start = SPIN_UP_BEATS + FULL_SPEED_BEATS
    s = (b - stop_start) / STOP_BEATS
    within = np.select(
        [b.real < SPIN_UP_BEATS, b.real < stop_start, b.real < stop_start + STOP_BEATS],
        [SPIN_UP_BEATS * smoothstep_integral(b / SPIN_UP_BEATS),
         0.5 * SPIN_UP_BEATS + (b - SPIN_UP_BEATS),
         0.5 * SPIN_UP_BEATS + FULL_SPEED_BEATS + STOP_BEATS * (s - smoothstep_integral(s))],
        0.5 * SPIN_UP_BEATS + FULL_SPEED_BEATS + 0.5 * STOP_BEATS)
    return np.where(beat.real <= 0.0, 0.0 * beat,
                    amplitude * (loops * TURNS_PER_LOOP + FULL_SPEED * within))
