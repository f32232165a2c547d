"""Backends agree: the same small scene simulated on the CPU (this session's runtime) and on Vulkan
(a fresh process: Mesa's lavapipe where there is no GPU, as in CI) or CUDA (where there is an
NVIDIA GPU; skipped elsewhere) gives the same trajectory within float32 rounding with an explicit
integrator. (A whole frame used to run in one serialized launch on Vulkan too, whose GPU-style
loops ran the substeps side by side: the sheet barely fell, exit 0.) The implicit integrator runs
on CUDA with the block-Jacobi CG (the CPU's is Gauss–Seidel: the two solves agree to their
tolerance, not to rounding). A sheet large enough for the CPU's packed grid (its SIMD pass; GPU
archs gather) is compared with CUDA as well. On Vulkan, where the implicit CG breaks down at
random, that integrator is refused with exit 2 rather than run. (Self-collision is refused on every
GPU arch: tests/test_scene.py.)"""

import json
import math
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from taichi_cloth import cli
from taichi_cloth.physics.packed_grid import PACKED_PARTICLE_MINIMUM

REPO = Path(__file__).resolve().parent.parent
FRAMES = 10
POSITION_TOLERANCE = 1e-5  # m: float32 rounding over ten frames of a 1 m sheet
ENERGY_TOLERANCE = 1e-3  # relative
SOLVE_POSITION_TOLERANCE = 1e-4  # m: two preconditioners, each solve to its CG tolerance
SOLVE_ENERGY_TOLERANCE = 1e-2
# The side of the smallest sheet that steps on the packed grid on the CPU (the springs, dashpots,
# curvature bending and drag's faces in the SIMD pass), against CUDA's gather.
PACKED_SIDE = math.isqrt(PACKED_PARTICLE_MINIMUM - 1) + 1


def frames_of(folder: Path) -> list[dict]:
    return json.loads((folder / "stats.json").read_text())["per_frame"]


def run_on(arch: str, overrides: list[str], out: Path) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-m", "taichi_cloth", "simulate", "sheet", "--arch", arch,
         "--frames", str(FRAMES), "--quiet", "--out", str(out),
         *[item for override in overrides for item in ("--set", override)]],
        cwd=REPO, capture_output=True, text=True, timeout=300)


def skip_without(arch: str, result: subprocess.CompletedProcess) -> None:
    """Skip where the machine has no such device: CUDA anywhere (CI has no GPU), Vulkan only
    outside CI (CI installs lavapipe, so there a missing Vulkan is a failure)."""
    missing = result.returncode == 2 and f"--arch {arch}" in result.stderr
    if missing and (arch == "cuda" or not os.environ.get("CI")):
        pytest.skip(result.stderr.strip())


@pytest.mark.parametrize("arch, integrator, side, position_tolerance, energy_tolerance", [
    ("vulkan", "symplectic", 12, POSITION_TOLERANCE, ENERGY_TOLERANCE),
    ("cuda", "symplectic", 12, POSITION_TOLERANCE, ENERGY_TOLERANCE),
    ("cuda", "symplectic", PACKED_SIDE, POSITION_TOLERANCE, ENERGY_TOLERANCE),
    ("cuda", "implicit", 12, SOLVE_POSITION_TOLERANCE, SOLVE_ENERGY_TOLERANCE),
])
def test_cpu_and_gpu_trajectories_agree(arch, integrator, side, position_tolerance,
                                        energy_tolerance, tmp_path):
    overrides = [f"cloth.resolution=[{side},{side}]", f"simulation.integrator={integrator}"]
    result = run_on(arch, overrides, tmp_path / arch)  # first: where it skips, nothing else runs
    skip_without(arch, result)
    assert result.returncode == 0, result.stderr
    assert cli.simulate("sheet", overrides, FRAMES, str(tmp_path / "cpu"), None, True) == 0
    cpu, gpu = frames_of(tmp_path / "cpu"), frames_of(tmp_path / arch)
    assert len(cpu) == len(gpu) == FRAMES + 1
    drop = cpu[0]["center_of_mass"][1] - min(f["center_of_mass"][1] for f in cpu)
    assert drop > 1e-3  # the sheet really falls: a backend that did not move it would differ
    for here, there in zip(cpu, gpu):
        np.testing.assert_allclose(there["center_of_mass"], here["center_of_mass"],
                                   atol=position_tolerance)
        assert there["kinetic_energy"] == pytest.approx(here["kinetic_energy"],
                                                        rel=energy_tolerance, abs=1e-9)


def test_the_implicit_integrator_is_refused_on_vulkan(tmp_path):
    result = run_on("vulkan", ["simulation.integrator=implicit"], tmp_path / "out")
    assert result.returncode == 2
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and "--arch vulkan" in lines[0] and "implicit" in lines[0]
    assert not (tmp_path / "out").exists()
