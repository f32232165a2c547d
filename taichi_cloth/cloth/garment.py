"""Garment meshes built in NumPy: particles, UVs, triangles, springs per family, masses, pins.

The library's shapes are regular grids of ``columns × rows`` particles, index = row · columns +
column (row 0 is the top: the waist of a skirt, the top edge of a sheet):

- a sheet, hanging in the x-y plane (``vertical``) or lying in the x-z plane (``horizontal``);
- a skirt: a conical tube from the waist circle down to the hem circle, periodic around, so the
  seam closes (column ``columns − 1`` connects to column 0).

A garment from a file (``cloth.shape = "mesh"``) is any triangle or quad mesh
(``mesh_garment.py``); it has no grid (columns = rows = 0).

Spring families (seed §2.1, Fig. 1): stretch between grid neighbours, shear across each cell's
diagonals, bend between skip-one neighbours. Per-spring stiffness follows ``materials`` from the
local rest spacing; particle masses lump areal density × one third of each adjacent triangle.
"""

from dataclasses import dataclass, field

import numpy as np

from taichi_cloth.errors import InputError
from taichi_cloth.cloth.topology import (grid_springs, grid_triangles, hinge_stencils,
                                          lumped_mass, triangle_edges)
from taichi_cloth.config.materials import Material, spring_constants
from taichi_cloth.config.tables import ClothConfig


