"""Optional force effects, each an object with a ``@ti.func force(...)``.

The force evaluation (``forces.py``) sums the scene's list of effects with ``ti.static``
unrolling, so an effect the scene does not declare emits no code at all (DESIGN.md, promise 3;
the pattern of Genesis' ``force_fields.py``). Every value an effect reads that is fixed for the
run (g, wind speed, coefficients) is baked in at compile time, as ``model.real(value)`` so that it
keeps the model's precision (a bare Python float would be baked as f32); the time t is a kernel
argument.

Seed §2.3: F_i = f_gravity + f_damper + f_stretch + f_wind. The dampers live with the springs
(``forces.py``); gravity and wind are here, with air drag, the ground and body contact.
"""

import math

import taichi as ti

from taichi_cloth.config.scene import DragEffect, GravityEffect, WindEffect


@ti.data_oriented
class Gravity:
    """f = m_i · g, g pointing down (−y) [N]."""

    name = "gravity"

    def __init__(self, config: GravityEffect):
        self.g = config.g
        self.uniform_acceleration = (0.0, -config.g, 0.0)  # the same for every particle [m/s²]

    @ti.func
    def force(self, model, x, v, i_p, t):
        return ti.Vector([0.0, -model.real(self.g), 0.0]) * model.particle_mass[i_p]


@ti.func
def face_pressure(model, x, i_t, air_velocity):
    """Aerodynamic force on triangle i_t from air moving at ``air_velocity`` relative to it [N]:
    f = ½·ρ·C_d·A·(u·n)|u·n|·n (a flat plate's normal pressure; u the relative air velocity,
    n the unit normal, A the area). Returned without the ½ρC_d factor, which the caller applies.
    The sign of n cancels, so winding does not matter."""
    tri = model.triangles[i_t]
    twice_area_normal = (x[tri[1]] - x[tri[0]]).cross(x[tri[2]] - x[tri[0]])
    twice_area = twice_area_normal.norm()
    result = ti.Vector.zero(model.real, 3)
    if twice_area > 0:
        normal = twice_area_normal / twice_area
        normal_speed = air_velocity.dot(normal)
        result = 0.5 * twice_area * normal_speed * ti.abs(normal_speed) * normal
    return result


@ti.func
def face_velocity(model, v, i_t):
    tri = model.triangles[i_t]
    return (v[tri[0]] + v[tri[1]] + v[tri[2]]) / 3.0


@ti.func
def face_damping(model, x, i_t, air_velocity):
    """(n, w) with −w·n·nᵀ a corner's share of ∂(face pressure)/∂v_corner: d/du of
    A·(u·n)|u·n|·n is 2A·|u·n|·n·nᵀ, ∂u/∂v_corner = −I/3 and a corner gets a third of the face's
    force, so w = (2/9)·A·|u·n| (without the ½ρC_d factor; the normal's rotation left out)."""
    tri = model.triangles[i_t]
    twice_area_normal = (x[tri[1]] - x[tri[0]]).cross(x[tri[2]] - x[tri[0]])
    twice_area = twice_area_normal.norm()
    normal = twice_area_normal / ti.max(twice_area, 1e-30)
    return normal, (1.0 / 9.0) * twice_area * ti.abs(air_velocity.dot(normal))


@ti.data_oriented
class Drag:
    """Still-air drag through each face: the pressure of air at rest on a face moving at the
    mean velocity of its corners, a third to each corner [N]."""

    name = "drag"
    has_local_jacobian = True  # drag is stiff on light cloth: the implicit solver treats it so

    def __init__(self, config: DragEffect):
        self.factor = 0.5 * config.air_density * config.coefficient

    @ti.func
    def force(self, model, x, v, i_p, t):
        f = ti.Vector.zero(model.real, 3)
        for k in range(model.particle_triangle_start[i_p], model.particle_triangle_start[i_p + 1]):
            i_t = model.particle_triangle[k]
            f += face_pressure(model, x, i_t, -face_velocity(model, v, i_t))
        return model.real(self.factor) / 3.0 * f

    @ti.func
    def local_jacobian(self, model, x, v, i_p, t, definite: ti.template()):
        """(0, ∂f/∂v_i): the faces' ``face_damping`` for still air, negative semi-definite.
        Explicit quadratic drag overshoots at large steps on light cloth
        (h·ρ_air·C_d·|u|/ρ_cloth > 2 in a gale)."""
        damping = ti.Matrix.zero(model.real, 3, 3)
        for k in range(model.particle_triangle_start[i_p], model.particle_triangle_start[i_p + 1]):
            i_t = model.particle_triangle[k]
            normal, weight = face_damping(model, x, i_t, -face_velocity(model, v, i_t))
            damping -= weight * normal.outer_product(normal)
        return ti.Matrix.zero(model.real, 3, 3), model.real(self.factor) * damping


@ti.data_oriented
class Wind:
    """What moving air adds to still-air drag, through each face's normal [N].

    Seed §2.3 gives the wind by strength α, azimuth β and elevation γ; here its velocity is
    w = α·(1 + gusts·s(τ))·(cos γ cos β, sin γ, cos γ sin β) [m/s], β from +x towards +z, γ above
    the horizontal. s ∈ [−1, 1] is a sum of three sines at incommensurate multiples of the gust
    frequency, evaluated at τ = t − (x·d)/α so gusts travel downwind with the air. The force on a
    face is P(w − v_face) − P(−v_face), P the face pressure (``face_pressure``): with ``drag``
    also declared the total is the pressure of the relative air velocity, and α = 0 adds nothing.
    """

    name = "wind"
    has_local_jacobian = True

    def __init__(self, config: WindEffect):
        azimuth, elevation = math.radians(config.azimuth), math.radians(config.elevation)
        self.direction = (math.cos(elevation) * math.cos(azimuth), math.sin(elevation),
                          math.cos(elevation) * math.sin(azimuth))
        self.strength = config.strength
        self.gusts = config.gusts
        self.angular_frequency = 2.0 * math.pi * config.gust_frequency
        self.travel_speed = max(config.strength, 0.1)
        self.factor = 0.5 * config.air_density * config.coefficient

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
