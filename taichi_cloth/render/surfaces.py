"""Triangle surfaces to draw and export: the cloth as a smooth, textured render mesh, the body as
capsule meshes, the floor. Each is built once in NumPy into f32 Taichi fields (vertices [m], unit
normals, colours in [0, 1], flat triangle indices) that a kernel updates per frame; none of them
touches the simulation.

Cloth: a grid garment's particles are refined ``subdivision`` times per spacing by a tensor-product
Catmull-Rom spline, p(s, t) = Σ_a Σ_b w_a(t) w_b(s) x[row + a, column + b] over the 4 × 4
surrounding particles, with
    w_−1 = (−s³ + 2s² − s)/2, w_0 = (3s³ − 5s² + 2)/2, w_1 = (−3s³ + 4s² + s)/2, w_2 = (s³ − s²)/2,
which passes through every particle and is C¹ between them (columns wrap on a skirt; at an open
edge the end particle is repeated). Normals are gathered per vertex as the sum of the adjacent
triangles' area-weighted normals ½ (p1 − p0) × (p2 − p0), normalised. UVs are linear in the grid,
as the garment's are, so the texture sampled at them moves with the fabric. A mesh garment (from a
file) is drawn as its own triangles, with its own UVs.

Body: one unit capsule template, directions n on the unit sphere and an end flag s ∈ {0, 1}
(hemisphere at a or at b), placed per capsule as p = a + s (b − a) + r F n with F an orthonormal
frame whose third axis is (b − a)/|b − a|; the normal is F n.
"""

import numpy as np
import taichi as ti

from taichi_cloth.body.capsules import DISPLAY_CAPSULE_NAMES
from taichi_cloth.cloth.garment import Garment
from taichi_cloth.cloth.topology import grid_triangles
from taichi_cloth.gather import triangle_gather_lists
from taichi_cloth.uploads import UploadBatch

CAPSULE_SEGMENTS = 20  # vertices around a capsule
CAPSULE_RINGS = 7  # latitude rings per hemisphere (pole to equator)
GROUND_FINE_RADIUS, GROUND_FINE_STEP = 1.2, 0.03  # m: fine rings near the centre, for shadows
GROUND_RINGS = (1.2, 1.5, 2.0, 2.5, 3.0, 4.0, 5.0, 6.0, 7.0, 9.0, 12.0)  # m, radii beyond them
SHADOW_STRENGTH = 0.4  # fraction of the floor's light a capsule touching it takes away
SHADOW_SOFTNESS = 0.015  # m, blur of the shadow of a capsule on the floor
SHADOW_HEIGHT = 0.12  # m: a capsule this high above the floor casts a quarter-strength shadow
SHADOW_AMBIENT = 0.3  # strength of the faint, wide shadow of the whole figure
SHADOW_AMBIENT_RADIUS = 0.15  # m, its width
SHADOW_AMBIENT_HEIGHT = 0.25  # m, the height at which a capsule's share of it halves
GROUND_FADE = (1.0, 7.0)  # m: the floor blends from sand into the background between these radii
GROUND_SEGMENTS = 128
GROUND_COLOR = (0.86, 0.80, 0.70)  # sand
HAIR_COLOR = (0.16, 0.09, 0.06)
TOP_COLOR = (0.95, 0.93, 0.86)  # the dancer's top, on the upper back capsule
PROP_COLOR = (0.62, 0.63, 0.66)  # a body that is not a dancer (e.g. a towel bar)


def catmull_rom_weights(fraction: np.ndarray) -> np.ndarray:
    """Weights (K, 4) of the points at offsets −1, 0, 1, 2 for fractions s (K,) in [0, 1)."""
    s = fraction[:, None]
    return np.concatenate([(-s ** 3 + 2 * s ** 2 - s) / 2, (3 * s ** 3 - 5 * s ** 2 + 2) / 2,
                           (-3 * s ** 3 + 4 * s ** 2 + s) / 2, (s ** 3 - s ** 2) / 2], axis=1)


