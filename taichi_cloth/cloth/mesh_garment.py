"""A garment from a triangle or quad mesh (``cloth.shape = "mesh"``, ``cloth.mesh = "x.obj"``):
springs from its edges, bending hinges and lumped masses from its triangles, warp and weft from
its UVs, pins from its groups or a vertex list.

Pattern axes. The pattern's v axis (a garment's length, where the grid garments run their rows)
comes from the UVs: per triangle the gradient ∂x/∂v of the map from (u, v) to the rest position,
[x1 − x0, x2 − x0] = [∂x/∂u, ∂x/∂v]·[[Δu1, Δu2], [Δv1, Δv2]], area-weighted over a vertex's
triangles. The warp runs down the pattern, −∂x/∂v (a grid garment's v falls down its rows),
turned by ``cloth.bias`` towards ∂x/∂u, as on the grid garments. Without UVs the pattern's
down is the world's (−y, or x where the cloth lies flat) in each vertex's tangent plane.

Springs (materials.py has the grid's constants and their derivation):

- A quad is a grid cell: its four sides are stretch springs, its diagonals shear springs. A
  side runs along the pattern's u or v axis (whichever its direction is nearer to); each vertex's
  spacing along u (dx) and v (dz) is the mean length of its quad sides of that kind, and a side
  along u takes k = k_m(φ)·dz̄/dx̄ (along v: k_m(φ)·dx̄/dz̄), a diagonal G·(dx̄² + dz̄²)/(2·dx̄·dz̄),
  with the bar the mean over the spring's two ends, φ its angle to the warp: the grid's own
  constants, so a grid written out as quads builds the same cloth.
- An edge of triangles only is a stretch spring with Van Gelder's constant for a triangulated
  membrane, k = k_m(φ)·Σ_t A_t/|e|² over its (one or two) triangles (Van Gelder, "Approximate
  simulation of elastic membranes by triangulated spring meshes", J. Graphics Tools 3(2), 1998):
  exact in stretch on the right triangles of a grid, but the edges also carry shear (as a
  membrane of Poisson ratio 1/3, G ≈ k_m/3, stiffer than woven cloth's G): a triangle mesh
  shears less than the same fabric as quads. ``cloth.springs`` without "stretch" has no springs
  on such edges.
"""

import sys
from pathlib import Path

import numpy as np

from taichi_cloth.errors import InputError
from taichi_cloth.cloth.obj_mesh import ObjMesh, read_obj, winding_conflicts
from taichi_cloth.cloth.topology import hinge_stencils, lumped_mass
from taichi_cloth.cloth.garment import Garment, grain_cos_sq, hinge_rigidity
from taichi_cloth.config.materials import Material, stretch_modulus
from taichi_cloth.config.tables import ClothConfig


def mesh_path(cloth: ClothConfig, source: str) -> Path:
    """cloth.mesh, relative to the scene file; InputError when it is not a file."""
    if not cloth.mesh:
        raise InputError(f"{source}: cloth.mesh: shape = \"mesh\" needs a file, e.g. "
                         f"cloth.mesh = \"garment.obj\"")
    path = Path(cloth.mesh) if Path(cloth.mesh).is_absolute() \
        else Path(source).parent / cloth.mesh
    if not path.is_file():
        raise InputError(f"{source}: cloth.mesh: {path} is not a file")
    return path


