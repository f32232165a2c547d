"""Spring dashpots (seed §2.3, f_damper): every spring i–j gets a damper along it,
f_i = c·((v_j − v_i)·n)·n with c = scale·β·k [N·s/m] (Rayleigh damping, β the material's damping
time [s], k the spring's stiffness). It acts inside the spring pass, where n is at hand
(``physics.forces``), so it has no per-particle force of its own: it sets the model's dashpots."""

from dataclasses import dataclass

import taichi as ti

from taichi_cloth.effects.base import Effect
from taichi_cloth.settings import setting


@dataclass(frozen=True)
class DampingSettings:
    scale: float = setting(1.0, "float", low=0.0, doc="multiplies the material's damping time")


@ti.data_oriented
class Damping(Effect):
    name = "damping"
    Settings = DampingSettings
    has_force = False

    @staticmethod
    def model_options(settings: DampingSettings) -> dict:
        return {"damping_scale": settings.scale}