def spline_stencil(count: int, subdivision: int, periodic: bool):
    """Along one grid axis of ``count`` particles: the render positions in particle units (K,),
    the 4 particle indices (K, 4) and weights (K, 4) of each."""
    render_count = count * subdivision if periodic else (count - 1) * subdivision + 1
    position = np.arange(render_count) / subdivision
    base = np.minimum(np.floor(position).astype(int), count - 1)
    index = base[:, None] + np.arange(-1, 3)[None, :]
    index = index % count if periodic else np.clip(index, 0, count - 1)
    return position, index, catmull_rom_weights(position - base)


def triangle_gather_fields(triangles: np.ndarray, vertex_count: int, uploads: UploadBatch):
    """Taichi fields of the triangles around each vertex (CSR start (V+1,), triangle (K,)),
    filled through ``uploads``."""
    start, item = triangle_gather_lists(triangles, vertex_count)
    start_field = ti.field(ti.i32, vertex_count + 1)
    item_field = ti.field(ti.i32, len(item))
    uploads.add([(start_field, start), (item_field, item)])
    return start_field, item_field


@ti.data_oriented
class Surface:
    """A triangle mesh for GGUI: vertices [m], unit normals, colours and flat indices (f32/i32
    fields), and the NumPy triangles (T, 3).

    Its fields are filled from NumPy through ``uploads``: a renderer's batch, which sends every
    surface's copies in one launch once they are all built (``from_numpy`` compiles a kernel
    for each field: ~20 of them took ~2 s of ``render hula``'s start-up), or, without one, a
    batch of the surface's own, which every subclass's constructor sends when its fields are
    allocated (``_send_own``, its last line). Once sent, a copy added to it is made at once."""

    def __init__(self, vertex_count: int, triangles: np.ndarray,
                 uploads: UploadBatch | None = None):
        self.vertex_count = vertex_count
        self.triangles = np.ascontiguousarray(triangles, dtype=np.int32)
        self.uploads = UploadBatch() if uploads is None else uploads
        self._sends_own = uploads is None
        self.vertices = ti.Vector.field(3, ti.f32, vertex_count)
        self.normals = ti.Vector.field(3, ti.f32, vertex_count)
        self.colors = ti.Vector.field(3, ti.f32, vertex_count)
        self.indices = ti.field(ti.i32, self.triangles.size)
        self.uploads.add([(self.indices, self.triangles.ravel())])

    def _send_own(self) -> None:
        """The end of a constructor: send the surface's own batch (not a renderer's)."""
        if self._sends_own:
            self.uploads.send()

    def set_colors(self, colors: np.ndarray) -> None:
        """Per-vertex colours (V, 3) in [0, 1]."""
        self.uploads.add([(self.colors, colors)])

    def points(self) -> np.ndarray:
        """Vertex positions (V, 3) [m] as float64."""
        return self.vertices.to_numpy().astype(np.float64)


