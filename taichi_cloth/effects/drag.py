"""Still-air drag: the face pressure (``aerodynamics``) of air at rest on each moving face.

Each face's pressure is computed once per force evaluation (``prepare``: its normal, area and
mean velocity), and each particle gathers a third of its faces' (in the fixed order of
``model.particle_triangle``), instead of every particle recomputing its six faces; so are the
faces' damping blocks for the implicit solver (``local_jacobian``), where it asks for them. On a
packed grid cloth the SIMD pass does the same in lanes (``lane_faces``,
``physics.packed_grid``)."""

from dataclasses import dataclass

import taichi as ti

from taichi_cloth.effects.aerodynamics import (FaceAir, face_damping, face_geometry,
                                               face_pressure, face_velocity)
from taichi_cloth.effects.base import Effect, EffectContext
from taichi_cloth.settings import setting


@dataclass(frozen=True)
class DragSettings:
    coefficient: float = setting(1.0, "float", low=0.0, doc="drag coefficient C_d of a face")
    air_density: float = setting(1.2, "float", low=0.0, doc="kg/m³")


@ti.data_oriented
class Drag(Effect):
    """Still-air drag through each face: the pressure of air at rest on a face moving at the
    mean velocity of its corners, a third to each corner [N]."""

    name = "drag"
    Settings = DragSettings
    has_jacobian = True  # drag is stiff on light cloth: the implicit solver treats it so
    lane_faces = True  # a grid cloth's SIMD pass can compute its faces (``face_air``)

    def __init__(self, settings: DragSettings, context: EffectContext):
        super().__init__(settings, context)
        self.face_factor = 0.5 * settings.air_density * settings.coefficient  # ½ρC_d [kg/m³]
        self.model = context.model
        self.faces = FaceAir(context.model, context.needs_jacobian)

    @ti.func
    def prepare(self, x, v, t):
        """Every face's pressure of still air, once (and its damping, for the implicit
        solver)."""
        model = self.model
        for i_t in range(model.triangle_count):
            air = self._air(model, v, i_t)
            normal, twice_area = face_geometry(model, x, i_t)
            self.faces.store(i_t, face_pressure(normal, twice_area, air), normal,
                             face_damping(normal, twice_area, air))

    @ti.func
    def face_air(self, face_velocity: ti.template()):
        """Still air relative to a face moving at ``face_velocity`` (components) [m/s]."""
        return -face_velocity[0], -face_velocity[1], -face_velocity[2]

    @ti.func
    def _air(self, model, v, i_t):
        """``face_air`` of triangle i_t as a vector [m/s]."""
        return ti.Vector(self.face_air(face_velocity(model, v, i_t)))

    @ti.func
    def force(self, model, x, v, i_p, t):
        """A third of the pressure of each of the particle's faces (after ``prepare``)."""
        return self.faces.particle_force(model, i_p, model.real(self.face_factor))

    @ti.func
    def local_jacobian(self, model, x, v, i_p, t, definite: ti.template()):
        """(0, ∂f/∂v_i): the faces' ``face_damping`` for still air (after ``prepare``),
        negative semi-definite. Explicit quadratic drag overshoots at large steps on light cloth
        (h·ρ_air·C_d·|u|/ρ_cloth > 2 in a gale)."""
        return ti.Matrix.zero(model.real, 3, 3), self.faces.particle_damping(
            model, i_p, model.real(self.face_factor), definite)
