"""The pairs of cloth primitives that already lie within the self-collision thickness of each other
in the cloth's rest shape and are neighbours along it: around edges shorter than twice the
thickness (a disc's centre, a garment file's small triangles at a dart or a seam), a vertex and a
triangle it is not a corner of, or two edges that share no particle, may be that close while the
cloth lies flat. Self-collision leaves them out for good (``candidate_pairs.py``;
docs/physics.md, "Self-collision"): pushed apart, they would stretch the cloth in its own plane
from the first step. Layers that start that close (a lining, a garment file's pocket, a sheet
laid over another) are not neighbours: a pair counts as one only when a path along the mesh's
edges joins a particle of one primitive to a particle of the other within twice the thickness
plus the two primitives' longest edge (round a dart or across a thin strip the path is about
the distance itself; between two layers it runs round to where they are sewn, or nowhere).

Found in NumPy once, when self-collision is set up: a grid of cells a little wider than the
largest grown box, each box filed under the (at most 8) cells it meets, every pair sharing a cell
tested for its boxes' overlap and then for its exact distance (the closest points of a point and
a triangle, and of two segments: C. Ericson, "Real-Time Collision Detection", 2005, §5.1.5 and
§5.1.9, as ``proximity.py`` computes them in the kernels); then the paths, shortest first from
every particle of the pairs found (Bellman–Ford's relaxation, all sources at once, no path
followed past the longest such bound)."""

import numpy as np

from taichi_cloth.gather import gather_lists


def rest_neighbours(x: np.ndarray, triangles: np.ndarray, edges: np.ndarray,
                    distance: float) -> tuple[np.ndarray, np.ndarray]:
    """(vertex–triangle pairs (k, 2): a particle and a triangle it is not a corner of; edge–edge
    pairs (k, 2): two edges that share no particle, the lower index first) whose closest points at
    positions x (N, 3) [m] are less than ``distance`` [m] apart and that a path along the edges
    joins within 2·``distance`` plus their longest edge (module docstring), each sorted by
    row."""
    x = np.asarray(x, dtype=np.float64)
    triangle_box = _boxes(x[triangles], distance)
    edge_box = _boxes(x[edges], 0.5 * distance)
    # one grid for all: cells a little wider than the widest box (so that no box meets more
    # than two a side, rounding included), keyed alike in every filing
    cell = 1.001 * max(float((triangle_box[1] - triangle_box[0]).max(initial=0.0)), distance)
    origin = x.min(axis=0) - distance  # (the keys then span the cloth's extent, wherever it is)
    span = int(np.ceil((x.max(axis=0) - origin + distance).max() / cell)) + 2
    grid = (origin, cell, span)
    particle, triangle = _sharing_cells(_filed(np.stack([x, x]), *grid),
                                        _filed(triangle_box, *grid))
    inside = np.all((triangle_box[0][triangle] <= x[particle])
                    & (x[particle] <= triangle_box[1][triangle]), axis=1)
    inside &= np.all(triangles[triangle] != particle[:, None], axis=1)
    particle, triangle = particle[inside], triangle[inside]
    corners = x[triangles[triangle]]
    near = _point_triangle_distance(x[particle], *corners.transpose(1, 0, 2)) < distance
    particle, triangle = particle[near], triangle[near]

    filed = _filed(edge_box, *grid)
    first, second = _sharing_cells(filed, filed)
    keep = (first < second) & np.all((edge_box[0][first] <= edge_box[1][second])
                                     & (edge_box[0][second] <= edge_box[1][first]), axis=1)
    keep &= np.all(edges[first][:, :, None] != edges[second][:, None, :], axis=(1, 2))
    first, second = first[keep], second[keep]
    ends, other = x[edges[first]], x[edges[second]]
    near = _segment_distance(ends[:, 0], ends[:, 1], other[:, 0], other[:, 1]) < distance
    first, second = first[near], second[near]

    # the neighbours among them: a path along the edges within 2·distance + the longest edge
    length = np.linalg.norm(x[edges[:, 0]] - x[edges[:, 1]], axis=1)
    longest_side = np.max(np.linalg.norm(x[triangles] - x[np.roll(triangles, 1, axis=1)],
                                         axis=2), axis=1, initial=0.0)
    within = [2 * distance + longest_side[triangle],
              2 * distance + np.maximum(length[first], length[second])]
    ids = [(particle[:, None], triangles[triangle]), (edges[first], edges[second])]
    sources = np.concatenate([particle, edges[first].ravel()])
    path_keys, path_length = _paths(len(x), edges, length, sources,
                                    max((w.max(initial=0.0) for w in within)))
    joined = [_joined(path_keys, path_length, len(x), *pair, bound)
              for pair, bound in zip(ids, within)]
    return (_sorted_pairs(particle[joined[0]], triangle[joined[0]]),
            _sorted_pairs(first[joined[1]], second[joined[1]]))


