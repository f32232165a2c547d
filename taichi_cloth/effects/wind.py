"""Wind (seed §2.3, f_wind: strength α, azimuth β, elevation γ) with travelling gusts."""

import math
from dataclasses import dataclass

import taichi as ti

from taichi_cloth.effects.aerodynamics import face_damping, face_pressure, face_velocity
from taichi_cloth.effects.base import Effect
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
    frequency, evaluated at τ = t − (x·d)/α so gusts travel downwind with the air. The force on a
    face is P(w − v_face) − P(−v_face), P the face pressure (``face_pressure``): with ``drag``
    also declared the total is the pressure of the relative air velocity, and α = 0 adds nothing.
    """

    name = "wind"
    Settings = WindSettings
    has_jacobian = True

    def __init__(self, settings: WindSettings, context=None):
        super().__init__(settings, context)
        azimuth, elevation = math.radians(settings.azimuth), math.radians(settings.elevation)
        self.direction = (math.cos(elevation) * math.cos(azimuth), math.sin(elevation),
                          math.cos(elevation) * math.sin(azimuth))
        self.strength = settings.strength
        self.gusts = settings.gusts
        self.angular_frequency = 2.0 * math.pi * settings.gust_frequency
        self.travel_speed = max(settings.strength, 0.1)
        self.factor = 0.5 * settings.air_density * settings.coefficient

    @ti.func
    def gust(self, tau):
        """s(τ) ∈ [−1, 1]."""
        w = self.angular_frequency  # the shape of the gusts; f32 constants are precise enough
        return (ti.sin(w * tau) + 0.5 * ti.sin(2.3 * w * tau + 1.3)
                + 0.25 * ti.sin(4.7 * w * tau + 0.7)) / 1.75

    @ti.func
    def velocity(self, model, x, i_p, t):
        """The wind's velocity w [m/s] at particle i_p and time t."""
        direction = ti.Vector([model.real(c) for c in ti.static(self.direction)])
        tau = t - x[i_p].dot(direction) / model.real(self.travel_speed)
        gust_factor = 1.0 + model.real(self.gusts) * self.gust(tau)
        return model.real(self.strength) * gust_factor * direction

    @ti.func
    def local_jacobian(self, model, x, v, i_p, t, definite: ti.template()):
        """(0, ∂f/∂v_i) of P(w − v) − P(−v): the ``face_damping`` of the moving air minus that of
        still air. The difference is positive where the cloth outruns the wind; ``definite``
        drops those faces, so the block stays negative semi-definite."""
        wind = self.velocity(model, x, i_p, t)
        damping = ti.Matrix.zero(model.real, 3, 3)
        for k in range(model.particle_triangle_start[i_p], model.particle_triangle_start[i_p + 1]):
            i_t = model.particle_triangle[k]
            face = face_velocity(model, v, i_t)
            normal, moving = face_damping(model, x, i_t, wind - face)
            _, still = face_damping(model, x, i_t, -face)
            weight = moving - still
            if ti.static(definite):
                weight = ti.max(weight, 0.0)
            damping -= weight * normal.outer_product(normal)
        return ti.Matrix.zero(model.real, 3, 3), model.real(self.factor) * damping

    @ti.func
    def force(self, model, x, v, i_p, t):
        wind = self.velocity(model, x, i_p, t)
        f = ti.Vector.zero(model.real, 3)
        for k in range(model.particle_triangle_start[i_p], model.particle_triangle_start[i_p + 1]):
            i_t = model.particle_triangle[k]
            face = face_velocity(model, v, i_t)
            f += face_pressure(model, x, i_t, wind - face) - face_pressure(model, x, i_t, -face)
        return model.real(self.factor) / 3.0 * f
