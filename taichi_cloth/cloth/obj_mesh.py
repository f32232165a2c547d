"""Garment meshes from Wavefront OBJ files, read and checked before any cloth is built.

Why this reads the file itself: a cloth needs one particle per position, the texture
coordinates of every face corner (a garment's UV map has seams, where one vertex carries two
coordinates) and its groups by name (pins). meshio's OBJ reader keeps only each corner's vertex
index (it drops the corner's texture index and the group names, and refuses a file with more
``vt`` than ``v`` lines: every garment with a seam); trimesh splits vertices at UV seams (which
would cut the cloth apart there) or, keeping their order, gives each vertex one of its
coordinates. The statements a garment needs are few: ``v``, ``vt``, ``f`` (corners ``v``,
``v/vt``, ``v/vt/vn``, ``v//vn``; negative indices count back from the last line read), ``g`` and
``o`` (the names the following faces belong to); the rest (``vn``, ``s``, ``usemtl``, ``l`` ...)
does not shape the cloth and is skipped.

Checks, each one line naming the file: a bad number or index (with its line), a face of fewer
than 3 or more than 4 corners, a corner repeated in a face, a degenerate face (area below
``DEGENERATE_AREA`` × the squared mean edge), an edge shared by more than two faces
(non-manifold), vertices in no face (they would be massless particles). Faces whose shared
edges run the same way (inconsistent winding) are reported by ``winding_conflicts`` as a
warning: the physics does not depend on the winding, the rendering's normals do.
"""

from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from taichi_cloth.errors import InputError

DEGENERATE_AREA = 1e-8  # of the squared mean edge length: a face smaller is degenerate


@dataclass(frozen=True)
class ObjMesh:
    """An OBJ's polygons: positions (N, 3) as in the file; faces (F, 4) vertex indices, −1 in
    the fourth column of a triangle; face_uvs (F, 4) indices into ``uvs`` per corner (−1 where
    a corner has none); uvs (M, 2); groups: name of a ``g`` or ``o`` → the sorted vertex indices
    of its faces."""

    positions: np.ndarray
    faces: np.ndarray
    face_uvs: np.ndarray
    uvs: np.ndarray
    groups: dict = field(default_factory=dict)

    @property
    def has_uvs(self) -> bool:
        return bool(len(self.uvs)) and bool(np.all(self.face_uvs[self.faces >= 0] >= 0))

    def triangles(self) -> tuple[np.ndarray, np.ndarray]:
        """(T, 3) vertex and (T, 3) texture indices: a quad (a, b, c, d) is split along a–c
        into (a, b, c) and (a, c, d), triangles in face order, each quad's pair in place."""
        quads = self.faces[:, 3] >= 0
        first = np.concatenate([self.faces[:, :3], self.face_uvs[:, :3]], axis=1)
        second = np.concatenate([self.faces[:, [0, 2, 3]], self.face_uvs[:, [0, 2, 3]]], axis=1)
        both = np.stack([first, second], axis=1)  # (F, 2, 6)
        keep = np.stack([np.ones(len(quads), bool), quads], axis=1)
        rows = both[keep]
        return rows[:, :3].astype(np.int32), rows[:, 3:].astype(np.int32)


def _index(text: str, count: int, path: Path, number: int, what: str) -> int:
    """A 1-based (or negative, counting back) OBJ index into ``count`` items, 0-based."""
    try:
        value = int(text)
    except ValueError:
        raise InputError(f"{path}:{number}: {what} index {text!r} is not an integer") from None
    index = value - 1 if value > 0 else count + value
    if value == 0 or not 0 <= index < count:
        raise InputError(f"{path}:{number}: {what} index {value} is outside the {count} "
                         f"{what}s read so far")
    return index


def _numbers(parts: list, count: int, path: Path, number: int) -> list:
    try:
        values = [float(text) for text in parts[:count]]
    except ValueError:
        raise InputError(f"{path}:{number}: {' '.join(parts)!r} is not {count} numbers") from None
    if len(values) < count or not all(np.isfinite(values)):
        raise InputError(f"{path}:{number}: needs {count} finite numbers, got "
                         f"{' '.join(parts)!r}")
    return values


