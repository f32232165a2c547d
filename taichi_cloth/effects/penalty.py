"""Penalty contact with friction, shared by the body's capsules (``collision``), the ground and the
support plate.

Seed §2.6: bones are capsules (a segment a–b and a radius r), particles are points, and a point
inside a capsule is pushed out by a spring on its penetration (the penalty method, §2.6.2).
Point vs capsule (§2.6.3, docs/physics.md): s = clamp(((x − a)·(b − a)) / |b − a|², 0, 1),
y = a + s·(b − a), distance |x − y| − r; s strictly inside (0, 1) is the cylinder, s = 0 or 1 a
hemispherical cap, and a = b a sphere.

The contact force is part of the shared force evaluation (so RK4 stages and the implicit solve see
it). With depth d = r + margin − |x − y| > 0, normal n = (x − y)/|x − y|, particle mass m, and the
relative velocity u = v − v_surface:

    f_n = m·(k̂·d − 2ζ·√k̂·(u·n)), clamped at 0 (contact pushes, never pulls)
    f_t = −min(μ·f_n, 2·m·√k̂·|u_t|) · u_t/|u_t|     (Coulomb, regularised for small slip)

k̂ [1/s²] is a stiffness per unit mass, so a contact's frequency √k̂ does not depend on the cloth's
resolution, ζ the damping ratio of that normal spring, μ the friction coefficient. The surface
velocity of a capsule is interpolated along its axis from the endpoint velocities.
"""

from dataclasses import dataclass
from typing import NamedTuple

import numpy as np
import taichi as ti

from taichi_cloth.settings import setting


class ContactMode(NamedTuple):
    """A penalty contact's stiff mode for ``dt = "auto"`` and an explicit step's split: each of
    the n = ``contacts`` penalties on one coordinate has stiffness k̂ [1/s²] (per unit mass), a
    dashpot at damping ratio ζ and regularised friction, a damper of rate 2√k̂ in the tangent
    plane (module docstring; docs/physics.md, "Time step"). They add up: n springs make the
    normal mode ω² = n·k̂, n dashpots of rate 2ζ√k̂ give it the ratio ζ·√n, and n friction
    dampers, of rate 2n·√k̂ together, are the mode ω² = n·k̂ at ratio √n. A particle against a
    fixed surface is n = 1; a particle with its shares of the contact samples around it is
    n = Σ w_a·m_s/m_a (``collision``: 6 inside a uniform grid); a pair between two free
    particles of equal mass pushes on their relative coordinate as two contacts. n need not be
    a whole number."""
    stiffness: float
    damping_ratio: float
    contacts: float = 1.0

    @property
    def summed_stiffness(self) -> float:
        """n·k̂ [1/s²], the normal mode's ω²."""
        return self.contacts * self.stiffness

    def oscillators(self) -> tuple[tuple[float, float], tuple[float, float]]:
        """(ω [rad/s], ζ) of the normal mode and of the friction dampers' mode."""
        omega, root = np.sqrt(self.summed_stiffness), np.sqrt(self.contacts)
        return (omega, self.damping_ratio * root), (omega, root)


@dataclass(frozen=True)
class PenaltySettings:
    """The keys every penalty contact effect takes (k̂, ζ, μ and the margin; module docstring);
    an effect's own settings extend them (and may change a default)."""

    stiffness: float = setting(1e5, "float", low=0.0, low_inclusive=False,
                               doc="penalty stiffness per unit particle mass, 1/s²")
    damping: float = setting(0.1, "float", low=0.0, doc="normal damping ratio ζ")
    friction: float = setting(0.5, "float", low=0.0, doc="Coulomb coefficient μ")
    thickness: float = setting(0.005, "float", low=0.0, doc="contact margin off the surface, m")


def closest_points_numpy(x: np.ndarray, a: np.ndarray, b: np.ndarray):
    """For points x (N,3) and segments a, b (C,3): segment parameter s (N,C), closest points
    y (N,C,3) and distances |x − y| (N,C). A degenerate segment (a = b) gives s = 0."""
    axis = b - a
    length_sq = np.einsum("ck,ck->c", axis, axis)
    offset = x[:, None, :] - a[None, :, :]
    safe = np.where(length_sq > 0, length_sq, 1.0)
    s = np.clip(np.einsum("nck,ck->nc", offset, axis) / safe, 0.0, 1.0)
    s = np.where(length_sq > 0, s, 0.0)
    closest = a[None] + s[..., None] * axis[None]
    return s, closest, np.linalg.norm(x[:, None, :] - closest, axis=-1)


def capsule_penetration_depths(x: np.ndarray, a: np.ndarray, b: np.ndarray,
                               radius: np.ndarray) -> np.ndarray:
    """How deep [m] each point of x (P, 3) lies inside the capsule it is deepest in (0 when in
    none), the capsules (a, b) (C, 3) [m] with ``radius`` (C,) [m]: a Taichi kernel over the
    points in float64, each against the capsules whose bounding sphere it is inside (a point on
    the sphere lies where no capsule reaches: depth 0). The metric samples ~10⁴ points a frame.
    It compiles once per process whatever the sizes (NumPy arrays as arguments)."""
    depth = np.zeros(len(x))
    if len(x) and len(a):
        a, b = (np.ascontiguousarray(end, dtype=np.float64) for end in (a, b))
        radius = np.ascontiguousarray(radius, dtype=np.float64)
        reach = 0.5 * np.linalg.norm(b - a, axis=1) + radius
        deepest_in_capsules(np.ascontiguousarray(x, dtype=np.float64), a, b, radius,
                            0.5 * (a + b), reach * reach, depth)
    return depth