@ti.data_oriented
class ClothSurface(Surface):
    """The cloth as a render mesh whose vertex i is Σ_k weight[i, k]·x[source[i, k]] over
    ``taps`` particles; ``update(x)`` follows the particles. A grid garment is refined into the
    smooth spline surface (16 taps); a mesh garment is drawn as it is (1 tap), split at its UV
    seams (``Garment.uv_layout``)."""

    def __init__(self, garment: Garment, subdivision: int, uploads: UploadBatch | None = None):
        self.columns = self.rows = 0  # the render grid's size; none for a mesh garment
        if garment.is_grid:
            source, weight, triangles, self.uvs, self.uv_footprint, (self.columns, self.rows) = \
                spline_surface(garment, subdivision)
        else:
            particle, self.uvs, triangles = garment.uv_layout()
            source, weight = particle[:, None], np.ones((len(particle), 1))
            corners = self.uvs[triangles]
            steps = np.abs(np.roll(corners, -1, axis=1) - corners).reshape(-1, 2)
            self.uv_footprint = tuple(np.mean(steps, axis=0))
        self.taps = source.shape[1]
        super().__init__(len(source), triangles, uploads)
        self.source = ti.field(ti.i32, (self.vertex_count, self.taps))
        self.weight = ti.field(ti.f32, (self.vertex_count, self.taps))
        self.uploads.add([(self.source, source.astype(np.int32)), (self.weight, weight)])
        self.triangle_start, self.triangle_item = triangle_gather_fields(
            self.triangles, self.vertex_count, self.uploads)
        self._send_own()

    @ti.kernel
    def update(self, x: ti.template()):
        """Render vertices from the particle positions ``x`` [m], then their normals."""
        for i in range(self.vertex_count):
            p = ti.Vector.zero(ti.f32, 3)
            for k in ti.static(range(self.taps)):
                p += self.weight[i, k] * ti.cast(x[self.source[i, k]], ti.f32)
            self.vertices[i] = p
        for i in range(self.vertex_count):
            n = ti.Vector.zero(ti.f32, 3)
            for k in range(self.triangle_start[i], self.triangle_start[i + 1]):
                corner = 3 * self.triangle_item[k]
                p0 = self.vertices[self.indices[corner]]
                n += (self.vertices[self.indices[corner + 1]] - p0).cross(
                    self.vertices[self.indices[corner + 2]] - p0)
            self.normals[i] = n / ti.max(n.norm(), 1e-12)


def spline_surface(garment: Garment, subdivision: int):
    """A grid garment refined ``subdivision`` times by the Catmull-Rom surface: (source (V, 16),
    weight (V, 16), triangles (T, 3), uvs (V, 2), uv footprint (du, dv) of a render cell,
    (columns, rows) of the render grid)."""
    periodic = garment.periodic
    column_position, column_index, column_weight = spline_stencil(
        garment.columns, subdivision, periodic)
    row_position, row_index, row_weight = spline_stencil(garment.rows, subdivision, False)
    columns, rows = len(column_position), len(row_position)
    source = row_index[:, None, :, None] * garment.columns + column_index[None, :, None, :]
    weight = row_weight[:, None, :, None] * column_weight[None, :, None, :]
    u_step = garment.uvs[1, 0] - garment.uvs[0, 0]
    v_step = garment.uvs[garment.columns, 1] - garment.uvs[0, 1]
    uu, vv = np.meshgrid(garment.uvs[0, 0] + column_position * u_step,
                         garment.uvs[0, 1] + row_position * v_step)
    return (source.reshape(-1, 16), weight.reshape(-1, 16),
            grid_triangles(columns, rows, periodic), np.stack([uu, vv], axis=-1).reshape(-1, 2),
            (abs(u_step) / subdivision, abs(v_step) / subdivision), (columns, rows))


@ti.data_oriented
class ClothEdges:
    """The simulation mesh's edges as lines between the particles (the viewer's wireframe: the
    mesh the physics runs on, not the smoothed render mesh)."""

    def __init__(self, garment: Garment):
        edges = garment.edges
        self.vertices = ti.Vector.field(3, ti.f32, garment.particle_count)
        self.indices = ti.field(ti.i32, edges.size)
        self.indices.from_numpy(edges.ravel().astype(np.int32))

    @ti.kernel
    def update(self, x: ti.template()):
        for i in self.vertices:
            self.vertices[i] = ti.cast(x[i], ti.f32)


