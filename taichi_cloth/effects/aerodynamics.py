"""Air on the cloth's faces: the pressure of air moving relative to a triangle, shared by drag and
wind (seed §2.3 names the wind force; drag is its still-air part).

A face moving at the mean velocity of its corners through air at velocity w feels the normal
pressure of a flat plate, ½·ρ·C_d·A·(u·n)|u·n|·n with u = w − v_face, and each corner takes a
third of it. Every face is computed once per force evaluation (``FaceAir``), and every particle
gathers over its own triangles (``model.particle_triangle``), so the sum has a fixed order.
"""

import taichi as ti


@ti.func
def cross_components(a: ti.template(), b: ti.template()):
    """a × b of two vectors given as their three components (Taichi scalars, or SIMD_LANES-vectors
    of ``physics.packed_pass``, one triangle per lane), as three components."""
    return (a[1] * b[2] - a[2] * b[1], a[2] * b[0] - a[0] * b[2], a[0] * b[1] - a[1] * b[0])


@ti.func
def unit_normal_and_twice_area(edge_a: ti.template(), edge_b: ti.template()):
    """(n, 2A) of the triangle spanned by edges ``edge_a`` and ``edge_b`` [m], each given as its
    three components: its unit normal n = a × b / |a × b| as three components (0 for a
    degenerate triangle) and twice its area |a × b| [m²]."""
    twice_area_normal = cross_components(edge_a, edge_b)
    twice_area = ti.sqrt(twice_area_normal[0] * twice_area_normal[0]
                         + twice_area_normal[1] * twice_area_normal[1]
                         + twice_area_normal[2] * twice_area_normal[2])
    inverse = 1.0 / ti.max(twice_area, 1e-30)
    n = (twice_area_normal[0] * inverse, twice_area_normal[1] * inverse,
         twice_area_normal[2] * inverse)
    return n, twice_area


@ti.func
def normal_pressure(n: ti.template(), twice_area, air_velocity: ti.template()):
    """A·(u·n)|u·n|·n [m⁴/s²] on a face of unit normal ``n`` and twice its area ``twice_area``
    [m²] from air moving at ``air_velocity`` u relative to it [m/s], n and u given as their
    three components (the components of the result; without the ½ρC_d factor)."""
    u = air_velocity
    normal_speed = u[0] * n[0] + u[1] * n[1] + u[2] * n[2]
    magnitude = 0.5 * twice_area * normal_speed * ti.abs(normal_speed)
    return magnitude * n[0], magnitude * n[1], magnitude * n[2]


@ti.func
def plate_pressure(edge_a: ti.template(), edge_b: ti.template(), air_velocity: ti.template()):
    """The flat plate's pressure on the triangle spanned by edges ``edge_a`` and ``edge_b`` [m]
    from air moving at ``air_velocity`` relative to it [m/s], each given as its three components
    (x, y, z): the components of A·(u·n)|u·n|·n [m⁴/s²] (``normal_pressure``), written with
    N = a × b = 2A·n as ½·(u·N)|u·N|·N / (N·N), which needs no square root (the SIMD lanes of
    ``physics.packed_pass``: one triangle per lane); 0 for a degenerate triangle."""
    u = air_velocity
    twice_area_normal = cross_components(edge_a, edge_b)
    square = twice_area_normal[0] * twice_area_normal[0] \
        + twice_area_normal[1] * twice_area_normal[1] \
        + twice_area_normal[2] * twice_area_normal[2]
    normal_flux = u[0] * twice_area_normal[0] + u[1] * twice_area_normal[1] \
        + u[2] * twice_area_normal[2]
    magnitude = 0.5 * normal_flux * ti.abs(normal_flux) / ti.max(square, 1e-30)
    return magnitude * twice_area_normal[0], magnitude * twice_area_normal[1], \
        magnitude * twice_area_normal[2]


@ti.func
def face_geometry(model, x, i_t):
    """(unit normal n as a vector, twice the area [m²]) of triangle i_t at positions x."""
    tri = model.triangles[i_t]
    n, twice_area = unit_normal_and_twice_area(x[tri[1]] - x[tri[0]], x[tri[2]] - x[tri[0]])
    return ti.Vector([n[0], n[1], n[2]]), twice_area