def read_obj(path: Path) -> ObjMesh:
    """The polygons of the OBJ file at ``path``, checked (module docstring); InputError."""
    try:
        lines = path.read_text(encoding="utf-8", errors="replace").splitlines()
    except OSError as error:
        raise InputError(f"{path}: cannot read: {error.strerror or error}") from None
    positions, uvs, faces, face_uvs, face_groups = [], [], [], [], []
    names: tuple = ()
    for number, line in enumerate(lines, start=1):
        parts = line.split("#", 1)[0].split()
        if not parts:
            continue
        keyword, rest = parts[0], parts[1:]
        if keyword == "v":
            positions.append(_numbers(rest, 3, path, number))
        elif keyword == "vt":
            uvs.append(_numbers(rest, 2, path, number))
        elif keyword in ("g", "o"):
            names = tuple(rest) if keyword == "g" else (" ".join(rest),)
        elif keyword == "f":
            if not 3 <= len(rest) <= 4:
                raise InputError(f"{path}:{number}: a face of {len(rest)} corners; garments "
                                 f"are triangles and quads (triangulate the rest, e.g. "
                                 f"Blender's Triangulate Faces)")
            corners = [text.split("/") for text in rest]
            vertex = [_index(c[0], len(positions), path, number, "vertex") for c in corners]
            texture = [_index(c[1], len(uvs), path, number, "texture coordinate")
                       if len(c) > 1 and c[1] else -1 for c in corners]
            if len(set(vertex)) < len(vertex):
                raise InputError(f"{path}:{number}: a face repeats a vertex (degenerate)")
            faces.append(vertex + [-1] * (4 - len(vertex)))
            face_uvs.append(texture + [-1] * (4 - len(texture)))
            face_groups.append(names)
    if not faces:
        raise InputError(f"{path}: no faces (f lines): not a garment mesh")
    mesh = ObjMesh(np.array(positions, float), np.array(faces, np.int64),
                   np.array(face_uvs, np.int64), np.array(uvs, float).reshape(-1, 2),
                   group_vertices(np.array(faces, np.int64), face_groups))
    check_mesh(mesh, path)
    return mesh


def group_vertices(faces: np.ndarray, face_groups: list) -> dict:
    """Group name → sorted vertex indices of the faces that name it."""
    members: dict = {}
    for face, names in zip(faces, face_groups):
        for name in names:
            members.setdefault(name, set()).update(int(v) for v in face if v >= 0)
    return {name: np.array(sorted(vertices), np.int64) for name, vertices in members.items()}


def face_edges(faces: np.ndarray) -> np.ndarray:
    """Every face's boundary edges as directed pairs (E, 2) in winding order."""
    edges = []
    for corner in range(4):
        following = faces[:, (corner + 1) % 4]
        if corner == 2:  # a triangle closes from its third corner to its first
            following = np.where(following < 0, faces[:, 0], following)
        if corner == 3:
            following = faces[:, 0]
        edges.append(np.stack([faces[:, corner], following], axis=1))
    edges = np.concatenate(edges)
    return edges[edges[:, 0] >= 0]


def check_mesh(mesh: ObjMesh, path: Path) -> None:
    """InputError for degenerate faces, non-manifold edges and vertices in no face."""
    used = np.zeros(len(mesh.positions), bool)
    used[mesh.faces[mesh.faces >= 0]] = True
    if not used.all():
        loose = np.flatnonzero(~used)
        raise InputError(f"{path}: {len(loose)} vertices are in no face (first: "
                         f"{loose[0] + 1}); they would be particles without mass")
    edges = face_edges(mesh.faces)
    lengths = np.linalg.norm(mesh.positions[edges[:, 1]] - mesh.positions[edges[:, 0]], axis=1)
    triangles, _ = mesh.triangles()
    p0, p1, p2 = (mesh.positions[triangles[:, k]] for k in range(3))
    area = 0.5 * np.linalg.norm(np.cross(p1 - p0, p2 - p0), axis=1)
    small = np.flatnonzero(area <= DEGENERATE_AREA * np.mean(lengths) ** 2)
    if len(small):
        raise InputError(f"{path}: {len(small)} degenerate faces (no area; first: vertices "
                         f"{' '.join(str(v + 1) for v in triangles[small[0]])})")
    undirected, counts = np.unique(np.sort(edges, axis=1), axis=0, return_counts=True)
    if counts.max() > 2:
        a, b = undirected[np.argmax(counts)] + 1
        raise InputError(f"{path}: the edge between vertices {a} and {b} is shared by "
                         f"{counts.max()} faces: a garment must be a manifold surface")


def winding_conflicts(mesh: ObjMesh) -> int:
    """The number of interior edges whose two faces run along it the same way."""
    _, counts = np.unique(face_edges(mesh.faces), axis=0, return_counts=True)
    return int(np.count_nonzero(counts > 1))


def count_vertices(path: Path) -> int:
    """The number of ``v`` lines (for the memory estimate before anything is built)."""
    try:
        with open(path, encoding="utf-8", errors="replace") as handle:
            return sum(1 for line in handle if line.startswith("v "))
    except OSError as error:
        raise InputError(f"{path}: cannot read: {error.strerror or error}") from None
