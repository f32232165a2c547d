"""Wind (seed §2.3, f_wind: strength α, azimuth β, elevation γ) with travelling gusts.

Each face's force is computed once per force evaluation (``prepare``, ``aerodynamics.FaceAir``),
with the wind at the face's centroid, and each particle gathers a third of its faces'; so are
the faces' damping blocks for the implicit solver."""

import math
from dataclasses import dataclass

import taichi as ti

from taichi_cloth.effects.aerodynamics import (FaceAir, face_damping, face_geometry,
                                               face_pressure, face_velocity)
from taichi_cloth.effects.base import Effect, EffectContext
from taichi_cloth.settings import setting


@dataclass(frozen=True)
class WindSettings:
    strength: float = setting(3.0, "float", low=0.0, doc="alpha: wind speed, m/s")
    azimuth: float = setting(0.0, "float", low=-360.0, high=360.0,
                             doc="beta: degrees from +x towards +z")
    elevation: float = setting(0.0, "float", low=-90.0, high=90.0,
                               doc="gamma: degrees above the horizontal")
    gusts: float = setting(0.0, "float", low=0.0, high=1.0, doc="relative gust amplitude")
    gust_frequency: float = setting(0.5, "float", low=0.0, low_inclusive=False, doc="Hz")
    coefficient: float = setting(1.0, "float", low=0.0, doc="pressure coefficient C_d of a face")
    air_density: float = setting(1.2, "float", low=0.0, doc="kg/m³")


@ti.data_oriented
class Wind(Effect):
    """What moving air adds to still-air drag, through each face's normal [N].

    Seed §2.3 gives the wind by strength α, azimuth β and elevation γ; here its velocity is
    w = α·(1 + gusts·s(τ))·(cos γ cos β, sin γ, cos γ sin β) [m/s], β from +x towards +z, γ above
    the horizontal. s ∈ [−1, 1] is a sum of three sines at incommensurate multiples of the gust
    frequency, evaluated at τ = t − (x·d)/α so gusts travel downwind with the air (x the face's
    centroid). The force on a face is P(w − v_face) − P(−v_face), P the face pressure
    (``face_pressure``): with ``drag`` also declared the total is the pressure of the relative
    air velocity, and α = 0 adds nothing.
    """

    name = "wind"
    Settings = WindSettings
    has_jacobian = True

    def __init__(self, settings: WindSettings, context: EffectContext):
        super().__init__(settings, context)
        azimuth, elevation = math.radians(settings.azimuth), math.radians(settings.elevation)
        self.direction = (math.cos(elevation) * math.cos(azimuth), math.sin(elevation),
                          math.cos(elevation) * math.sin(azimuth))
        self.strength = settings.strength
        self.gusts = settings.gusts
        self.angular_frequency = 2.0 * math.pi * settings.gust_frequency
        self.travel_speed = max(settings.strength, 0.1)
        self.factor = 0.5 * settings.air_density * settings.coefficient
        self.model = context.model
        self.faces = FaceAir(context.model, context.needs_jacobian)

    @ti.func
    def gust(self, tau):
        """s(τ) ∈ [−1, 1]."""
        w = self.angular_frequency  # the shape of the gusts; f32 constants are precise enough
        return (ti.sin(w * tau) + 0.5 * ti.sin(2.3 * w * tau + 1.3)
                + 0.25 * ti.sin(4.7 * w * tau + 0.7)) / 1.75

    @ti.func
    def velocity(self, model, position, t):
        """The wind's velocity w [m/s] at ``position`` [m] and time t [s]."""
        direction = ti.Vector([model.real(c) for c in ti.static(self.direction)])
        tau = t - position.dot(direction) / model.real(self.travel_speed)
        gust_factor = 1.0 + model.real(self.gusts) * self.gust(tau)
        return model.real(self.strength) * gust_factor * direction

    @ti.func
    def prepare(self, x, v, t):
        """Every face's P(w − v_face) − P(−v_face), once, and the difference of the two
        ``face_damping`` weights for the implicit solver, with w at the face's centroid."""
        model = self.model
        time = ti.cast(t, model.real)
        for i_t in range(model.triangle_count):
            tri = model.triangles[i_t]
            centroid = (x[tri[0]] + x[tri[1]] + x[tri[2]]) / 3.0
            still = -face_velocity(model, v, i_t)
            moving = self.velocity(model, centroid, time) + still
            normal, twice_area = face_geometry(model, x, i_t)
            self.faces.store(
                i_t, face_pressure(normal, twice_area, moving)
                - face_pressure(normal, twice_area, still), normal,
                face_damping(normal, twice_area, moving) - face_damping(normal, twice_area, still))

    @ti.func
    def local_jacobian(self, model, x, v, i_p, t, definite: ti.template()):
        """(0, ∂f/∂v_i) of P(w − v) − P(−v) (after ``prepare``): the ``face_damping`` of the
        moving air minus that of still air. The difference is negative where the cloth outruns
        the wind; ``definite`` drops those faces, so the block stays negative semi-definite."""
        return ti.Matrix.zero(model.real, 3, 3), self.faces.particle_damping(
            model, i_p, model.real(self.factor), definite)

    @ti.func
    def force(self, model, x, v, i_p, t):
        """A third of each of the particle's faces' force (after ``prepare``)."""
        return self.faces.particle_force(model, i_p, model.real(self.factor))
