"""Contact with the ground plane: the penalty force of ``penalty`` against y = height."""

from dataclasses import dataclass

import numpy as np
import taichi as ti

from taichi_cloth.effects.base import Effect
from taichi_cloth.effects.penalty import (ContactMode, PenaltySettings, penalty_blocks,
                                          penalty_force)
from taichi_cloth.settings import setting


@dataclass(frozen=True)
class GroundSettings(PenaltySettings):
    height: float = setting(0.0, "float", doc="y of the ground plane, m")


@ti.data_oriented
class GroundContact(Effect):
    """Penalty contact with the plane y = height (plus margin), at rest."""

    name = "ground"
    Settings = GroundSettings
    has_jacobian = True

    def __init__(self, settings: GroundSettings, context=None):
        super().__init__(settings, context)
        config = settings
        self.height = config.height
        self.surface_height = config.height + config.thickness
        self.stiffness, self.damping_ratio = config.stiffness, config.damping
        self.friction = config.friction

    def penetration_depths(self, points: np.ndarray) -> np.ndarray:
        """Metres below the plane (without the margin)."""
        return np.maximum(self.height - points[:, 1], 0.0)

    @ti.func
    def force(self, model, x, v, i_p, t):
        real = model.real
        depth = real(self.surface_height) - x[i_p][1]
        f = ti.Vector.zero(real, 3)
        if depth > 0:
            f = penalty_force(model.particle_mass[i_p], depth, ti.Vector([0.0, 1.0, 0.0], dt=real),
                              v[i_p], real(self.stiffness), real(self.damping_ratio),
                              real(self.friction))
        return f

    @ti.func
    def local_jacobian(self, model, x, v, i_p, t, definite: ti.template()):
        """(∂f/∂x, ∂f/∂v) of the penalty (``penalty_blocks``): −m·k̂·e_y·e_yᵀ, exact for a plane
        (no curvature), and the damping block."""
        real = model.real
        return penalty_blocks(model.particle_mass[i_p], real(self.surface_height) - x[i_p][1],
                              ti.Vector([0.0, 1.0, 0.0], dt=real), v[i_p],
                              ti.Matrix.zero(real, 3, 3), real(self.stiffness),
                              real(self.damping_ratio), real(self.friction), real, True)

    def stability_modes(self) -> list[ContactMode]:
        return [ContactMode(self.stiffness, self.damping_ratio)]
