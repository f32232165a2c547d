"""Connectivity of a grid cloth, in NumPy: the spring pairs of each family (seed §2.1, Fig. 1),
the triangles, the lumped particle masses, and the per-particle gather lists (CSR) through which
every particle sums its own springs and triangles in a fixed order (no atomic adds, so a run is
bit-reproducible on the CPU)."""

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


def gather_lists(pairs: np.ndarray, particle_count: int):
    """CSR lists of what each particle touches: (start (N+1,), item (K,), other (K,)).

    For springs: item = spring index, other = the particle at its other end. Entries of one
    particle keep the order of ``pairs`` (a stable sort), so sums over them are reproducible.
    """
    owner = np.concatenate([pairs[:, 0], pairs[:, 1]])
    item = np.concatenate([np.arange(len(pairs))] * 2)
    other = np.concatenate([pairs[:, 1], pairs[:, 0]])
    order = np.argsort(owner, kind="stable")
    start = np.searchsorted(owner[order], np.arange(particle_count + 1)).astype(np.int32)
    return start, item[order].astype(np.int32), other[order].astype(np.int32)


def triangle_gather_lists(triangles: np.ndarray, particle_count: int):
    """CSR lists of the triangles around each particle: (start (N+1,), triangle (K,))."""
    owner = triangles.ravel()
    triangle = np.repeat(np.arange(len(triangles)), 3)
    order = np.argsort(owner, kind="stable")
    start = np.searchsorted(owner[order], np.arange(particle_count + 1)).astype(np.int32)
    return start, triangle[order].astype(np.int32)
