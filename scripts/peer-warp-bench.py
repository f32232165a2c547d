#!/usr/bin/env python3
"""Peer benchmark: a hand-written NVIDIA Warp kernel for the reference sheet's symplectic Euler
substep on the CPU.

Not part of taichi_cloth: a measuring aid for docs/performance.md, run in a venv of its own so
the project never depends on Warp:

    python3 -m venv /tmp/peers && /tmp/peers/bin/pip install warp-lang==1.19.0 numpy
    /tmp/peers/bin/python scripts/peer-warp-bench.py --sizes 32 64 128 256

Where ``peer-newton-bench.py`` runs newton's general solver (a force kernel per force kind with
atomic adds into a force array, then an integration kernel, each launched from Python), this is
what a Warp user would write for this one problem: one kernel per substep in which each particle
gathers its own springs through a CSR list of its neighbours (no atomics) and updates itself,
x and v read from one buffer and written to the other; the two launches of the ping-pong are
recorded once (``wp.launch(..., record_cmd=True)``) and replayed, the cheapest way Warp offers to
launch a kernel again from Python. The reference problem and the NumPy step it is checked against
are ``peer_reference.py``'s (the same sheet, springs, masses, gravity, f32 and dt as taichi_cloth's
``bench``). Warp runs a CPU kernel as a serial loop in the calling thread, so this is one thread.
"""

import json
import os
import platform
import sys

import numpy as np
import warp as wp
from peer_reference import (DT_S, GRAVITY, HEIGHT_M, median_rate, numpy_reference,
                            peer_arguments, reference_sheet, spring_arrays)

wp.config.quiet = True


@wp.kernel
def symplectic_substep(x: wp.array(dtype=wp.vec3), v: wp.array(dtype=wp.vec3),
                       x_out: wp.array(dtype=wp.vec3), v_out: wp.array(dtype=wp.vec3),
                       start: wp.array(dtype=wp.int32), neighbour: wp.array(dtype=wp.int32),
                       rest: wp.array(dtype=wp.float32), stiffness: wp.array(dtype=wp.float32),
                       inv_mass: wp.array(dtype=wp.float32), gravity: wp.vec3, h: wp.float32):
    """f_i = Σ_j k (l − L)/l (x_j − x_i) over i's springs; v' = v + h (f/m + g), x' = x + h v';
    pinned particles (inverse mass 0) stay."""
    i = wp.tid()
    xi = x[i]
    force = wp.vec3(0.0)
    for k in range(start[i], start[i + 1]):
        d = x[neighbour[k]] - xi
        length = wp.length(d)
        force += stiffness[k] * (length - rest[k]) / length * d
    w = inv_mass[i]
    if w == 0.0:
        v_out[i] = wp.vec3(0.0)
        x_out[i] = xi
    else:
        velocity = v[i] + h * (w * force + gravity)
        v_out[i] = velocity
        x_out[i] = xi + h * velocity


class WarpCloth:
    """The reference sheet of n × n particles on Warp's CPU device, stepped by recorded
    launches of ``symplectic_substep``."""

    def __init__(self, n: int):
        positions, mass, pinned, springs = reference_sheet(n)
        first, second, rest, stiffness = spring_arrays(positions, springs)
        owner = np.concatenate([first, second])
        order = np.argsort(owner, kind="stable")
        other = np.concatenate([second, first])[order].astype(np.int32)
        start = np.searchsorted(owner[order], np.arange(n * n + 1)).astype(np.int32)
        device = "cpu"
        arrays = {name: wp.array(values, dtype=dtype, device=device) for name, values, dtype in (
            ("start", start, wp.int32), ("neighbour", other, wp.int32),
            ("rest", np.concatenate([rest, rest])[order], wp.float32),
            ("stiffness", np.concatenate([stiffness, stiffness])[order], wp.float32),
            ("inv_mass", np.where(pinned, 0.0, 1.0 / mass).astype(np.float32), wp.float32))}
        self.x = [wp.array(positions.astype(np.float32), dtype=wp.vec3, device=device)
                  for _ in range(2)]
        self.v = [wp.zeros(n * n, dtype=wp.vec3, device=device) for _ in range(2)]
        self.current = 0
        self.launches = [wp.launch(symplectic_substep, dim=n * n, inputs=[
            self.x[a], self.v[a], self.x[1 - a], self.v[1 - a], arrays["start"],
            arrays["neighbour"], arrays["rest"], arrays["stiffness"], arrays["inv_mass"],
            wp.vec3(0.0, -GRAVITY, 0.0), DT_S], device=device, record_cmd=True) for a in (0, 1)]

    def substeps(self, count: int):
        for _ in range(count):
            self.launches[self.current].launch()
            self.current = 1 - self.current
        wp.synchronize_device("cpu")

    def positions(self) -> np.ndarray:
        return self.x[self.current].numpy()


def check(n: int, simulated: float) -> dict:
    cloth = WarpCloth(n)
    steps = round(simulated / DT_S)
    cloth.substeps(steps)
    x = cloth.positions()
    reference, start = numpy_reference(n, steps)
    return {"check_size": n, "substeps": steps, "finite": bool(np.isfinite(x).all()),
            "fell": bool(x[-n:, 1].mean() < HEIGHT_M),
            "pinned_edge_max_move": float(np.abs(x[:n] - start[:n]).max()),
            "max_abs_diff_vs_numpy_oracle_m": float(np.abs(x - reference).max())}


def main():
    args = peer_arguments(__doc__.splitlines()[0])
    wp.init()
    print(f"warp {wp.config.version} (mode {wp.config.mode}), python "
          f"{platform.python_version()}, {os.cpu_count()} logical CPUs; one thread")
    if not args.no_check:
        print(json.dumps({"check": check(args.check_size, args.check_seconds)}))
    print(f"{'size':>6} {'particles':>10} {'substeps/s':>12} {'particle-substeps/s':>20}")
    for n in args.sizes:
        cloth = WarpCloth(n)
        row = {"benchmark": "reference", "simulator": "warp (hand-written)",
               "integrator": "symplectic", "device": "cpu", "size": n, "particles": n * n,
               **median_rate(cloth.substeps, n * n, args.seconds, args.repeats), "dt": DT_S,
               "finite": bool(np.isfinite(cloth.positions()).all()), "warp": wp.config.version}
        print(f"{n:>6} {n * n:>10} {row['substeps_per_second']:>12.1f} "
              f"{row['particle_substeps_per_second']:>20.4g}")
        print(json.dumps(row), flush=True)


if __name__ == "__main__":
    sys.exit(main())
