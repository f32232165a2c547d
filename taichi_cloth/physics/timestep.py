"""Choosing the time step: the scene's dt, or ``dt = "auto"`` from the cloth's highest frequency.

The highest angular frequency ω_max of the linearised cloth at rest is the square root of the
largest eigenvalue of M⁻¹K over the free particles, K the stiffness matrix of the springs (a
spring at rest along unit n contributes k·n·nᵀ blocks) and of the effects that couple particles
(bending's constant Hessian). Power iteration on M⁻¹K estimates it; Gershgorin
(ω² ≤ max_i Σ_j |K_ij| / m_i, for springs 2·Σ_{s∋i} k_s / m_i, docs/physics.md) bounds it from
above. Penalty contact adds its
stiffness per unit mass k̂ to ω², and its own modes (the normal spring with its damping ratio, and
the friction damper) bound the step too. The step is then ``safety`` × the integrator's stability bound
for all modes up to ω_max with the springs' Rayleigh damping (``integrators.stability``).
Backward Euler is stable at any step, so its step is chosen for accuracy instead:
``IMPLICIT_FRAME_FRACTION`` of a frame (1/60 s at 30 fps), the body's motion resolved, and no
longer than √(``IMPLICIT_PIN_TRAVEL`` · ℓ_pin / a_pin), a_pin the largest acceleration of the
pins the body carries and ℓ_pin the median rest length of the springs that hang from them (one
end pinned): one linearised step errs by ~a_pin·h² where the pins drag the cloth, and that
error is left as strain, of about a_pin·h²/ℓ_pin, in the springs next to the pins. Measured on
the cotton hula at 1/60 s, max strain in the row below the waist (5–8 cm from any capsule; a CG
tolerance of 10⁻³ instead of 3·10⁻³ does not remove it): 64 × 28 (ℓ_pin 2.07 cm) 2.0 % at 90
beats a minute (a_pin·h²/ℓ_pin = 0.035), 4.1 % at 120 (0.061), 5.5 % at 140 (0.084);
128 × 56 (1.02 cm) at 90: 8.0 % (0.070), and 2.0 % at 1/90 s (0.031). ``IMPLICIT_PIN_TRAVEL``
= 0.045 keeps 64 × 28 at 90 beats a minute on 1/60 s and gives the other three 1/90 s.
A frame is then split into a whole number of equal substeps not longer than that.
"""

import math
from dataclasses import dataclass

import numpy as np

from taichi_cloth.errors import InputError
from taichi_cloth.gather import scatter_sum
from taichi_cloth.physics.integrators.stability import contact_step_limit, largest_stable_step

IMPLICIT_FRAME_FRACTION = 0.5
IMPLICIT_PIN_TRAVEL = 0.045  # the largest a_pin·h²/ℓ_pin of a backward Euler step (docstring)


@dataclass(frozen=True)
class TimeStep:
    """dt [s] and substeps per frame; for ``auto`` also the estimate behind it: ω_max [rad/s] and
    the integrator's stability bound [s] (None when it has none: backward Euler); for a step in
    seconds split further, the bound of the modes that split it (``choose_time_step``)."""

    dt: float
    substeps_per_frame: int
    requested: float | str
    omega_max: float | None = None
    stable_dt: float | None = None
    pin_acceleration: float | None = None  # m/s², a_pin of backward Euler's auto step
    pin_spacing: float | None = None  # m, ℓ_pin of backward Euler's auto step

    def report(self) -> dict:
        return {"requested": self.requested, "omega_max": self.omega_max,
                "stable_dt": self.stable_dt, "pin_acceleration": self.pin_acceleration,
                "pin_spacing": self.pin_spacing}


def stiffness_product(ends, stiffness, directions, u):
    """K·u for springs at rest (blocks k·n·nᵀ): minus the linear elastic force of displacements u.
    (K·u)_i = Σ_{springs i–j} k·n·(n·(u_i − u_j))."""
    along = np.einsum("sk,sk->s", u[ends[:, 1]] - u[ends[:, 0]], directions) * stiffness
    pull = along[:, None] * directions
    return scatter_sum(ends[:, 1], pull, len(u)) - scatter_sum(ends[:, 0], pull, len(u))


