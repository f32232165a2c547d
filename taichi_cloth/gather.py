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


def sweep_rows(spring_start: np.ndarray, spring_neighbor: np.ndarray, coupled_rows,
               particle_count: int):
    """The rows of A's off-diagonal entries in the order Gauss–Seidel sweeps read them: each
    particle's springs (gather entries) and the coupled effects' scalar entries H_ij merged,
    each coupled entry folded into the row's first spring to the same neighbour when there is
    one. ``coupled_rows``: per coupled effect (start (N+1,), neighbour (K,), H (K,), β [s]),
    ∂f_i/∂x_j = −H_ij·I and ∂f_i/∂v_j = −β·H_ij·I (``Effect.coupled_rows``).

    Returns (start (N+1,), bounds (N, 3), neighbour (S,), spring (S,), coupled (S, 2)): row i's
    entries ``start[i]:start[i + 1]`` in four runs, cut at ``bounds[i]``: lower neighbours
    (j < i) with a spring, lower ones with only coupled entries, then the same for j > i. An
    entry's ``spring`` is its gather entry (−1: none) and ``coupled`` the sums Σ H_ij and
    Σ β·H_ij [N/m, N·s/m] over the coupled effects. The springs of a run keep their gather
    order, the coupled-only entries their neighbours' order, so the sweeps are reproducible.
    A row's sums then read each spring once and each neighbour that only coupled entries reach
    once, not once per list it is in."""
    count = particle_count
    owner = np.repeat(np.arange(count, dtype=np.int64), np.diff(spring_start))
    neighbor = np.asarray(spring_neighbor, np.int64)
    spring = np.arange(len(neighbor))
    keys = owner * count + neighbor
    spring_keys, first_spring = np.unique(keys, return_index=True)  # each pair's first spring
    coupled_keys, coupled_values = [np.zeros(0, np.int64)], [np.zeros((0, 2))]
    for start, rows_neighbor, value, damping_time in coupled_rows:
        rows_owner = np.repeat(np.arange(count, dtype=np.int64), np.diff(start))
        if (rows_owner == rows_neighbor).any():
            raise ValueError("sweep_rows: a coupled row holds its own diagonal entry")
        coupled_keys.append(rows_owner * count + rows_neighbor)
        coupled_values.append(np.stack([value, damping_time * np.asarray(value)], axis=1))
    pairs, inverse = np.unique(np.concatenate(coupled_keys), return_inverse=True)
    values = np.concatenate(coupled_values)
    sums = np.stack([np.bincount(inverse, values[:, c], len(pairs)) for c in (0, 1)], axis=1)
    found = np.minimum(np.searchsorted(spring_keys, pairs), max(len(spring_keys) - 1, 0))
    folded = spring_keys[found] == pairs if len(spring_keys) else np.zeros(len(pairs), bool)
    coupled = np.zeros((len(neighbor), 2))
    coupled[first_spring[found[folded]]] = sums[folded]  # each pair once: its first spring
    only = pairs[~folded]
    owner = np.concatenate([owner, only // count])
    neighbor = np.concatenate([neighbor, only % count])
    spring = np.concatenate([spring, np.full(len(only), -1)])
    coupled = np.concatenate([coupled, sums[~folded]])
    upper = neighbor > owner
    run = 2 * upper + (spring < 0)
    order = np.lexsort((np.where(spring < 0, neighbor, spring), run, owner))
    owner, run = owner[order], run[order]
    start = np.searchsorted(owner, np.arange(count + 1)).astype(np.int32)
    bounds = np.stack([start[:-1] + np.bincount(owner[run < cut], minlength=count)
                       for cut in (1, 2, 3)], axis=1).astype(np.int32)
    return (start, bounds, neighbor[order].astype(np.int32), spring[order].astype(np.int32),
            coupled[order])
