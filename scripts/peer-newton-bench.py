#!/usr/bin/env python3
"""Peer benchmark: NVIDIA newton's semi-implicit (symplectic Euler) cloth step on the CPU.

Not part of taichi_cloth: a measuring aid for docs/performance.md, run in a venv of its own so
the project never depends on newton:

    python3 -m venv /tmp/peers && /tmp/peers/bin/pip install newton==1.8.0
    /tmp/peers/bin/python scripts/peer-newton-bench.py --sizes 32 64 128 256

(newton 1.8.0 pulls warp-lang 1.19.0 and numpy; no torch, no CUDA needed).

Reference problem (``peer_reference.py`` beside this script), identical to taichi_cloth's ``bench`` (taichi_cloth/studies/bench.py, REFERENCE_MATERIAL,
garment.py, materials.py), rebuilt here in NumPy so this script needs nothing from that project:

- n × n particles 0.01 m apart, horizontal in the x–z plane at y = 1.0 m:
  x = linspace(-w/2, w/2, n), z = linspace(0, w, n) - w/2, w = 0.01 (n - 1); index = row·n + column.
- row 0 (the n particles at z = -w/2) pinned: zero inverse mass (newton: mass 0 -> inv_mass 0 and
  gravity is masked off for inv_mass == 0, so they stay at rest like ours).
- masses lumped from the two triangles per cell: m_i = ρ Σ_{t∋i} area_t / 3, ρ = 0.13 kg/m²
  -> 1.3e-5 kg inside, 6.5e-6 kg on edges, 2.1667e-6 / 4.3333e-6 kg at corners (as ours).
- springs in our order: stretch (row, column neighbours), shear (both diagonals), bend (skip-one
  along rows and columns); 12 per interior particle; no damping (kd = 0).
- per-spring stiffness from taichi_cloth.config.materials.spring_constants(REFERENCE_MATERIAL, 0.01, 0.01)
  = SpringConstants(stretch_x=10.0, stretch_z=10.0, shear=2.0, bend=1.0) [N/m]
  (stretch k = k_m·dz/dx = 10; shear k = G(dx²+dz²)/(2dxdz) = 2; bend k = B/(dx·dz) = 1e-4/1e-4 = 1).
  newton's eval_spring (solvers/semi_implicit/kernels_particle.py) applies
  f_i = -ke (l - L) (x_i - x_j)/l - kd ..., i.e. ke in N/m exactly like ours
  f_i = k (l - L)/l · (x_j - x_i), so ke = our k with no conversion.
- gravity 9.81 m/s² along -y (ModelBuilder(up_axis=Y), default gravity -9.81 along up), float32,
  dt = 1/1920 s, no contact: particle radius 0 so finalize() creates no particle hash grid
  (model.particle_grid is also forced to None), no shapes/bodies, no triangles, contacts=None,
  enable_tri_contact=False.

One substep = state_0.clear_forces(); solver.step(state_0, state_1, control, None, dt); swap —
the loop newton's own examples run. On the CPU, warp launches each kernel from Python and runs
it as a serial loop in the calling thread (warp/_src/codegen.py cpu_module_template_forward:
``for (task_index = 0; task_index < dim->size; ++task_index)``), so newton runs single-threaded
on CPU; the measured process-CPU-time / wall-time ratio is printed as a check.

Timing like ours (``peer_reference.median_rate``): a warm-up batch (compiles kernels, excluded) +
one more batch, then ``--repeats`` repeats of at least ``--seconds`` each of batches of
max(1, min(256, round(2e6 / N))) substeps; the median repeat is reported.
"""

import json
import os
import platform
import sys
import time

import numpy as np
import warp as wp
from peer_reference import (DT_S, HEIGHT_M, STIFFNESS, median_rate, numpy_reference,
                            peer_arguments, reference_sheet)

wp.config.quiet = True  # before newton imports (and initialises) warp

import newton  # noqa: E402

def build_model(n: int):
    positions, mass, pinned, springs = reference_sheet(n)
    builder = newton.ModelBuilder(up_axis=newton.Axis.Y)  # gravity -9.81 along +y up
    builder.add_particles(
        pos=[tuple(map(float, p)) for p in positions],
        vel=[(0.0, 0.0, 0.0)] * len(positions),
        mass=[0.0 if pin else float(m) for m, pin in zip(mass, pinned)],
        radius=[0.0] * len(positions),  # no particle-particle contact (no hash grid)
    )
    for family, pairs in springs.items():
        ke = STIFFNESS[family]
        for i, j in pairs:
            builder.add_spring(int(i), int(j), ke, 0.0, 0.0)  # kd = 0, control unused
    model = builder.finalize(device="cpu")
    model.particle_grid = None  # documented way to switch off eval_particle_contact
    return model, positions, mass, pinned, springs


