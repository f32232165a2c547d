"""Contact with a flat round support: a solid plate (a disc of radius R and thickness T whose top
face lies at y = height), the penalty force of ``penalty`` on its surface plus the margin.

The drape tester's support disc (ISO 9073-9) and any round table: a capsule cannot make a flat
top, and a ground plane has no edge for cloth to fall over. In the plane of the radial distance
r = |(x − c_x, z − c_z)| and the height y the plate is the rectangle [0, R] × [height − T, height],
so its signed distance (negative inside) is a 2-D box's (Quilez, "2D distance functions"):

    d_r = r − R,  d_y = max(y − height, height − T − y),
    s = |(max(d_r, 0), max(d_y, 0))| + min(max(d_r, d_y), 0).

With depth = margin − s > 0 the force is ``penalty_force`` along n = ∇s (up on the top face,
outward on the rim and the side, round the edge between them: the plate plus the margin is
smooth). Its stiffness Jacobian is m·k̂·(−n·nᵀ + depth·∇²s): ∇²s is 0 on the faces, t·tᵀ/r on
the side and m_q·m_qᵀ/|q| + (d_r/|q|)·t·tᵀ/r round the edge (q = (d_r, d_y), m_q the unit vector
across q in the (r, y) plane, t the tangent of the circle); that curvature term is positive
semi-definite and ``definite`` drops it (as for the capsules).

A point inside is pushed out through the nearest face, so cloth driven past the plate's mid-plane
within one step leaves through the bottom: the plate's thickness bounds how fast cloth may hit it
(about T/(2h)), and a start out of contact can fall through in a backward Euler step, which
linearises contact where the step begins (docs/physics.md).
"""

from dataclasses import dataclass

import numpy as np
import taichi as ti

from taichi_cloth.effects.base import Effect
from taichi_cloth.effects.penalty import (ContactMode, PenaltySettings, penalty_blocks,
                                          penalty_force)
from taichi_cloth.settings import setting


@dataclass(frozen=True)
class SupportSettings(PenaltySettings):
    thickness: float = setting(0.002, "float", low=0.0, doc="contact margin around the plate, m")
    height: float = setting(0.5, "float", doc="y of the plate's top face, m")
    radius: float = setting(0.09, "float", low=0.0, low_inclusive=False, doc="plate radius, m")
    centre: tuple = setting([0.0, 0.0], "float_list", length=2,
                            doc="[x, z] of the plate's axis, m")
    plate_thickness: float = setting(0.02, "float", low=0.0, low_inclusive=False,
                                     doc="the plate's own thickness T, m (cloth pushed past "
                                         "its mid-plane within a step comes out below)")


@ti.data_oriented
class SupportContact(Effect):
    """Penalty contact with a static solid round plate (module docstring)."""

    name = "support"
    Settings = SupportSettings
    has_jacobian = True

    def __init__(self, settings: SupportSettings, context=None):
        super().__init__(settings, context)
        self.height, self.radius = settings.height, settings.radius
        self.centre_x, self.centre_z = (float(value) for value in settings.centre)
        self.plate_thickness, self.margin = settings.plate_thickness, settings.thickness
        self.stiffness, self.damping_ratio = settings.stiffness, settings.damping
        self.friction = settings.friction

    def signed_distances(self, points: np.ndarray) -> np.ndarray:
        """s [m] of each point (N, 3): its distance to the plate, negative inside."""
        radial = np.hypot(points[:, 0] - self.centre_x, points[:, 2] - self.centre_z)
        beyond_rim = radial - self.radius
        beyond_face = np.maximum(points[:, 1] - self.height,
                                 self.height - self.plate_thickness - points[:, 1])
        outside = np.hypot(np.maximum(beyond_rim, 0.0), np.maximum(beyond_face, 0.0))
        return outside + np.minimum(np.maximum(beyond_rim, beyond_face), 0.0)

    def penetration_depths(self, points: np.ndarray) -> np.ndarray:
        """Metres inside the plate (without the margin)."""
        return np.maximum(-self.signed_distances(points), 0.0)

    @ti.func
    def probe(self, p, real: ti.template()):
        """(s, n = ∇s, curvature ∇²s) of the plate at point p (module docstring), in ``real``."""
        radial = ti.Vector([p[0] - real(self.centre_x), 0.0, p[2] - real(self.centre_z)], dt=real)
        r = ti.max(radial.norm(), real(1e-30))
        e_r = radial / r
        e_y = ti.Vector([0.0, 1.0, 0.0], dt=real)
        tangent = e_y.cross(e_r)
        beyond_rim = r - real(self.radius)
        above = p[1] - real(self.height)
        below = real(self.height - self.plate_thickness) - p[1]
        side = real(1.0)  # which face is nearer vertically: +1 the top, −1 the bottom
        beyond_face = above
        if below > above:
            side, beyond_face = real(-1.0), below
        s = real(0.0)
        n = ti.Vector.zero(real, 3)
        curvature = ti.Matrix.zero(real, 3, 3)
        wall = tangent.outer_product(tangent) / r  # ∇²r
        if beyond_rim > 0 and beyond_face > 0:  # round the edge
            s = ti.sqrt(beyond_rim * beyond_rim + beyond_face * beyond_face)
            n = (beyond_rim * e_r + side * beyond_face * e_y) / s
            across = (-side * beyond_face * e_r + beyond_rim * e_y) / s
            curvature = across.outer_product(across) / s + beyond_rim / s * wall
        elif beyond_rim > beyond_face:  # the side (outside or inside)
            s = beyond_rim
            n = e_r
            curvature = wall
        else:  # a face
            s = beyond_face
            n = side * e_y
        return s, n, curvature

    @ti.func
    def force(self, model, x, v, i_p, t):
        real = model.real
        s, n, _ = self.probe(x[i_p], real)
        depth = real(self.margin) - s
        f = ti.Vector.zero(real, 3)
        if depth > 0:
            f = penalty_force(model.particle_mass[i_p], depth, n, v[i_p], real(self.stiffness),
                              real(self.damping_ratio), real(self.friction))
        return f

    @ti.func
    def local_jacobian(self, model, x, v, i_p, t, definite: ti.template()):
        """(∂f/∂x, ∂f/∂v) of the penalty (``penalty_blocks``): m·k̂·(−n·nᵀ + depth·∇²s), the
        curvature term dropped when ``definite``, and the damping block."""
        real = model.real
        s, n, curvature = self.probe(x[i_p], real)
        return penalty_blocks(model.particle_mass[i_p], real(self.margin) - s, n, v[i_p],
                              curvature, real(self.stiffness), real(self.damping_ratio),
                              real(self.friction), real, definite)

    def stability_modes(self) -> list[ContactMode]:
        return [ContactMode(self.stiffness, self.damping_ratio)]