@ti.func
def face_pressure(normal, twice_area, air_velocity):
    """Aerodynamic force on a face of unit normal ``normal`` and twice its area ``twice_area``
    (``face_geometry``) from air moving at ``air_velocity`` relative to it [N]:
    f = ½·ρ·C_d·A·(u·n)|u·n|·n (``normal_pressure``; u the relative air velocity, A the area).
    Returned without the ½ρC_d factor, which the caller applies. The sign of n cancels, so
    winding does not matter."""
    f_x, f_y, f_z = normal_pressure(normal, twice_area, air_velocity)
    return ti.Vector([f_x, f_y, f_z])


@ti.func
def face_velocity(model, v, i_t):
    tri = model.triangles[i_t]
    return (v[tri[0]] + v[tri[1]] + v[tri[2]]) / 3.0


@ti.func
def face_damping(normal, twice_area, air_velocity):
    """w with −w·n·nᵀ a corner's share of ∂(face pressure)/∂v_corner on a face of unit normal
    ``normal`` and twice its area ``twice_area``: d/du of A·(u·n)|u·n|·n is 2A·|u·n|·n·nᵀ,
    ∂u/∂v_corner = −I/3 and a corner gets a third of the face's force, so w = (2/9)·A·|u·n|
    [m³/s] (without the ½ρC_d factor; the normal's rotation left out)."""
    return (1.0 / 9.0) * twice_area * ti.abs(air_velocity.dot(normal))


@ti.data_oriented
class FaceAir:
    """The air's force on every face, computed once per force evaluation by an effect's
    ``prepare`` (``store``), and each particle's share of its faces' (in the fixed order of
    ``model.particle_triangle``): ``force`` A·(u·n)|u·n|·n [m⁴/s²] and, where the integrator
    solves with Jacobians (``keeps_blocks``), the face's unit ``normal`` and ``face_damping``
    weight [m³/s], all without the ½ρC_d factor. Instead of every particle computing its six
    faces (each face three times)."""

    def __init__(self, model, keeps_blocks: bool):
        faces = max(1, model.triangle_count)
        self.force = ti.Vector.field(3, model.real, faces)
        self.keeps_blocks = keeps_blocks
        if keeps_blocks:
            self.normal = ti.Vector.field(3, model.real, faces)
            self.weight = ti.field(model.real, faces)

    @ti.func
    def store(self, i_t, force, normal, weight):
        """Face i_t's force, and (``keeps_blocks``) its normal and damping weight."""
        self.force[i_t] = force
        if ti.static(self.keeps_blocks):
            self.normal[i_t] = normal
            self.weight[i_t] = weight

    @ti.func
    def particle_force(self, model, i_p, factor):
        """A third of the force of each face of particle i_p, times ``factor`` (½ρC_d) [N]."""
        f = ti.Vector.zero(model.real, 3)
        for k in range(model.particle_triangle_start[i_p], model.particle_triangle_start[i_p + 1]):
            f += self.force[model.particle_triangle[k]]
        return factor / 3.0 * f

    @ti.func
    def particle_damping(self, model, i_p, factor, definite: ti.template()):
        """∂f_i/∂v_i = −factor·Σ w·n·nᵀ over the faces of particle i_p [N·s/m]; ``definite``
        drops a face with w < 0, so the block stays negative semi-definite."""
        ti.static_assert(self.keeps_blocks, "the faces' blocks were not asked for "
                                            "(EffectContext.needs_jacobian)")
        damping = ti.Matrix.zero(model.real, 3, 3)
        for k in range(model.particle_triangle_start[i_p], model.particle_triangle_start[i_p + 1]):
            i_t = model.particle_triangle[k]
            weight = self.weight[i_t]
            if ti.static(definite):
                weight = ti.max(weight, 0.0)
            normal = self.normal[i_t]
            damping -= weight * normal.outer_product(normal)
        return factor * damping
