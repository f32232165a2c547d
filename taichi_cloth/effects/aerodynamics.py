"""Air on the cloth's faces: the pressure of air moving relative to a triangle, shared by drag and
wind (seed §2.3 names the wind force; drag is its still-air part).

A face moving at the mean velocity of its corners through air at velocity w feels the normal
pressure of a flat plate, ½·ρ·C_d·A·(u·n)|u·n|·n with u = w − v_face, and each corner takes a
third of it. Every particle gathers over its own triangles (``model.particle_triangle``), so the
sum has a fixed order.
"""

import taichi as ti


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