def capsule_template(segments: int = CAPSULE_SEGMENTS, rings: int = CAPSULE_RINGS):
    """Unit capsule: directions (V, 3) on the unit sphere (axis +z), end flags (V,) (0 at a,
    1 at b) and triangles (T, 3), as a periodic grid of latitude rows × ``segments``.
    The rows run from the pole at a through both equators to the pole at b; the triangles
    with two corners on a pole (zero area) are left out."""
    polar = np.concatenate([np.linspace(np.pi, np.pi / 2, rings + 1),
                            np.linspace(np.pi / 2, 0.0, rings + 1)])
    end = np.repeat([0.0, 1.0], rings + 1)
    azimuth = 2 * np.pi * np.arange(segments) / segments
    direction = np.stack([
        np.sin(polar)[:, None] * np.cos(azimuth)[None, :],
        np.sin(polar)[:, None] * np.sin(azimuth)[None, :],
        np.repeat(np.cos(polar)[:, None], segments, axis=1),
    ], axis=-1).reshape(-1, 3)
    ends = np.repeat(end, segments)
    triangles = grid_triangles(segments, len(polar), periodic=True)
    row = triangles // segments
    on_pole = (row == 0) | (row == len(polar) - 1)
    return direction, ends, triangles[np.sum(on_pole, axis=1) < 2]


def capsule_colors(body, skin, direction: np.ndarray, ends: np.ndarray) -> np.ndarray:
    """Colours (C + D, V, 3) of every template vertex of every capsule: skin, a tube top on the
    upper back below the shoulders, hair over the top of the head; one neutral colour for a body
    that is not a dancer."""
    capsule_count = body.capsule_count + body.display_capsule_count
    names = getattr(body, "capsule_names", None)
    if names is None:
        return np.broadcast_to(PROP_COLOR, (capsule_count, len(ends), 3)).copy()
    names = list(names) + list(DISPLAY_CAPSULE_NAMES)
    colors = np.broadcast_to(skin, (capsule_count, len(ends), 3)).copy()
    for k, name in enumerate(names):
        if name in ("back_upper", "back"):
            colors[k][(ends < 0.5) | (direction[:, 2] < 0.45)] = TOP_COLOR  # shoulders bare
        elif name == "head":  # the top, and the back: local +x is world −z on an upright capsule
            colors[k][((ends > 0.5) & (direction[:, 2] > 0.25)) | (direction[:, 0] > 0.3)] = \
                HAIR_COLOR
    return colors


@ti.data_oriented
class BodySurface(Surface):
    """The body's collision and display capsules as one mesh; ``update(pose)`` places them."""

    def __init__(self, body, skin=(0.80, 0.58, 0.45), uploads: UploadBatch | None = None):
        """body: a ``body.Body`` (or anything with its capsule attributes and ``pose``)."""
        direction, ends, template_triangles = capsule_template()
        self.template_count = len(ends)
        self.capsule_count = body.capsule_count + body.display_capsule_count
        offsets = np.arange(self.capsule_count)[:, None, None] * self.template_count
        super().__init__(self.capsule_count * self.template_count,
                         (template_triangles[None] + offsets).reshape(-1, 3), uploads)
        self.body = body
        self.direction = ti.Vector.field(3, ti.f32, self.template_count)
        self.end = ti.field(ti.f32, self.template_count)
        self.capsule_a = ti.Vector.field(3, ti.f32, self.capsule_count)
        self.capsule_b = ti.Vector.field(3, ti.f32, self.capsule_count)
        self.capsule_radius = ti.field(ti.f32, self.capsule_count)
        self.uploads.add([(self.direction, direction), (self.end, ends), (
            self.capsule_radius, np.concatenate([body.capsule_radius,
                                                 body.display_capsule_radius]))])
        self.set_colors(capsule_colors(body, skin, direction, ends).reshape(-1, 3))
        self._send_own()

    def update(self, t: float) -> None:
        """Place every capsule at the body's pose at time ``t`` [s]."""
        pose = self.body.pose(t)
        ends_a = np.concatenate([pose.capsule_a, pose.display_capsule_a])
        ends_b = np.concatenate([pose.capsule_b, pose.display_capsule_b])
        self.uploads.add([(self.capsule_a, ends_a), (self.capsule_b, ends_b)])
        self.place()

    @ti.kernel
    def place(self):
        for k, j in ti.ndrange(self.capsule_count, self.template_count):
            a, b = self.capsule_a[k], self.capsule_b[k]
            axis_vector = b - a
            length = axis_vector.norm()
            axis = ti.Vector([0.0, 1.0, 0.0])
            if length > 1e-9:
                axis = axis_vector / length
            helper = ti.Vector([1.0, 0.0, 0.0])
            if ti.abs(axis[0]) > 0.9:
                helper = ti.Vector([0.0, 0.0, 1.0])
            first = axis.cross(helper).normalized()
            second = axis.cross(first)
            n = self.direction[j]
            normal = first * n[0] + second * n[1] + axis * n[2]
            i = k * self.template_count + j
            self.vertices[i] = a + self.end[j] * axis_vector + self.capsule_radius[k] * normal
            self.normals[i] = normal


