"""Gravity (seed §2.3, f_gravity): f = m_i·g, g pointing down (−y) [N]."""

from dataclasses import dataclass

import numpy as np
import taichi as ti

from taichi_cloth.effects.base import Effect
from taichi_cloth.settings import setting


@dataclass(frozen=True)
class GravitySettings:
    g: float = setting(9.81, "float", low=0.0, doc="m/s², pointing down (−y)")


@ti.data_oriented
class Gravity(Effect):
    name = "gravity"
    Settings = GravitySettings

    def __init__(self, settings: GravitySettings, context=None):
        super().__init__(settings, context)
        self.g = settings.g
        self.uniform_acceleration = (0.0, -settings.g, 0.0)  # the same for every particle [m/s²]

    @ti.func
    def force(self, model, x, v, i_p, t):
        return ti.Vector([0.0, -model.real(self.g), 0.0]) * model.particle_mass[i_p]

    def potential_energy(self, x: np.ndarray, mass: np.ndarray) -> float:
        """Σ m_i·g·y_i [J]."""
        return self.g * float(np.sum(mass * x[:, 1]))
