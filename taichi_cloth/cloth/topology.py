"""Connectivity of a grid cloth, in NumPy: the spring pairs of each family (seed §2.1, Fig. 1),
the triangles, the lumped particle masses, and the bending stencils (hinges) of any triangle
mesh. The per-particle gather lists over them are in ``gather.py``."""

import numpy as np


def grid_springs(columns: int, rows: int, periodic: bool) -> dict:
    """Spring index pairs per family for a columns × rows grid (periodic: columns wrap)."""
    index = np.arange(rows * columns).reshape(rows, columns)

    def pairs(row_step: int, column_step: int) -> np.ndarray:
        row_end = rows - row_step
        if periodic:
            a = index[:row_end, :]
            b = np.roll(index, -column_step, axis=1)[row_step:, :]
        elif column_step >= 0:
            a = index[:row_end, :columns - column_step]
            b = index[row_step:, column_step:]
        else:
            a = index[:row_end, -column_step:]
            b = index[row_step:, :columns + column_step]
        return np.stack([a.ravel(), b.ravel()], axis=1).astype(np.int32)

    return {
        "stretch": np.concatenate([pairs(0, 1), pairs(1, 0)]),
        "shear": np.concatenate([pairs(1, 1), pairs(1, -1)]),
        "bend": np.concatenate([pairs(0, 2), pairs(2, 0)]),
    }


def grid_triangles(columns: int, rows: int, periodic: bool) -> np.ndarray:
    """Two triangles per cell, (T,3) int32."""
    index = np.arange(rows * columns).reshape(rows, columns)
    right = np.roll(index, -1, axis=1) if periodic else index[:, 1:]
    left = index if periodic else index[:, :-1]
    top_left, top_right = left[:-1], right[:-1]
    bottom_left, bottom_right = left[1:], right[1:]
    first = np.stack([top_left, bottom_left, bottom_right], axis=-1).reshape(-1, 3)
    second = np.stack([top_left, bottom_right, top_right], axis=-1).reshape(-1, 3)
    triangles = np.concatenate([first, second]).astype(np.int32)
    # A skirt's rows run down and its columns counter-clockwise seen from above, which winds the
    # sheet's triangles inwards on the cone: reverse them so that normals point outwards.
    return triangles[:, [0, 2, 1]] if periodic else triangles


def lumped_mass(positions: np.ndarray, triangles: np.ndarray, density: float) -> np.ndarray:
    """m_i = ρ · Σ_{triangles t ∋ i} area_t / 3 [kg]."""
    p0, p1, p2 = (positions[triangles[:, k]] for k in range(3))
    area = 0.5 * np.linalg.norm(np.cross(p1 - p0, p2 - p0), axis=1)
    mass = np.zeros(len(positions))
    for k in range(3):
        np.add.at(mass, triangles[:, k], density * area / 3.0)
    return mass


def hinge_stencils(triangles: np.ndarray) -> np.ndarray:
    """The bending stencils of a triangle mesh: for every interior edge (shared by exactly two
    triangles) its vertices (x0, x1) and the two opposite vertices (x2 of the first triangle,
    x3 of the second), shape (H, 4), in the order the edges first appear."""
    first_seen = {}
    stencils = []
    for triangle in triangles:
        for corner in range(3):
            a, b, opposite = triangle[corner], triangle[(corner + 1) % 3], triangle[(corner + 2) % 3]
            key = (min(a, b), max(a, b))
            if key in first_seen:
                edge_a, edge_b, other = first_seen.pop(key)
                stencils.append((edge_a, edge_b, other, opposite))
            else:
                first_seen[key] = (a, b, opposite)
    return np.array(stencils, dtype=np.int32).reshape(-1, 4)


def triangle_edges(triangles: np.ndarray) -> np.ndarray:
    """The mesh's edges (E, 2), each once, lower index first, sorted."""
    pairs = np.concatenate([triangles[:, [0, 1]], triangles[:, [1, 2]], triangles[:, [2, 0]]])
    return np.unique(np.sort(pairs, axis=1), axis=0)