def triangle_uv_gradients(positions: np.ndarray, triangles: np.ndarray,
                          corner_uvs: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Per triangle: ∂x/∂u, ∂x/∂v (T, 3) each and whether its UV triangle has area (T,)."""
    e1 = positions[triangles[:, 1]] - positions[triangles[:, 0]]
    e2 = positions[triangles[:, 2]] - positions[triangles[:, 0]]
    d1, d2 = corner_uvs[:, 1] - corner_uvs[:, 0], corner_uvs[:, 2] - corner_uvs[:, 0]
    determinant = d1[:, 0] * d2[:, 1] - d2[:, 0] * d1[:, 1]
    valid = np.abs(determinant) > 1e-14
    safe = np.where(valid, determinant, 1.0)[:, None]
    du = (e1 * d2[:, 1:2] - e2 * d1[:, 1:2]) / safe
    dv = (e2 * d1[:, 0:1] - e1 * d2[:, 0:1]) / safe
    return du, dv, valid


def pattern_axes(positions: np.ndarray, triangles: np.ndarray,
                 corner_uvs: np.ndarray | None) -> tuple[np.ndarray, np.ndarray]:
    """Unit (across, down) axes (N, 3) of the pattern at every vertex (module docstring)."""
    p0, p1, p2 = (positions[triangles[:, k]] for k in range(3))
    face_normal = np.cross(p1 - p0, p2 - p0)  # length: twice the area
    normal = np.zeros_like(positions)
    for k in range(3):
        np.add.at(normal, triangles[:, k], face_normal)
    normal /= np.maximum(np.linalg.norm(normal, axis=1, keepdims=True), 1e-300)
    down = np.zeros_like(positions)
    across = np.zeros_like(positions)
    if corner_uvs is not None:
        du, dv, valid = triangle_uv_gradients(positions, triangles, corner_uvs)
        weight = (np.linalg.norm(face_normal, axis=1) * valid)[:, None]
        for k in range(3):
            np.add.at(down, triangles[:, k], -dv * weight / np.maximum(
                np.linalg.norm(dv, axis=1, keepdims=True), 1e-300))
            np.add.at(across, triangles[:, k], du * weight / np.maximum(
                np.linalg.norm(du, axis=1, keepdims=True), 1e-300))
    world = np.array([0.0, -1.0, 0.0]) - normal[:, 1:2] * -normal  # −y in the tangent plane
    flat = np.linalg.norm(world, axis=1) < 0.1
    world[flat] = np.array([1.0, 0.0, 0.0]) - normal[flat, 0:1] * normal[flat]
    missing = np.linalg.norm(down, axis=1) < 1e-12
    down[missing] = world[missing]
    down /= np.linalg.norm(down, axis=1, keepdims=True)
    across = across - np.einsum("nk,nk->n", across, down)[:, None] * down
    no_across = np.linalg.norm(across, axis=1) < 1e-12
    across[no_across] = np.cross(down[no_across], normal[no_across])
    across /= np.linalg.norm(across, axis=1, keepdims=True)
    return across, down


def mesh_springs(faces: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(quad sides (Q, 2), quad diagonals (D, 2), triangle-only edges (E, 2)), each pair lower
    index first, unique, sorted."""
    quads = faces[faces[:, 3] >= 0]
    triangles = faces[faces[:, 3] < 0, :3]
    sides = np.concatenate([quads[:, [k, (k + 1) % 4]] for k in range(4)])
    diagonals = np.concatenate([quads[:, [0, 2]], quads[:, [1, 3]]])
    triangle_sides = np.concatenate([triangles[:, [k, (k + 1) % 3]] for k in range(3)])

    def unique(pairs):
        return np.unique(np.sort(pairs, axis=1), axis=0).reshape(-1, 2).astype(np.int32)

    sides, diagonals, triangle_sides = unique(sides), unique(diagonals), unique(triangle_sides)
    key = int(faces.max()) + 1
    in_quads = np.isin(triangle_sides[:, 0].astype(np.int64) * key + triangle_sides[:, 1],
                       sides[:, 0].astype(np.int64) * key + sides[:, 1])
    triangle_sides = triangle_sides[~in_quads]
    return sides, diagonals, triangle_sides


def quad_spacings(positions: np.ndarray, sides: np.ndarray, along_v: np.ndarray):
    """Each vertex's spacing (dx along u, dz along v) (N,) [m]: the mean length of its quad
    sides of that kind; a vertex with sides of one kind only takes that length for both."""
    length = np.linalg.norm(positions[sides[:, 1]] - positions[sides[:, 0]], axis=1)
    spacing = []
    for kind in (~along_v, along_v):
        total, count = np.zeros(len(positions)), np.zeros(len(positions))
        for end in (0, 1):
            np.add.at(total, sides[kind, end], length[kind])
            np.add.at(count, sides[kind, end], 1.0)
        spacing.append((total, count))
    (tx, cx), (tz, cz) = spacing
    dx = np.where(cx > 0, tx / np.maximum(cx, 1), tz / np.maximum(cz, 1))
    dz = np.where(cz > 0, tz / np.maximum(cz, 1), dx)
    return dx, dz


def van_gelder_stiffness(positions: np.ndarray, triangles: np.ndarray, edges: np.ndarray,
                         modulus: np.ndarray) -> np.ndarray:
    """k = k_m(φ)·Σ_t A_t/|e|² [N/m] for each edge of ``edges`` (E, 2: unique, lower index
    first, sorted, as ``mesh_springs`` gives them) over the triangles that hold it."""
    if not len(edges):
        return np.zeros(0)
    p0, p1, p2 = (positions[triangles[:, k]] for k in range(3))
    area = 0.5 * np.linalg.norm(np.cross(p1 - p0, p2 - p0), axis=1)
    count = len(positions)
    edge_keys = edges[:, 0].astype(np.int64) * count + edges[:, 1]  # ascending
    summed = np.zeros(len(edges))
    for k in range(3):
        pair = np.sort(triangles[:, [k, (k + 1) % 3]], axis=1).astype(np.int64)
        keys = pair[:, 0] * count + pair[:, 1]
        slot = np.minimum(np.searchsorted(edge_keys, keys), len(edges) - 1)
        hit = edge_keys[slot] == keys
        np.add.at(summed, slot[hit], area[hit])
    length_sq = np.sum((positions[edges[:, 1]] - positions[edges[:, 0]]) ** 2, axis=1)
    return modulus * summed / length_sq


def corner_uv_table(mesh: ObjMesh) -> np.ndarray | None:
    """The UVs (T, 3, 2) of every triangle corner, None when the file has none."""
    if not mesh.has_uvs:
        return None
    _, uv_index = mesh.triangles()
    return mesh.uvs[uv_index]


def mesh_pins(cloth: ClothConfig, mesh: ObjMesh, source: str) -> np.ndarray:
    """The pinned vertices (N,) bool: the groups ``cloth.pin_groups`` or the 1-based vertices
    ``cloth.pin_vertices`` (OBJ numbering) for pin = "group" / "vertices"."""
    pinned = np.zeros(len(mesh.positions), bool)
    if cloth.pin == "group":
        for name in cloth.pin_groups:
            if name not in mesh.groups:
                known = ", ".join(sorted(mesh.groups)) or "none"
                raise InputError(f"{source}: cloth.pin_groups: no group {name!r} in "
                                 f"{cloth.mesh} (its groups: {known})")
            pinned[mesh.groups[name]] = True
    elif cloth.pin == "vertices":
        listed = np.asarray(cloth.pin_vertices, dtype=np.int64)
        if np.any(listed > len(pinned)):
            raise InputError(f"{source}: cloth.pin_vertices: {int(listed.max())} is beyond the "
                             f"{len(pinned)} vertices of {cloth.mesh}")
        pinned[listed - 1] = True
    return pinned


def build_mesh_garment(cloth: ClothConfig, material: Material, source: str) -> Garment:
    """The garment of ``cloth.mesh`` (module docstring), scaled by ``cloth.mesh_scale`` and
    moved by ``cloth.mesh_offset``; prints a warning when its faces' windings disagree."""
    path = mesh_path(cloth, source)
    mesh = read_obj(path)
    conflicts = winding_conflicts(mesh)
    if conflicts:
        print(f"warning: {path}: {conflicts} edges join faces wound opposite ways; the physics "
              f"does not mind, but shading will flip there", file=sys.stderr)
    positions = mesh.positions * cloth.mesh_scale + np.asarray(cloth.mesh_offset, float)
    return garment_from_mesh(mesh, positions, mesh_pins(cloth, mesh, source), cloth, material,
                             source)


def garment_from_mesh(mesh: ObjMesh, positions: np.ndarray, pinned: np.ndarray,
                      cloth: ClothConfig, material: Material, source: str) -> Garment:
    """The garment of ``mesh``'s faces, UVs and groups at ``positions`` (N, 3) [m] with the
    pins ``pinned`` (N,) bool (module docstring)."""
    if cloth.bending == "springs":
        raise InputError(f"{source}: cloth.bending: skip-one springs need a grid; a mesh "
                         f"garment bends with \"curvature\"")
    triangles, _ = mesh.triangles()
    corner_uvs = corner_uv_table(mesh)
    across, down = pattern_axes(positions, triangles, corner_uvs)
    bias = np.radians(cloth.bias)
    warp = np.cos(bias) * down + np.sin(bias) * across
    sides, diagonals, triangle_sides = mesh_springs(mesh.faces)
    along_v = grain_cos_sq(positions, down, sides) >= 0.5
    dx, dz = quad_spacings(positions, sides, along_v)
    mean = {name: 0.5 * (values[pairs[:, 0]] + values[pairs[:, 1]])
            for name, values, pairs in (("side_dx", dx, sides), ("side_dz", dz, sides),
                                        ("diagonal_dx", dx, diagonals),
                                        ("diagonal_dz", dz, diagonals))}
    side_modulus = stretch_modulus(material, grain_cos_sq(positions, warp, sides))
    side_stiffness = np.where(along_v, side_modulus * mean["side_dx"] / mean["side_dz"],
                              side_modulus * mean["side_dz"] / mean["side_dx"])
    shear_stiffness = material.shear_stiffness * (mean["diagonal_dx"] ** 2
                                                  + mean["diagonal_dz"] ** 2) / (
        2 * mean["diagonal_dx"] * mean["diagonal_dz"])
    edge_stiffness = van_gelder_stiffness(
        positions, triangles, triangle_sides,
        stretch_modulus(material, grain_cos_sq(positions, warp, triangle_sides)))
    families = {"stretch": (np.concatenate([sides, triangle_sides]),
                            np.concatenate([side_stiffness, edge_stiffness])),
                "shear": (diagonals, shear_stiffness)}
    chosen = {name: value for name, value in families.items()
              if name in cloth.springs and len(value[0])}
    if not chosen:
        raise InputError(f"{source}: cloth.springs: {list(cloth.springs)} gives this mesh no "
                         f"springs (shear springs are a quad's diagonals; it has no quads)")
    hinges = hinge_stencils(triangles)
    uvs = np.zeros((len(positions), 2))
    if corner_uvs is not None:
        uvs[triangles.ravel()[::-1]] = corner_uvs.reshape(-1, 2)[::-1]  # each vertex's first
    return Garment(
        positions=positions, uvs=uvs, triangles=triangles,
        springs={name: pairs for name, (pairs, _) in chosen.items()},
        spring_stiffness={name: stiffness for name, (_, stiffness) in chosen.items()},
        mass=lumped_mass(positions, triangles, material.density),
        pinned=pinned, columns=0, rows=0, periodic=False,
        damping_time=material.damping, warp=warp, hinges=hinges,
        hinge_rigidity=hinge_rigidity(positions, warp, hinges, material.bend_stiffness,
                                      material.bend_weft),
        corner_uvs=corner_uvs)