@ti.data_oriented
class GroundSurface(Surface):
    """A sand-coloured disc at ``height`` [m] that blends into the background between the radii
    ``GROUND_FADE`` (smoothstep), so the floor shows no edge and no horizon, with soft contact
    shadows of the body's capsules (fine rings near the centre carry them).

    GGUI lights without falloff, so far out a point light grazes the floor and could never light it
    up to a bright background colour. ``shade`` therefore draws the floor with normals turned
    towards the key light (full light everywhere) and divides the colours it wants to see by that
    light: sand lit evenly as the floor's centre is, blending into exactly the background.

    Shadow of a capsule (segment a–b, radius r) at a floor point g, as if lit from above: with c
    the point of the segment nearest to g seen from above, ρ = |g − c|_xz − r and h the height of
    the capsule's underside at c, occlusion o = exp(−max(ρ, 0)² / 2σ²) / (1 + h/H)², σ = σ₀ + h/4
    (a blob that widens and fades with height, H = ``SHADOW_HEIGHT``), and at least the wide,
    faint o = A exp(−max(ρ, 0)² / 2 R²) / (1 + h/H_A) that the whole figure takes from the sky
    (A, R, H_A = ``SHADOW_AMBIENT``, ``_RADIUS``, ``_HEIGHT``); the floor keeps
    1 − ``SHADOW_STRENGTH`` · max o of its colour."""

    def __init__(self, height: float, uploads: UploadBatch | None = None):
        radius = np.concatenate([np.arange(0.0, GROUND_FINE_RADIUS, GROUND_FINE_STEP),
                                 GROUND_RINGS])
        azimuth = 2 * np.pi * np.arange(GROUND_SEGMENTS) / GROUND_SEGMENTS
        points = np.stack([radius[:, None] * np.cos(azimuth)[None, :],
                           np.full((len(radius), GROUND_SEGMENTS), height),
                           radius[:, None] * np.sin(azimuth)[None, :]], axis=-1).reshape(-1, 3)
        super().__init__(len(points), grid_triangles(GROUND_SEGMENTS, len(radius), periodic=True),
                         uploads)
        s = np.clip((radius - GROUND_FADE[0]) / (GROUND_FADE[1] - GROUND_FADE[0]), 0, 1)
        self.fade = np.repeat(s * s * (3 - 2 * s), GROUND_SEGMENTS)
        self.up = np.tile([0.0, 1.0, 0.0], (len(points), 1))
        self.height = height
        self.shaded_count = GROUND_SEGMENTS * int(np.sum(radius < GROUND_FINE_RADIUS))
        self.unshadowed = ti.Vector.field(3, ti.f32, len(points))
        self.host_points = points.astype(np.float32).astype(np.float64)  # the vertices' values
        self.uploads.add([(self.vertices, points)])
        self._send_own()

    def shade(self, key_light: np.ndarray, lighting, background) -> None:
        """Normals and colours for a renderer whose lighting factor for unit normals and points
        (V, 3) is ``lighting(normals, points)`` (V,) and whose key light is at ``key_light`` [m]."""
        points = self.host_points
        toward_key = key_light - points
        toward_key /= np.linalg.norm(toward_key, axis=1, keepdims=True)
        fade = self.fade[:, None]
        sunlit = lighting(self.up, np.zeros_like(points))[:, None]
        seen = (1 - fade) * np.array(GROUND_COLOR) * sunlit + fade * np.asarray(background)
        colors = np.clip(seen / lighting(toward_key, points)[:, None], 0, 1)
        self.uploads.add([(self.normals, toward_key), (self.colors, colors),
                          (self.unshadowed, colors)])

    @ti.kernel
    def cast_shadows(self, body: ti.template()):
        """Darken the floor's inner rings under ``body``'s capsules (a ``BodySurface``)."""
        for i in range(self.shaded_count):
            g = self.vertices[i]
            occlusion = 0.0
            for k in range(body.capsule_count):
                a, b = body.capsule_a[k], body.capsule_b[k]
                d = b - a
                along = d[0] * d[0] + d[2] * d[2]
                t = 0.0
                if along > 1e-12:
                    t = ti.math.clamp(((g[0] - a[0]) * d[0] + (g[2] - a[2]) * d[2]) / along, 0, 1)
                c = a + t * d
                r = body.capsule_radius[k]
                rho = ti.max(ti.sqrt((g[0] - c[0]) ** 2 + (g[2] - c[2]) ** 2) - r, 0.0)
                h = ti.max(c[1] - r - g[1], 0.0)
                sigma = SHADOW_SOFTNESS + 0.25 * h
                occlusion = ti.max(occlusion, ti.exp(-rho * rho / (2 * sigma * sigma))
                                   / (1 + h / SHADOW_HEIGHT) ** 2,
                                   SHADOW_AMBIENT * ti.exp(-rho * rho
                                                           / (2 * SHADOW_AMBIENT_RADIUS ** 2))
                                   / (1 + h / SHADOW_AMBIENT_HEIGHT))
            self.colors[i] = self.unshadowed[i] * (1 - SHADOW_STRENGTH * occlusion)