def _paths(count: int, edges: np.ndarray, length: np.ndarray, sources: np.ndarray,
           radius: float) -> tuple[np.ndarray, np.ndarray]:
    """(keys source·``count`` + particle, sorted; the shortest path [m] along the edges (of
    ``length``) from each particle of ``sources`` to each particle within ``radius`` [m] of
    it), the mesh having ``count`` particles."""
    row, edge, neighbour = gather_lists(edges, count)  # each particle's edges, both ways
    step = length[edge]
    best_keys = _distinct(sources.astype(np.int64) * count + sources)
    best = np.zeros(len(best_keys))
    frontier_keys, frontier = best_keys, best
    while len(frontier_keys):
        source, at = frontier_keys // count, frontier_keys % count
        counts = row[at + 1] - row[at]
        k = _ranges(row[at], counts)
        keys = np.repeat(source, counts) * count + neighbour[k]
        reached = np.repeat(frontier, counts) + step[k]
        keys, reached = _shortest(keys[reached <= radius], reached[reached <= radius])
        place = np.minimum(np.searchsorted(best_keys, keys), max(len(best_keys) - 1, 0))
        shorter = (best_keys[place] != keys) | (reached < best[place])
        frontier_keys, frontier = keys[shorter], reached[shorter]
        best_keys, best = _shortest(np.concatenate([best_keys, frontier_keys]),
                                    np.concatenate([best, frontier]))
    return best_keys, best