@dataclass(frozen=True)
class Garment:
    """Rest geometry and topology of one piece of cloth (all float arrays float64, SI units).

    positions (N,3) m; uvs (N,2) texture coordinates in [0,1]; triangles (T,3) particle indices,
    counter-clockwise seen from outside (skirt) or from +z (vertical sheet); springs: family name →
    (S_f,2) particle indices; spring_stiffness: family → (S_f,) N/m; mass (N,) kg; pinned (N,) bool;
    columns, rows: grid shape; periodic: whether columns wrap around (skirt); damping_time: the
    fabric's Rayleigh damping time β [s]; warp (N,3):
    the unit warp direction in the rest shape at each particle (down the rows, turned by the bias
    towards the columns); hinges (H,4): the bending stencils of the triangles
    (``topology.hinge_stencils``); hinge_rigidity (H,): each hinge's B [N·m] from the warp and
    weft rigidity (``hinge_rigidity``); corner_uvs (T, 3, 2): a mesh garment's UVs per triangle
    corner (a vertex on a UV seam has several), None on a grid, whose ``uvs`` are per particle.
    """

    positions: np.ndarray
    uvs: np.ndarray
    triangles: np.ndarray
    springs: dict
    spring_stiffness: dict
    mass: np.ndarray
    pinned: np.ndarray
    columns: int
    rows: int
    periodic: bool
    damping_time: float
    warp: np.ndarray | None = None
    hinges: np.ndarray = field(default_factory=lambda: np.zeros((0, 4), np.int32))
    hinge_rigidity: np.ndarray = field(default_factory=lambda: np.zeros(0))
    start_offset: np.ndarray | None = None
    corner_uvs: np.ndarray | None = None

    @property
    def is_grid(self) -> bool:
        """Whether the particles form the ``columns × rows`` grid (not a mesh from a file)."""
        return self.columns * self.rows == len(self.positions) > 0

    @property
    def start_positions(self) -> np.ndarray:
        """The positions (N, 3) [m] the run starts from."""
        return self.positions if self.start_offset is None else self.positions + self.start_offset

    @property
    def particle_count(self) -> int:
        return len(self.positions)

    @property
    def edges(self) -> np.ndarray:
        """The mesh's edges (E, 2), each once, lower index first, sorted."""
        return triangle_edges(self.triangles)

    @property
    def spring_count(self) -> int:
        return sum(len(s) for s in self.springs.values())

    def uv_layout(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The garment's vertices for a UV-mapped surface: (source particle (N',), uvs (N', 2),
        triangles (T, 3)), split where the UVs have a seam, so that no triangle's UVs jump. A
        mesh garment has one vertex per distinct (particle, UV) of its triangles' corners; a
        skirt's column 0 is duplicated at u = 1 (one vertex per row, appended) and the seam
        triangles use the copies; other grids need no split."""
        count = len(self.positions)
        if self.corner_uvs is not None:
            keys = np.concatenate([self.triangles.reshape(-1, 1),
                                   self.corner_uvs.reshape(-1, 2)], axis=1)
            unique, corner_vertex = np.unique(keys, axis=0, return_inverse=True)
            return (unique[:, 0].astype(np.int64), unique[:, 1:],
                    corner_vertex.reshape(-1, 3).astype(np.int32))
        if not self.periodic:
            return np.arange(count), self.uvs, self.triangles
        columns = self.columns
        first_column = np.arange(self.rows) * columns
        u_period = columns * (self.uvs[1, 0] - self.uvs[0, 0])
        column = self.triangles % columns
        wraps = (column == columns - 1).any(axis=1)[:, None] & (column == 0)
        triangles = self.triangles.copy()
        triangles[wraps] = count + triangles[wraps] // columns
        uvs = np.concatenate([self.uvs, self.uvs[first_column] + [u_period, 0.0]])
        return np.concatenate([np.arange(count), first_column]), uvs, triangles


def sheet_positions(cloth: ClothConfig) -> np.ndarray:
    columns, rows = cloth.resolution
    width, depth = cloth.size
    x = np.linspace(-width / 2, width / 2, columns)
    along = np.linspace(0.0, depth, rows)
    xx, aa = np.meshgrid(x, along)
    if cloth.orientation == "vertical":
        return np.stack([xx, cloth.height - aa, np.zeros_like(xx)], axis=-1).reshape(-1, 3)
    return np.stack([xx, np.full_like(xx, cloth.height), aa - depth / 2], axis=-1).reshape(-1, 3)


def sheet_ripple(cloth: ClothConfig, source: str = "") -> np.ndarray | None:
    """The start offset (N, 3) [m] of a sheet with ``cloth.ripple`` = [a, k]: the sheet bent,
    without stretching, into the wave w(u) = a·sin(π·k·u/L) across its plane (z for a vertical
    sheet, y for a horizontal one) down its length L (u from the top row): a row at distance u
    along the fabric moves to w(u) across and ∫₀ᵘ √(1 − w′²) along, so every spring keeps its
    rest length to the quadrature's accuracy. None without a ripple (or for other shapes); a
    wave steeper than 45° (a·π·k/L > 1) is an InputError."""
    amplitude, half_waves = cloth.ripple
    if cloth.shape != "sheet" or amplitude == 0.0:
        return None
    columns, rows = cloth.resolution
    length = cloth.size[1]
    wavenumber = np.pi * half_waves / length
    if amplitude * wavenumber > 1.0:
        raise InputError(f"{source}: cloth.ripple: a wave of {amplitude:g} m and {half_waves:g} half-waves "
                         f"rises steeper than 45° on a sheet {length:g} m long")
    fine = np.linspace(0.0, length, 64 * rows)
    slope = amplitude * wavenumber * np.cos(wavenumber * fine)
    run = np.concatenate([[0.0], np.cumsum(0.5 * (np.sqrt(1 - slope[1:] ** 2)
                                                  + np.sqrt(1 - slope[:-1] ** 2))
                                           * np.diff(fine))])
    along = np.linspace(0.0, length, rows)
    shortening = np.interp(along, fine, run) - along
    across = amplitude * np.sin(wavenumber * along)
    offset = np.zeros((rows, columns, 3))
    if cloth.orientation == "vertical":  # rows run down −y, the plane's normal is z
        offset[:, :, 1], offset[:, :, 2] = -shortening[:, None], across[:, None]
    else:  # rows run along +z, the normal is y
        offset[:, :, 2], offset[:, :, 1] = shortening[:, None], across[:, None]
    return offset.reshape(-1, 3)


def skirt_positions(cloth: ClothConfig, waist_height: float) -> np.ndarray:
    """A cone: radius from waist to hem; ``length`` is measured along the fabric (a full
    circle skirt, flare = length, is a flat annulus)."""
    around, down = cloth.resolution
    flare = cloth.skirt_flare
    drop = cloth.length * np.sqrt(1.0 - (flare / cloth.length) ** 2)
    angle = 2 * np.pi * np.arange(around) / around
    fraction = np.linspace(0.0, 1.0, down)
    radius = cloth.waist_radius + flare * fraction
    ring_height = waist_height - drop * fraction
    radius = radius[:, None] + pleat_offset(cloth, angle)[None, :]
    x = radius * np.cos(angle)[None, :]
    z = radius * np.sin(angle)[None, :]
    y = np.repeat(ring_height[:, None], around, axis=1)
    return np.stack([x, y, z], axis=-1).reshape(-1, 3)


def pleat_offset(cloth: ClothConfig, angle: np.ndarray) -> np.ndarray:
    """The radial offset [m] of a pleated skirt at each column's ``angle`` (all the columns,
    evenly spaced): for box pleats a triangle wave of ``pleats`` periods between −pleat_depth/2
    (an inner fold) and +pleat_depth/2 (an outer fold), so that the fabric zigzags round the
    waist; for knife pleats a sawtooth, each pleat's columns stepping out from the inner to the
    outer fold and the next pleat starting again at its inner fold, so that every pleat faces
    the same way; zero for other garments. Rest lengths come from these positions, so the pleats' extra fabric is in the
    pattern (the bending rest state is flat: the pleats are laid, not pressed in)."""
    if cloth.shape != "pleated":
        return np.zeros_like(angle)
    phase = (cloth.pleats * angle / (2 * np.pi)) % 1.0
    if cloth.pleat_style == "knife":  # a sawtooth: each pleat's face runs outwards, then folds
        per_pleat = len(angle) // cloth.pleats  # back under the next one, all the same way round
        return cloth.pleat_depth * (np.round(phase * per_pleat) / (per_pleat - 1) - 0.5)
    return cloth.pleat_depth * (0.5 - np.abs(2.0 * phase - 1.0))


def settling_ripple(garment: "Garment", folds: int = 8, amplitude: float = 0.01) -> np.ndarray:
    """A displacement (N, 3) [m] that lets a wrap-around garment (a skirt) buckle into
    ``folds`` folds when it settles: amplitude·s²·sin(folds·θ) with s the fraction of the way
    from the first row (the waist, s = 0) to the last (the hem, s = 1), radial about the
    vertical axis, and on a cone flatter than 45° (a circle skirt) turned towards the vertical
    by the cone's own slant, (Δr·ŷ − Δy·r̂)/|(Δr, Δy)| for the slant (Δr, Δy) from waist to
    hem, so that a flat circle is pushed out of its plane; zero for other garments. A cone cut
    from flat fabric is an equilibrium, unstable but exact: without a push it would stand.
    A mesh garment wraps around when its particles circle the vertical axis through their
    centre (no gap of a quarter turn): θ is then the angle about that axis, s the height below
    its top (its highest pin) over its drop, and the push radial."""
    if garment.is_grid:
        if not garment.periodic:
            return np.zeros_like(garment.positions)
        columns, rows = garment.columns, garment.rows
        angle = np.tile(2 * np.pi * np.arange(columns) / columns, rows)
        fraction = np.repeat(np.linspace(0.0, 1.0, rows), columns)
        grid = garment.positions.reshape(rows, columns, 3)
        slant = np.tile(grid[-1] - grid[0], (rows, 1))
    else:
        positions = garment.positions
        top = positions[garment.pinned, 1].max() if garment.pinned.any() else positions[:, 1].max()
        relative = positions - [positions[:, 0].mean(), top, positions[:, 2].mean()]
        angle = np.arctan2(relative[:, 2], relative[:, 0])
        around = np.sort(angle)
        if np.diff(np.concatenate([around, around[:1] + 2 * np.pi])).max() > np.pi / 2:
            return np.zeros_like(positions)
        drop = np.maximum(-relative[:, 1], 0.0)
        fraction = drop / max(drop.max(), 1e-12)
        slant = np.stack([np.cos(angle), -np.ones_like(angle), np.sin(angle)], axis=1)  # steep
    outward = np.stack([np.cos(angle), np.zeros_like(angle), np.sin(angle)], axis=1)
    radial_run, drop = np.einsum("nk,nk->n", slant, outward), -slant[:, 1]
    direction = outward.copy()
    flat = radial_run > drop  # flatter than 45°: push across the cone
    direction[flat] = (drop[flat, None] * outward[flat]
                       + radial_run[flat, None] * np.array([0.0, 1.0, 0.0]))
    direction /= np.linalg.norm(direction, axis=1, keepdims=True)
    size = amplitude * fraction ** 2 * np.sin(folds * angle)
    return size[:, None] * direction


def disc_positions(cloth: ClothConfig) -> np.ndarray:
    """A flat annulus at y = height: rings evenly spaced from waist_radius to hem_radius."""
    around, rings = cloth.resolution
    angle = 2 * np.pi * np.arange(around) / around
    radius = np.linspace(cloth.waist_radius, cloth.hem_radius, rings)
    x = radius[:, None] * np.cos(angle)[None, :]
    z = radius[:, None] * np.sin(angle)[None, :]
    return np.stack([x, np.full_like(x, cloth.height), z], axis=-1).reshape(-1, 3)


def pinned_particles(cloth: ClothConfig, positions: np.ndarray) -> np.ndarray:
    columns, rows = cloth.resolution
    pinned = np.zeros(columns * rows, dtype=bool)
    if cloth.pin == "waist":
        pinned[:columns] = True
    elif cloth.pin == "top-edge":
        pinned[:columns * min(cloth.pin_rows, rows)] = True
    elif cloth.pin == "left-edge":
        pinned[::columns] = True
    elif cloth.pin == "corners":
        pinned[[0, columns - 1]] = True
    elif cloth.pin == "clamp":
        pinned = np.hypot(positions[:, 0], positions[:, 2]) <= cloth.clamp_radius + 1e-12
    return pinned


def grid_tangents(positions: np.ndarray, columns: int, rows: int, periodic: bool):
    """Unit tangents (N,3) of the rest grid down the rows (v) and along the rows, made
    orthogonal to v (u); the last row or column reuses the one before it."""
    grid = positions.reshape(rows, columns, 3)
    down = np.diff(grid, axis=0)
    down = np.concatenate([down, down[-1:]], axis=0)
    across = np.roll(grid, -1, axis=1) - grid if periodic else np.diff(grid, axis=1)
    if not periodic:
        across = np.concatenate([across, across[:, -1:]], axis=1)
    v = down.reshape(-1, 3) / np.linalg.norm(down.reshape(-1, 3), axis=1, keepdims=True)
    u = across.reshape(-1, 3)
    u = u - np.einsum("nk,nk->n", u, v)[:, None] * v
    return u / np.linalg.norm(u, axis=1, keepdims=True), v


def grain_cos_sq(positions: np.ndarray, warp: np.ndarray, pairs: np.ndarray) -> np.ndarray:
    """cos² of the angle between each pair's rest direction (pairs (S, 2) of particle indices)
    and the warp (``warp``: (N, 3) unit vectors) averaged over its two ends."""
    direction = positions[pairs[:, 1]] - positions[pairs[:, 0]]
    grain = warp[pairs[:, 0]] + warp[pairs[:, 1]]
    return np.einsum("sk,sk->s", direction, grain) ** 2 / (
        np.einsum("sk,sk->s", direction, direction) * np.einsum("sk,sk->s", grain, grain))


def hinge_rigidity(positions: np.ndarray, warp: np.ndarray, hinges: np.ndarray,
                   rigidity_warp: float, rigidity_weft: float) -> np.ndarray:
    """B [N·m] of every bending hinge (H, 4; edge x0–x1 first): a hinge whose rest edge makes
    angle ψ with the warp folds the cloth across the direction at ψ + 90°, so
    B = B_weft·cos²ψ + B_warp·sin²ψ (a fold line along the weft bends the warp)."""
    cos_sq = grain_cos_sq(positions, warp, hinges[:, :2])
    return rigidity_weft * cos_sq + rigidity_warp * (1.0 - cos_sq)


def family_stiffness(positions: np.ndarray, springs: dict, material: Material, columns: int,
                     rows: int, periodic: bool, warp: np.ndarray) -> dict:
    """Per-spring stiffness [N/m] from the local rest spacing of each spring's two particles.

    A particle's spacing along a row (dx) is its distance to its right neighbour; down a column
    (dz) to the particle below (the last column or row reuses the one before it).
    ``materials.spring_constants`` maps (dx, dz) and each stretch spring's angle to the warp
    (``warp``: (N, 3) unit vectors, averaged over the spring's ends) to stiffness.
    """
    grid = positions.reshape(rows, columns, 3)
    if periodic:
        dx = np.linalg.norm(np.roll(grid, -1, axis=1) - grid, axis=-1)
    else:
        dx = np.linalg.norm(np.diff(grid, axis=1), axis=-1)
        dx = np.concatenate([dx, dx[:, -1:]], axis=1)
    dz = np.linalg.norm(np.diff(grid, axis=0), axis=-1)
    dz = np.concatenate([dz, dz[-1:]], axis=0)
    dx, dz = dx.ravel(), dz.ravel()
    stiffness = {}
    for family, pairs in springs.items():
        a, b = pairs[:, 0], pairs[:, 1]
        cos_sq = grain_cos_sq(positions, warp, pairs)
        constants = spring_constants(material, 0.5 * (dx[a] + dx[b]), 0.5 * (dz[a] + dz[b]),
                                     cos_sq, cos_sq)
        horizontal = (a // columns) == (b // columns)
        if family == "stretch":
            stiffness[family] = np.where(horizontal, constants.stretch_x, constants.stretch_z)
        else:
            stiffness[family] = np.broadcast_to(getattr(constants, family), a.shape).astype(float)
    return stiffness


def build_garment(cloth: ClothConfig, material: Material, waist_height: float | None = None,
                  source: str = "") -> Garment:
    """Build the garment a scene's ``[cloth]`` describes. ``waist_height`` places a skirt (the
    body's waist when there is one, else ``cloth.waist_height``)."""
    if cloth.shape in ("mesh", "dress"):  # meshes: their module builds on this one
        from taichi_cloth.cloth.dress import dress_mesh
        from taichi_cloth.cloth.mesh_garment import build_mesh_garment, garment_from_mesh
        if cloth.shape == "mesh":
            return build_mesh_garment(cloth, material, source)
        mesh, positions = dress_mesh(cloth, cloth.waist_height if waist_height is None
                                     else waist_height, source)
        pinned = np.zeros(len(positions), bool)
        if cloth.pin == "shoulders":
            pinned[mesh.groups["shoulders"]] = True
        return garment_from_mesh(mesh, positions, pinned, cloth, material, source)
    columns, rows = cloth.resolution
    periodic = cloth.is_skirt or cloth.shape == "disc"
    if periodic and columns < 5:
        raise InputError(f"{source}: cloth.resolution: a {cloth.shape} needs at least 5 "
                         f"particles around, got {columns}")
    if cloth.shape == "pleated" and cloth.pleat_style == "knife" and (
            columns % cloth.pleats or columns < 3 * cloth.pleats):
        raise InputError(f"{source}: cloth.resolution: knife pleats need a multiple of pleats = "
                         f"{cloth.pleats} particles around, at least 3 a pleat, got {columns}")
    if cloth.shape == "pleated" and cloth.pleat_style == "box" and columns % (2 * cloth.pleats):
        raise InputError(f"{source}: cloth.resolution: a pleated skirt needs a multiple of 2 × "
                         f"pleats = {2 * cloth.pleats} particles around (its folds on "
                         f"particles), got {columns}")
    if cloth.is_skirt:
        if abs(cloth.skirt_flare) > cloth.length:
            raise InputError(f"{source}: cloth.length: must be at least |hem_radius − "
                             f"waist_radius| = {abs(cloth.hem_radius - cloth.waist_radius):g} m")
        positions = skirt_positions(cloth, cloth.waist_height if waist_height is None
                                    else waist_height)
    elif cloth.shape == "disc":
        if cloth.hem_radius <= cloth.waist_radius:
            raise InputError(f"{source}: cloth.hem_radius: a disc's outer radius must exceed "
                             f"its inner waist_radius {cloth.waist_radius:g} m")
        positions = disc_positions(cloth)
    else:
        positions = sheet_positions(cloth)
    u = np.arange(columns) / columns if periodic else np.linspace(0, 1, columns)
    uvs = np.stack(np.meshgrid(u, 1.0 - np.linspace(0, 1, rows)), axis=-1).reshape(-1, 2)
    all_springs = grid_springs(columns, rows, periodic)
    families = tuple(cloth.springs) + (("bend",) if cloth.bending == "springs" else ())
    springs = {family: all_springs[family] for family in ("stretch", "shear", "bend")
               if family in families}
    triangles = grid_triangles(columns, rows, periodic)
    warp = warp_directions(cloth, positions)
    hinges = hinge_stencils(triangles)
    return Garment(
        positions=positions,
        uvs=uvs,
        triangles=triangles,
        springs=springs,
        spring_stiffness=family_stiffness(positions, springs, material, columns, rows,
                                          periodic, warp),
        mass=lumped_mass(positions, triangles, material.density),
        pinned=pinned_particles(cloth, positions),
        columns=columns,
        rows=rows,
        periodic=periodic,
        damping_time=material.damping,
        warp=warp,
        hinges=hinges,
        hinge_rigidity=hinge_rigidity(positions, warp, hinges, material.bend_stiffness,
                                      material.bend_weft),
        start_offset=sheet_ripple(cloth, source),
    )


def warp_directions(cloth: ClothConfig, positions: np.ndarray) -> np.ndarray:
    """Unit warp direction (N, 3) at every particle: down the rows of a sheet or skirt (the
    garment's length), along +x on a disc, turned by ``cloth.bias`` towards the rows."""
    bias = np.radians(cloth.bias)
    columns, rows = cloth.resolution
    if cloth.shape == "disc":
        return np.tile([np.cos(bias), 0.0, np.sin(bias)], (len(positions), 1))
    across, down = grid_tangents(positions, columns, rows, cloth.is_skirt)
    return np.cos(bias) * down + np.sin(bias) * across