def highest_frequency(positions, ends, stiffness, mass, free, iterations: int = 60,
                      coupled=()) -> float:
    """ω_max [rad/s]: power iteration on M⁻¹K restricted to free particles, capped by the
    Gershgorin bound and never below the iteration's own estimate. ``coupled``: effects whose
    Hessian adds to K (``rest_stiffness_product``, ``stiffness_row_sums``: bending)."""
    directions = positions[ends[:, 1]] - positions[ends[:, 0]]
    directions /= np.linalg.norm(directions, axis=1, keepdims=True)
    row_sum = 2.0 * (np.bincount(ends[:, 0], stiffness, minlength=len(mass))
                     + np.bincount(ends[:, 1], stiffness, minlength=len(mass)))
    for effect in coupled:
        row_sum += effect.stiffness_row_sums(len(mass))
    gershgorin = float(np.max(np.where(free, row_sum / mass, 0.0)))
    rng = np.random.default_rng(0)
    u = rng.standard_normal(positions.shape) * free[:, None]
    estimate = 0.0
    for _ in range(iterations):
        u /= np.linalg.norm(u)
        product = stiffness_product(ends, stiffness, directions, u)
        for effect in coupled:
            product += effect.rest_stiffness_product(u)
        w = product / mass[:, None] * free[:, None]
        estimate = float(np.sum(u * w))
        u = w
    # The Rayleigh quotient approaches λ_max from below; 10 % headroom covers the rest.
    return math.sqrt(max(min(1.1 * estimate, gershgorin), estimate, 0.0))


def fewest_substeps(frame_duration: float, longest: float) -> int:
    """The fewest equal substeps of a frame of ``frame_duration`` [s] no longer than
    ``longest`` [s] (a step that divides the frame exactly, up to rounding, is kept)."""
    return max(1, math.ceil(frame_duration / longest - 1e-9))


def fixed_time_step(requested: float, frame_duration: float,
                    stable: float | None = None, safety: float = 1.0) -> TimeStep:
    """The step a scene with dt = ``requested`` [s] really takes: the frame of
    ``frame_duration`` [s] split into the fewest equal substeps no longer than ``requested``,
    nor than ``safety`` × ``stable`` [s] when that bound is given (kept as ``stable_dt``
    where it split the frame into more substeps)."""
    substeps = fewest_substeps(frame_duration, requested)
    split = substeps
    if stable is not None:
        split = max(substeps, fewest_substeps(frame_duration, safety * stable))
    return TimeStep(frame_duration / split, split, requested,
                    stable_dt=stable if split > substeps else None)


def choose_time_step(requested, frame_duration: float, integrator: str, positions, ends, stiffness,
                     mass, free, damping_time: float, contact_modes, safety: float,
                     coupled=(), pin_drive=lambda: (0.0, 0.0),
                     bounding_modes: dict | None = None) -> TimeStep:
    """The substep for a frame of ``frame_duration`` [s]; ``requested`` is seconds or "auto".
    contact_modes: the ``effects.penalty.ContactMode`` of each declared contact (collision,
    ground, self-collision); coupled: the effects whose Hessian adds to the springs'
    (``highest_frequency``); pin_drive: a function giving (a_pin [m/s²], ℓ_pin [m]) (module
    docstring), called for backward Euler's auto step; bounding_modes: by effect name, the
    contact modes that bound a step in seconds too (an explicit integrator's step split until
    they are stable: self-collision's penalty, whose instability stays within its band and so
    never blows up where the frame guard would see it; an undamped one under explicit Euler,
    stable at no step, is refused naming the effect's damping key)."""
    if requested != "auto":
        stable = None
        if integrator != "implicit" and bounding_modes:
            limits = {name: contact_step_limit(integrator, modes)
                      for name, modes in bounding_modes.items()}
            for name, limit in limits.items():
                if limit <= 0.0:
                    raise InputError(f"effects.{name}.damping: {integrator} is stable at no "
                                     f"step for an undamped penalty; give it damping or choose "
                                     f"another integrator")
            stable = min(limits.values())
        return fixed_time_step(requested, frame_duration, stable, safety)
    omega_spring = highest_frequency(positions, ends, stiffness, mass, free, coupled=coupled)
    contact_stiffness = max((mode.summed_stiffness for mode in contact_modes), default=0.0)
    omega_max = math.sqrt(omega_spring ** 2 + contact_stiffness)
    if integrator == "implicit":
        longest = IMPLICIT_FRAME_FRACTION * frame_duration
        acceleration, spacing = pin_drive()
        if acceleration > 0:
            longest = min(longest, math.sqrt(IMPLICIT_PIN_TRAVEL * spacing / acceleration))
        substeps = fewest_substeps(frame_duration, longest)
        return TimeStep(frame_duration / substeps, substeps, "auto", omega_max, None,
                        acceleration, spacing)
    stable = largest_stable_step(integrator, omega_max, damping_time, contact_modes)
    if stable <= 0.0:
        raise InputError(f"simulation.dt: \"auto\" finds no stable step for {integrator} "
                         f"(explicit Euler needs [effects.damping]); give dt in seconds or "
                         f"choose another integrator")
    substeps = fewest_substeps(frame_duration, safety * stable)
    return TimeStep(frame_duration / substeps, substeps, "auto", omega_max, stable)