def _shortest(keys: np.ndarray, lengths: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Each distinct key once, sorted, with its least length."""
    order = np.lexsort((lengths, keys))
    keys, lengths = keys[order], lengths[order]
    first = np.concatenate([[True], keys[1:] != keys[:-1]]) if len(keys) else np.zeros(0, bool)
    return keys[first], lengths[first]


def _joined(path_keys: np.ndarray, path_length: np.ndarray, count: int, first: np.ndarray,
            second: np.ndarray, bound: np.ndarray) -> np.ndarray:
    """Whether a path of at most ``bound`` (k,) [m] joins a particle of each pair's first
    primitive (k, a) to one of its second's (k, b): ``_paths``'s from the first's."""
    joined = np.zeros(len(bound), bool)
    for a in range(first.shape[1]):
        for b in range(second.shape[1]):
            keys = first[:, a].astype(np.int64) * count + second[:, b]
            place = np.minimum(np.searchsorted(path_keys, keys), max(len(path_keys) - 1, 0))
            found = (path_keys[place] == keys) if len(path_keys) else np.zeros(len(keys), bool)
            joined |= found & (path_length[place] <= bound)
    return joined


def _boxes(corners: np.ndarray, grow: float) -> np.ndarray:
    """(lower, upper) (2, n, 3) [m] of primitives with corners (n, c, 3), grown by ``grow``."""
    return np.stack([corners.min(axis=1) - grow, corners.max(axis=1) + grow])


def _filed(box: np.ndarray, origin: np.ndarray, cell: float,
           span: int) -> tuple[np.ndarray, np.ndarray]:
    """(cell keys, box indices) of each box (2, n, 3) under every cell it meets: at most two
    a side, the cells (``cell`` [m] wide from ``origin``, ``span`` a side) being wider than the
    boxes; unique pairs."""
    lower = np.floor((box[0] - origin) / cell).astype(np.int64)
    upper = np.floor((box[1] - origin) / cell).astype(np.int64)
    keys, ids = [], []
    for step in np.ndindex(2, 2, 2):
        cells = lower + np.array(step)
        meets = np.all(cells <= upper, axis=1)
        keys.append(((cells[meets, 0] * span) + cells[meets, 1]) * span + cells[meets, 2])
        ids.append(np.flatnonzero(meets))
    count = len(box[0])
    filed = _distinct(np.concatenate(keys) * count + np.concatenate(ids))
    return filed // count, filed % count


def _ranges(starts: np.ndarray, counts: np.ndarray) -> np.ndarray:
    """The indices starts[k], starts[k] + 1, … (counts[k] of them) for every k, in order."""
    return np.repeat(starts, counts) + np.arange(counts.sum()) - np.repeat(
        np.cumsum(counts) - counts, counts)


def _sharing_cells(first: tuple, second: tuple) -> tuple[np.ndarray, np.ndarray]:
    """(i, j): every pair of an entry of ``first`` and one of ``second`` ((cell keys, indices)
    each) filed under the same cell, once however many cells they share."""
    order = np.argsort(second[0], kind="stable")
    keys, ids = second[0][order], second[1][order]
    low = np.searchsorted(keys, first[0], "left")
    counts = np.searchsorted(keys, first[0], "right") - low
    i = np.repeat(first[1], counts)
    j = ids[_ranges(low, counts)]
    count = int(max(second[1].max(initial=0), 0)) + 1
    pairs = _distinct(i * count + j)
    return pairs // count, pairs % count


def _distinct(keys: np.ndarray) -> np.ndarray:
    """The distinct values of ``keys``, sorted (a sort and a comparison: NumPy's ``unique``
    hashes, 8× slower on these)."""
    keys = np.sort(keys)
    return keys[np.concatenate([[True], keys[1:] != keys[:-1]])] if len(keys) else keys


def _sorted_pairs(first: np.ndarray, second: np.ndarray) -> np.ndarray:
    """The pairs (k, 2), sorted by the first index, then the second."""
    pairs = np.stack([first, second], axis=1).astype(np.int64).reshape(-1, 2)
    return pairs[np.lexsort((pairs[:, 1], pairs[:, 0]))]


def _dot(u: np.ndarray, v: np.ndarray) -> np.ndarray:
    return np.einsum("nk,nk->n", u, v)


def _point_triangle_distance(p, a, b, c) -> np.ndarray:
    """|p − q| [m], q the point of triangle (a, b, c) closest to p, each (n, 3) (Ericson §5.1.5:
    the Voronoi regions of the vertices, edges and face, in ``closest_on_triangle``'s order)."""
    ab, ac = b - a, c - a
    d1, d2 = _dot(ab, p - a), _dot(ac, p - a)
    d3, d4 = _dot(ab, p - b), _dot(ac, p - b)
    d5, d6 = _dot(ab, p - c), _dot(ac, p - c)
    va, vb, vc = d3 * d6 - d5 * d4, d5 * d2 - d1 * d6, d1 * d4 - d3 * d2
    with np.errstate(divide="ignore", invalid="ignore"):
        along_ab, along_ac = d1 / (d1 - d3), d2 / (d2 - d6)
        along_bc = (d4 - d3) / ((d4 - d3) + (d5 - d6))
        face_b, face_c = vb / (va + vb + vc), vc / (va + vb + vc)
    zero, one = np.zeros_like(d1), np.ones_like(d1)
    regions = [(d1 <= 0) & (d2 <= 0), (d3 >= 0) & (d4 <= d3), (vc <= 0) & (d1 >= 0) & (d3 <= 0),
               (d6 >= 0) & (d5 <= d6), (vb <= 0) & (d2 >= 0) & (d6 <= 0),
               (va <= 0) & (d4 - d3 >= 0) & (d5 - d6 >= 0)]
    w_b = np.select(regions, [zero, one, along_ab, zero, zero, 1 - along_bc], face_b)
    w_c = np.select(regions, [zero, zero, zero, one, along_ac, along_bc], face_c)
    closest = a + w_b[:, None] * ab + w_c[:, None] * ac
    return np.linalg.norm(p - closest, axis=1)


def _segment_distance(a, b, c, d) -> np.ndarray:
    """The distance [m] between segments (a, b) and (c, d), each (n, 3), of positive length
    (Ericson §5.1.9; parallel segments take s = 0, as ``closest_between_segments``)."""
    d1, d2, r = b - a, d - c, a - c
    aa, ee, f = _dot(d1, d1), _dot(d2, d2), _dot(d2, r)
    cc, bb = _dot(d1, r), _dot(d1, d2)
    denominator = aa * ee - bb * bb
    with np.errstate(divide="ignore", invalid="ignore"):
        s = np.where(denominator > 1e-30 * aa * ee,
                     np.clip((bb * f - cc * ee) / denominator, 0.0, 1.0), 0.0)
        u = (bb * s + f) / ee
    s = np.where(u < 0, np.clip(-cc / aa, 0.0, 1.0),
                 np.where(u > 1, np.clip((bb - cc) / aa, 0.0, 1.0), s))
    u = np.clip(u, 0.0, 1.0)
    return np.linalg.norm((a + s[:, None] * d1) - (c + u[:, None] * d2), axis=1)
