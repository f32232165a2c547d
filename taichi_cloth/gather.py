"""Gather lists: for every particle, the CSR list of the items it belongs to (springs, triangles,
bending stencils). Every per-particle force sums over its own list in a fixed order, never
scattering with atomic adds, so a run is bit-reproducible on the CPU."""

import numpy as np


def scatter_sum(index: np.ndarray, values: np.ndarray, count: int) -> np.ndarray:
    """Σ of the rows of ``values`` (K, C) by ``index`` (K,) into (count, C): the sums of
    ``np.add.at`` (to rounding: bincount adds in float64), one ``np.bincount`` per column (~10×
    faster, for the host-side estimates run at start-up)."""
    return np.stack([np.bincount(index, values[:, c], minlength=count)
                     for c in range(values.shape[1])], axis=1)


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


def incidence_lists(items: np.ndarray, particle_count: int):
    """CSR lists of the items (rows of ``items`` (M, k), each k particle indices) around each
    particle: (start (N+1,), item (K,), slot (K,)), slot the particle's column in its item.
    Entries of one particle keep item order (a stable sort), so sums over them are reproducible."""
    owner = items.ravel()
    item = np.repeat(np.arange(len(items)), items.shape[1])
    slot = np.tile(np.arange(items.shape[1]), len(items))
    order = np.argsort(owner, kind="stable")
    start = np.searchsorted(owner[order], np.arange(particle_count + 1)).astype(np.int32)
    return start, item[order].astype(np.int32), slot[order].astype(np.int32)


def triangle_gather_lists(triangles: np.ndarray, particle_count: int):
    """CSR lists of the triangles around each particle: (start (N+1,), triangle (K,))."""
    start, triangle, _ = incidence_lists(triangles, particle_count)
    return start, triangle


def side_lists(start: np.ndarray, neighbor: np.ndarray):
    """A CSR list's entries of each row i, those to a lower neighbour (j < i) first: (entry (K,),
    split (N,)), row i's lower entries ``entry[start[i]:split[i]]`` and the others
    ``entry[split[i]:start[i + 1]]``, each in list order (rows whose neighbours ascend get the
    identity). Gauss–Seidel sweeps read a row's half without walking the other, while sums over
    whole rows keep the list order."""
    count = len(start) - 1
    owner = np.repeat(np.arange(count), np.diff(start))
    upper = neighbor > owner
    entry = np.argsort(2 * owner + upper, kind="stable").astype(np.int32)
    split = start[:-1] + np.bincount(owner[~upper], minlength=count)
    return entry, split.astype(np.int32)
