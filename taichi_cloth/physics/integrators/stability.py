"""Stability of each integrator on the damped oscillator ẍ = −ω²x − 2ζω·ẋ (docs/physics.md, "Closed forms").

One step of a linear method maps (x, v) to G(ωh, ζ)·(x, v); it is stable when the spectral radius
of G is at most 1. ``largest_stable_step`` finds the largest such h for every mode of a cloth
from its highest angular frequency ω_max and its damping: springs damped in proportion to their
stiffness (Rayleigh, c = β·k) give a mode of frequency ω the damping ratio ζ = β·ω/2, so the
bound is the minimum over ω ∈ (0, ω_max] of the per-mode bound.
"""

import numpy as np


def system_matrix(omega: float, zeta: float) -> np.ndarray:
    """d/dt (x, v) = A (x, v) for the damped oscillator."""
    return np.array([[0.0, 1.0], [-omega ** 2, -2.0 * zeta * omega]])


def amplification(method: str, omega: float, zeta: float, h) -> np.ndarray:
    """The one-step matrices G of ``method`` ("euler", "symplectic", "rk4", "implicit") for the
    steps h (an array (K,) of them: (K, 2, 2), or one: (2, 2))."""
    a = system_matrix(omega, zeta)
    ha = np.multiply.outer(np.asarray(h, float), a)
    identity = np.broadcast_to(np.eye(2), ha.shape)
    if method == "euler":
        return identity + ha
    if method == "symplectic":
        # v' = v + h·a(x, v);  x' = x + h·v'
        velocity_update = identity.copy()
        velocity_update[..., 1, :] += ha[..., 1, :]
        position_update = identity.copy()
        position_update[..., 0, 1] = ha[..., 0, 1]  # h·1
        return position_update @ velocity_update
    if method == "rk4":
        ha2 = ha @ ha
        return identity + ha + ha2 / 2 + ha2 @ ha / 6 + ha2 @ ha2 / 24
    if method == "implicit":
        return np.linalg.inv(identity - ha)
    raise ValueError(f"unknown method {method!r}")


def spectral_radius(g: np.ndarray) -> np.ndarray:
    """max |λ| of 2 × 2 matrices g (..., 2, 2), from λ = tr/2 ± √(tr²/4 − det)."""
    trace = g[..., 0, 0] + g[..., 1, 1]
    determinant = g[..., 0, 0] * g[..., 1, 1] - g[..., 0, 1] * g[..., 1, 0]
    root = np.sqrt((trace * trace / 4 - determinant).astype(complex))
    return np.maximum(np.abs(trace / 2 + root), np.abs(trace / 2 - root))


def is_stable(method: str, omega: float, zeta: float, h):
    """Whether the steps h (one, or an array) are stable: spectral radius of G at most 1."""
    return spectral_radius(amplification(method, omega, zeta, h)) <= 1.0 + 1e-12


SCAN_FACTOR = 1.05


def mode_step_limit(method: str, omega: float, zeta: float, h_max: float = 1e3) -> float:
    """Largest h with a stable step for one mode (scan up in factors of 1.05, then bisect).
    Returns ``h_max`` when every step up to it is stable, 0 when none is. The scan starts below
    ωh = 0.1·ζ, inside explicit Euler's region ωh ≤ 2ζ however light the damping, and at
    ωh = 1e-4 for an undamped mode, where explicit Euler's growth 1 + (ωh)²/2 is already
    measurable (it is never stable). The scan tests its whole geometric ladder of steps in one
    vectorised call (closed-form 2 × 2 eigenvalues), so ``dt = "auto"`` costs milliseconds."""
    h = (min(1e-4, 0.1 * zeta) if zeta > 0 else 1e-4) / omega
    if not is_stable(method, omega, zeta, h):
        return 0.0
    rungs = int(np.ceil(np.log(h_max / h) / np.log(SCAN_FACTOR))) + 1
    ladder = h * SCAN_FACTOR ** np.arange(1, rungs + 1)
    unstable = np.flatnonzero(~is_stable(method, omega, zeta, ladder) | (ladder >= h_max * 1.05))
    first = int(unstable[0]) if len(unstable) else rungs
    low = h if first == 0 else float(ladder[first - 1])
    if low >= h_max:
        return h_max
    high = low * SCAN_FACTOR
    for _ in range(40):
        middle = 0.5 * (low + high)
        low, high = (middle, high) if is_stable(method, omega, zeta, middle) else (low, middle)
    return low


def largest_stable_step(method: str, omega_max: float, damping_time: float,
                        contact_modes=()) -> float:
    """Largest stable h [s] for all spring modes up to ω_max [rad/s] with Rayleigh damping time
    β [s] (ζ = β·ω/2), and for each contact mode in ``contact_modes``
    (``contact_step_limit``). 0 when no step is stable (undamped explicit Euler)."""
    limits = [mode_step_limit(method, omega, 0.5 * damping_time * omega)
              for omega in np.geomspace(omega_max * 1e-3, omega_max, 25)]
    return float(min(limits + [contact_step_limit(method, contact_modes)]))


def contact_step_limit(method: str, contact_modes) -> float:
    """Largest stable h [s] for each ``effects.penalty.ContactMode`` in ``contact_modes``: its
    normal mode and its friction dampers' (``ContactMode.oscillators``); inf without contacts."""
    limits = [mode_step_limit(method, omega, ratio)
              for mode in contact_modes for omega, ratio in mode.oscillators()]
    return float(min(limits, default=np.inf))