class NewtonCloth:
    def __init__(self, n: int):
        started = time.perf_counter()
        self.n = n
        self.model, self.positions, self.mass, self.pinned, self.springs = build_model(n)
        self.build_seconds = time.perf_counter() - started
        self.solver = newton.solvers.SolverSemiImplicit(self.model, enable_tri_contact=False)
        self.state_0 = self.model.state()
        self.state_1 = self.model.state()
        self.control = self.model.control()

    def substeps(self, count: int, dt: float = DT_S):
        for _ in range(count):
            self.state_0.clear_forces()
            self.solver.step(self.state_0, self.state_1, self.control, None, dt)
            self.state_0, self.state_1 = self.state_1, self.state_0
        wp.synchronize_device("cpu")

    def x(self):
        return self.state_0.particle_q.numpy()


def check(n: int, simulated: float) -> dict:
    cloth = NewtonCloth(n)
    steps = round(simulated / DT_S)
    cloth.substeps(steps)
    x = cloth.x()
    xr, x0 = numpy_reference(n, steps)  # NumPy oracle of our formula on the same sheet
    free = x[-n:]
    return {
        "check_size": n, "simulated_s": steps * DT_S, "substeps": steps,
        "finite": bool(np.isfinite(x).all()),
        "free_edge_mean_y": float(free[:, 1].mean()),
        "fell": bool(free[:, 1].mean() < HEIGHT_M),
        "pinned_edge_max_move": float(np.abs(x[:n] - x0[:n]).max()),
        "numpy_oracle_free_edge_mean_y": float(xr[-n:, 1].mean()),
        "max_abs_diff_vs_numpy_oracle_m": float(np.abs(x - xr).max()),
        "springs": int(cloth.model.spring_count),
        "particles": int(cloth.model.particle_count),
        "gravity": [float(g) for g in cloth.model.gravity.numpy().reshape(-1)[:3]],
    }


def bench(n: int, seconds: float, repeats: int) -> dict:
    cloth = NewtonCloth(n)
    timing = median_rate(cloth.substeps, n * n, seconds, repeats)
    return {
        "benchmark": "reference", "simulator": "newton", "integrator": "SolverSemiImplicit",
        "device": "cpu", "size": n, "particles": n * n, "springs": int(cloth.model.spring_count),
        **timing, "dt": DT_S, "finite": bool(np.isfinite(cloth.x()).all()),
        "build_seconds": round(cloth.build_seconds, 3),
        "newton": newton.__version__, "warp": wp.config.version,
    }


def main():
    args = peer_arguments(__doc__.splitlines()[0])

    wp.init()
    print(f"newton {newton.__version__}, warp {wp.config.version} (mode {wp.config.mode}), "
          f"python {platform.python_version()}, {os.cpu_count()} logical CPUs; "
          "warp CPU kernels run as a serial loop in the calling thread (1 thread)")

    if not args.no_check:
        result = check(args.check_size, args.check_seconds)
        print(f"check {result['check_size']}x{result['check_size']} after "
              f"{result['simulated_s']:.4f} s: finite={result['finite']}, free-edge mean y = "
              f"{result['free_edge_mean_y']:.6f} m (fell={result['fell']}), NumPy oracle "
              f"{result['numpy_oracle_free_edge_mean_y']:.6f} m, max |x - oracle| = "
              f"{result['max_abs_diff_vs_numpy_oracle_m']:.3g} m, pinned moved "
              f"{result['pinned_edge_max_move']:.3g} m, gravity {result['gravity']}")
        print(json.dumps({"check": result}))

    print(f"{'size':>6} {'particles':>10} {'substeps/s':>12} {'particle-substeps/s':>20}")
    for n in args.sizes:
        row = bench(n, args.seconds, args.repeats)
        print(f"{n:>6} {row['particles']:>10} {row['substeps_per_second']:>12.1f} "
              f"{row['particle_substeps_per_second']:>20.4g}")
        print(json.dumps(row), flush=True)


if __name__ == "__main__":
    sys.exit(main())
