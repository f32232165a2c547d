"""Air on the cloth's faces: the pressure of air moving relative to a triangle, shared by drag and
wind (seed §2.3 names the wind force; drag is its still-air part).

A face moving at the mean velocity of its corners through air at velocity w feels the normal
pressure of a flat plate, ½·ρ·C_d·A·(u·n)|u·n|·n with u = w − v_face, and each corner takes a
third of it. Every particle gathers over its own triangles (``model.particle_triangle``), so the
sum has a fixed order.
"""

import taichi as ti


@ti.func
def unit_normal_and_twice_area(edge_a: ti.template(), edge_b: ti.template()):
    """(n, 2A) of the triangle spanned by edges ``edge_a`` and ``edge_b`` [m], each given as its
    three components: its unit normal n = a × b / |a × b| as three components (0 for a
    degenerate triangle) and twice its area |a × b| [m²]. On components, so that one formula
    serves a Taichi vector's components and the SIMD lanes of ``physics.packed_grid``
    (SIMD_LANES-vectors, one triangle per lane)."""
    a, b = edge_a, edge_b
    twice_area_normal = (a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2],
                         a[0] * b[1] - a[1] * b[0])
    twice_area = ti.sqrt(twice_area_normal[0] * twice_area_normal[0]
                         + twice_area_normal[1] * twice_area_normal[1]
                         + twice_area_normal[2] * twice_area_normal[2])
    inverse = 1.0 / ti.max(twice_area, 1e-30)
    n = (twice_area_normal[0] * inverse, twice_area_normal[1] * inverse,
         twice_area_normal[2] * inverse)
    return n, twice_area


@ti.func
def plate_pressure(edge_a: ti.template(), edge_b: ti.template(), air_velocity: ti.template()):
    """The flat plate's pressure on the triangle spanned by edges ``edge_a`` and ``edge_b`` [m]
    from air moving at ``air_velocity`` relative to it [m/s], each given as its three components
    (x, y, z): the components of A·(u·n)|u·n|·n [m⁴/s²] (without the ½ρC_d factor; 0 for a
    degenerate triangle), on components as ``unit_normal_and_twice_area``."""
    u = air_velocity
    n, twice_area = unit_normal_and_twice_area(edge_a, edge_b)
    normal_speed = u[0] * n[0] + u[1] * n[1] + u[2] * n[2]
    magnitude = 0.5 * twice_area * normal_speed * ti.abs(normal_speed)
    return magnitude * n[0], magnitude * n[1], magnitude * n[2]


@ti.func
def face_pressure(model, x, i_t, air_velocity):
    """Aerodynamic force on triangle i_t from air moving at ``air_velocity`` relative to it [N]:
    f = ½·ρ·C_d·A·(u·n)|u·n|·n (``plate_pressure``; u the relative air velocity, n the unit
    normal, A the area). Returned without the ½ρC_d factor, which the caller applies. The sign of
    n cancels, so winding does not matter."""
    tri = model.triangles[i_t]
    edge_a, edge_b = x[tri[1]] - x[tri[0]], x[tri[2]] - x[tri[0]]
    f_x, f_y, f_z = plate_pressure(edge_a, edge_b, air_velocity)
    return ti.Vector([f_x, f_y, f_z])


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
    n, twice_area = unit_normal_and_twice_area(x[tri[1]] - x[tri[0]], x[tri[2]] - x[tri[0]])
    normal = ti.Vector([n[0], n[1], n[2]])
    return normal, (1.0 / 9.0) * twice_area * ti.abs(air_velocity.dot(normal))
