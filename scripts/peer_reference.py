"""The reference problem of taichi_cloth's ``bench`` rebuilt in NumPy for the peer benchmarks
(``peer-newton-bench.py``, ``peer-warp-bench.py``), which run in a venv of their own and import
nothing from the project, plus the NumPy step both check their peer against and the timing loop
both use (the same as ``bench``'s: the median of repeats of at least ``seconds``).

See ``peer-newton-bench.py``'s docstring for how each constant follows from the project's scene.
"""

import argparse
import statistics
import time

import numpy as np

SPACING_M = 0.01
DT_S = 1.0 / 1920.0
HEIGHT_M = 1.0
DENSITY = 0.13  # kg/m²
GRAVITY = 9.81
# Per-spring stiffness [N/m], from taichi_cloth.config.materials.spring_constants(REFERENCE_MATERIAL,
# 0.01, 0.01) computed with the project's venv: stretch_x = stretch_z = 10.0, shear = 2.0, bend = 1.0.
STIFFNESS = {"stretch": 10.0, "shear": 2.0, "bend": 1.0}


def grid_springs(n: int) -> dict:
    """Spring index pairs per family, same order as taichi_cloth.garment.grid_springs."""
    index = np.arange(n * n).reshape(n, n)

    def pairs(row_step, column_step):
        row_end = n - row_step
        if column_step >= 0:
            a = index[:row_end, :n - column_step]
            b = index[row_step:, column_step:]
        else:
            a = index[:row_end, -column_step:]
            b = index[row_step:, :n + column_step]
        return np.stack([a.ravel(), b.ravel()], axis=1).astype(np.int32)

    return {
        "stretch": np.concatenate([pairs(0, 1), pairs(1, 0)]),
        "shear": np.concatenate([pairs(1, 1), pairs(1, -1)]),
        "bend": np.concatenate([pairs(0, 2), pairs(2, 0)]),
    }


def reference_sheet(n: int):
    """positions (N,3) float64, masses (N,), pinned (N,) bool, springs {family: (S,2)}."""
    side = SPACING_M * (n - 1)
    x = np.linspace(-side / 2, side / 2, n)
    along = np.linspace(0.0, side, n)
    xx, aa = np.meshgrid(x, along)
    positions = np.stack([xx, np.full_like(xx, HEIGHT_M), aa - side / 2], axis=-1).reshape(-1, 3)
    index = np.arange(n * n).reshape(n, n)
    tl, tr, bl, br = index[:-1, :-1], index[:-1, 1:], index[1:, :-1], index[1:, 1:]
    triangles = np.concatenate([np.stack([tl, bl, br], -1).reshape(-1, 3),
                                np.stack([tl, br, tr], -1).reshape(-1, 3)])
    p0, p1, p2 = (positions[triangles[:, k]] for k in range(3))
    area = 0.5 * np.linalg.norm(np.cross(p1 - p0, p2 - p0), axis=1)
    mass = np.zeros(n * n)
    for k in range(3):
        np.add.at(mass, triangles[:, k], DENSITY * area / 3.0)
    pinned = np.zeros(n * n, bool)
    pinned[:n] = True
    return positions, mass, pinned, grid_springs(n)


def numpy_step(x, v, first, second, rest, k, inv_mass, weight, h):
    """taichi_cloth.bench.NumpyCloth.step (float32), the oracle for the check below."""
    d = x[second] - x[first]
    length = np.sqrt(np.einsum("sk,sk->s", d, d))
    spring = (k * (length - rest) / length)[:, None] * d
    total = weight.copy()
    for c in range(3):
        total[:, c] += (np.bincount(first, spring[:, c], len(x))
                        - np.bincount(second, spring[:, c], len(x))).astype(np.float32)
    v_new = v + h * inv_mass[:, None] * total
    v_new[inv_mass == 0] = 0.0
    return x + h * v_new, v_new


def spring_arrays(positions: np.ndarray, springs: dict):
    """(first, second, rest length, stiffness) of every spring, families in order, float32."""
    first = np.concatenate([p[:, 0] for p in springs.values()])
    second = np.concatenate([p[:, 1] for p in springs.values()])
    stiffness = np.concatenate([np.full(len(p), STIFFNESS[f], np.float32)
                                for f, p in springs.items()])
    rest = np.linalg.norm(positions[second] - positions[first], axis=1).astype(np.float32)
    return first, second, rest, stiffness


def numpy_reference(n: int, steps: int) -> tuple[np.ndarray, np.ndarray]:
    """The sheet's positions after ``steps`` NumPy substeps (float32) and its start positions."""
    positions, mass, pinned, springs = reference_sheet(n)
    first, second, rest, stiffness = spring_arrays(positions, springs)
    x0 = positions.astype(np.float32)
    inv_mass = np.where(pinned, 0.0, 1.0 / mass).astype(np.float32)
    weight = np.zeros_like(x0)
    weight[:, 1] = -GRAVITY * mass
    x, v = x0, np.zeros_like(x0)
    for _ in range(steps):
        x, v = numpy_step(x, v, first, second, rest, stiffness, inv_mass, weight,
                          np.float32(DT_S))
    return x, x0


def median_rate(run_substeps, particles: int, seconds: float, repeats: int) -> dict:
    """Substeps per second of ``run_substeps(count)`` (which must finish its work): a warm-up
    batch (compiles), one more, then ``repeats`` repeats of at least ``seconds``; the median,
    the repeats and the process-CPU per wall second of each (1 for one thread)."""
    batch = max(1, min(256, round(2e6 / particles)))
    started = time.perf_counter()
    run_substeps(batch)
    compile_seconds = time.perf_counter() - started
    run_substeps(batch)
    rates, cpu_ratio = [], []
    for _ in range(repeats):
        done, t0, c0 = 0, time.perf_counter(), time.process_time()
        while True:
            run_substeps(batch)
            done += batch
            elapsed = time.perf_counter() - t0
            if elapsed >= seconds:
                break
        cpu_ratio.append((time.process_time() - c0) / elapsed)
        rates.append(done / elapsed)
    rate = statistics.median(rates)
    return {"substeps_per_second": rate, "particle_substeps_per_second": rate * particles,
            "repeats": [round(r, 3) for r in rates], "batch": batch,
            "compile_seconds": round(compile_seconds, 3),
            "process_cpu_per_wall": [round(r, 3) for r in cpu_ratio]}


def peer_arguments(description: str) -> argparse.Namespace:
    """The peer scripts' flags: sizes, the timing and the check against the NumPy step."""
    parser = argparse.ArgumentParser(description=description)
    parser.add_argument("--sizes", type=int, nargs="+", default=[32, 64, 128, 256])
    parser.add_argument("--seconds", type=float, default=1.0, help="minimum length of a repeat")
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--check-size", type=int, default=32)
    parser.add_argument("--check-seconds", type=float, default=0.1, help="simulated time")
    parser.add_argument("--no-check", action="store_true")
    return parser.parse_args()