@ti.kernel
def deepest_in_capsules(x: ti.types.ndarray(dtype=ti.types.vector(3, ti.f64), ndim=1),
                        a: ti.types.ndarray(dtype=ti.types.vector(3, ti.f64), ndim=1),
                        b: ti.types.ndarray(dtype=ti.types.vector(3, ti.f64), ndim=1),
                        radius: ti.types.ndarray(dtype=ti.f64, ndim=1),
                        centre: ti.types.ndarray(dtype=ti.types.vector(3, ti.f64), ndim=1),
                        reach_sq: ti.types.ndarray(dtype=ti.f64, ndim=1),
                        depth: ti.types.ndarray(dtype=ti.f64, ndim=1)):
    """depth[p] = max(0, max over capsules c of radius[c] − |x[p] − y|), y the point of segment
    a[c]–b[c] closest to x[p] (``closest_on_segment``; a = b a sphere), taken only for the
    capsules whose bounding sphere (``centre``, squared radius ``reach_sq``) holds x[p]."""
    for p in range(x.shape[0]):
        deepest = ti.f64(0.0)
        for c in range(a.shape[0]):
            if (x[p] - centre[c]).norm_sqr() < reach_sq[c]:
                along = closest_on_segment(x[p], a[c], b[c])
                closest = a[c] + along * (b[c] - a[c])
                deepest = ti.max(deepest, radius[c] - (x[p] - closest).norm())
        depth[p] = deepest


@ti.func
def normal_force_magnitude(mass, depth, normal_speed, stiffness, damping_ratio):
    """m·(k̂·d − 2ζ·√k̂·(u·n)), clamped at 0: contact pushes, never pulls [N]."""
    return ti.max(mass * (stiffness * depth - 2 * damping_ratio * ti.sqrt(stiffness) * normal_speed),
                  0.0)


@ti.func
def friction_viscosity(mass, normal_magnitude, slip_speed, stiffness, friction):
    """Regularised Coulomb friction as a viscous coefficient c_t [N·s/m], f_t = −c_t·u_t:
    c_t = min(μ·f_n, 2·m·√k̂·|u_t|) / |u_t| (2·m·√k̂ at zero slip)."""
    limit = 2 * mass * ti.sqrt(stiffness)
    return ti.min(friction * normal_magnitude / ti.max(slip_speed, 1e-30), limit)


@ti.func
def penalty_force(mass, depth, normal, relative_velocity, stiffness, damping_ratio, friction):
    """Normal penalty spring and dashpot plus regularised Coulomb friction (module docstring)."""
    normal_speed = relative_velocity.dot(normal)
    normal_magnitude = normal_force_magnitude(mass, depth, normal_speed, stiffness, damping_ratio)
    slip = relative_velocity - normal_speed * normal
    viscosity = friction_viscosity(mass, normal_magnitude, slip.norm(), stiffness, friction)
    return normal_magnitude * normal - viscosity * slip


@ti.func
def penalty_terms(mass, depth, normal, relative_velocity, stiffness, damping_ratio, friction,
                  real: ti.template()):
    """(``penalty_force`` [N], its normal magnitude f_n [N], ∂f/∂v [N·s/m]) in one evaluation,
    sharing the normal speed, the slip and the friction coefficient. ∂f/∂v is taken with the
    friction coefficient frozen at the current slip: −2ζ·m·√k̂·n·nᵀ − c_t·(I − n·nᵀ). Friction
    then acts implicitly like a damper (an explicit friction of stiffness 2·m·√k̂ would
    overshoot at large steps); negative semi-definite."""
    normal_speed = relative_velocity.dot(normal)
    normal_magnitude = normal_force_magnitude(mass, depth, normal_speed, stiffness, damping_ratio)
    slip = relative_velocity - normal_speed * normal
    viscosity = friction_viscosity(mass, normal_magnitude, slip.norm(), stiffness, friction)
    outer = normal.outer_product(normal)
    identity = ti.Matrix.identity(real, 3)
    damping_block = -2 * damping_ratio * mass * ti.sqrt(stiffness) * outer \
        - viscosity * (identity - outer)
    return normal_magnitude * normal - viscosity * slip, normal_magnitude, damping_block


@ti.func
def penalty_blocks(mass, depth, normal, relative_velocity, curvature, stiffness, damping_ratio,
                   friction, real: ti.template(), definite: ti.template()):
    """(∂f/∂x, ∂f/∂v) of ``penalty_force`` against a surface whose distance function has the
    Hessian ``curvature`` at the point: m·k̂·(−n·nᵀ + d·curvature), the curvature term (positive
    semi-definite for a convex surface) dropped when ``definite``, and ∂f/∂v of ``penalty_terms``.
    Zero while there is no force (d ≤ 0, or the normal force clamped to 0 as the point leaves
    fast: blocks there would make release sticky)."""
    stiffness_block = ti.Matrix.zero(real, 3, 3)
    damping_block = ti.Matrix.zero(real, 3, 3)
    if depth > 0:
        force, normal_magnitude, damping = penalty_terms(mass, depth, normal, relative_velocity,
                                                         stiffness, damping_ratio, friction, real)
        if normal_magnitude > 0:
            stiffness_block = -mass * stiffness * normal.outer_product(normal)
            if ti.static(not definite):
                stiffness_block += mass * stiffness * depth * curvature
            damping_block = damping
    return stiffness_block, damping_block


@ti.func
def closest_on_segment(x, a, b):
    """Parameter s ∈ [0, 1] of the point of segment a–b closest to x (s = 0 when a = b)."""
    axis = b - a
    return ti.min(ti.max((x - a).dot(axis) / ti.max(axis.dot(axis), 1e-30), 0.0), 1.0)