PLATE_SEGMENTS = 96  # vertices around the support plate's rim


class PlateSurface(Surface):
    """The support plate (``effects/support.py``): a flat-shaded cylinder of radius ``radius``
    [m] from ``height − thickness`` to ``height`` about the vertical axis through
    ``centre`` = (x, z) [m], grey as a prop; its top, side and bottom keep vertices of their own
    so that each face has its own normal."""

    def __init__(self, height: float, radius: float, thickness: float, centre,
                 uploads: UploadBatch | None = None):
        azimuth = 2 * np.pi * np.arange(PLATE_SEGMENTS) / PLATE_SEGMENTS
        rim = np.stack([np.cos(azimuth), np.zeros(PLATE_SEGMENTS), np.sin(azimuth)], axis=1)
        axis = np.array([centre[0], 0.0, centre[1]])
        up = np.array([0.0, 1.0, 0.0])
        top, bottom = axis + height * up, axis + (height - thickness) * up
        ring = np.arange(PLATE_SEGMENTS)
        following = (ring + 1) % PLATE_SEGMENTS
        points = np.concatenate([[top], top + radius * rim,  # the top: centre 0, rim 1..S
                                 top + radius * rim, bottom + radius * rim,  # the side
                                 [bottom], bottom + radius * rim])  # the bottom
        normals = np.concatenate([np.tile(up, (PLATE_SEGMENTS + 1, 1)), rim, rim,
                                  np.tile(-up, (PLATE_SEGMENTS + 1, 1))])
        s = PLATE_SEGMENTS
        triangles = np.concatenate([
            np.stack([np.zeros(s, int), 1 + following, 1 + ring], axis=1),
            np.stack([1 + s + ring, 1 + s + following, 1 + 2 * s + ring], axis=1),
            np.stack([1 + s + following, 1 + 2 * s + following, 1 + 2 * s + ring], axis=1),
            np.stack([np.full(s, 1 + 3 * s), 1 + 3 * s + 1 + ring, 1 + 3 * s + 1 + following],
                     axis=1)])
        super().__init__(len(points), triangles, uploads)
        self.uploads.add([(self.vertices, points), (self.normals, normals)])
        self.set_colors(np.broadcast_to(PROP_COLOR, (len(points), 3)))
        self._send_own()
