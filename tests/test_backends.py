"""Backends agree: the same small scene simulated on the CPU (this session's runtime) and on
Vulkan (a fresh process: Mesa's lavapipe where there is no GPU, as in CI) gives the same
trajectory within float32 rounding with an explicit integrator. (A whole frame used to run in one
serialized launch on Vulkan too, whose GPU-style loops ran the substeps side by side: the sheet
barely fell, exit 0.) The implicit integrator, whose CG breaks down at random on Vulkan, is
refused there with exit 2 rather than run."""

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from taichi_cloth import cli

REPO = Path(__file__).resolve().parent.parent
FRAMES = 10
POSITION_TOLERANCE = 1e-5  # m: float32 rounding over ten frames of a 1 m sheet
ENERGY_TOLERANCE = 1e-3  # relative


def frames_of(folder: Path) -> list[dict]:
    return json.loads((folder / "stats.json").read_text())["per_frame"]


def run_on_vulkan(overrides: list[str], out: Path) -> subprocess.CompletedProcess:
    return subprocess.run(
        [sys.executable, "-m", "taichi_cloth", "simulate", "sheet", "--arch", "vulkan",
         "--frames", str(FRAMES), "--quiet", "--out", str(out),
         *[item for override in overrides for item in ("--set", override)]],
        cwd=REPO, capture_output=True, text=True, timeout=300)


@pytest.mark.parametrize("integrator", ["symplectic"])
def test_cpu_and_vulkan_trajectories_agree(integrator, tmp_path):
    overrides = ["cloth.resolution=[12,12]", f"simulation.integrator={integrator}"]
    assert cli.simulate("sheet", overrides, FRAMES, str(tmp_path / "cpu"), None, True) == 0
    result = run_on_vulkan(overrides, tmp_path / "vulkan")
    if result.returncode == 2 and "vulkan" in result.stderr and not os.environ.get("CI"):
        pytest.skip(result.stderr.strip())
    assert result.returncode == 0, result.stderr
    cpu, vulkan = frames_of(tmp_path / "cpu"), frames_of(tmp_path / "vulkan")
    assert len(cpu) == len(vulkan) == FRAMES + 1
    drop = cpu[0]["center_of_mass"][1] - min(f["center_of_mass"][1] for f in cpu)
    assert drop > 1e-3  # the sheet really falls: a backend that did not move it would differ
    for here, there in zip(cpu, vulkan):
        np.testing.assert_allclose(there["center_of_mass"], here["center_of_mass"],
                                   atol=POSITION_TOLERANCE)
        assert there["kinetic_energy"] == pytest.approx(here["kinetic_energy"],
                                                        rel=ENERGY_TOLERANCE, abs=1e-9)


def test_the_implicit_integrator_is_refused_off_the_cpu(tmp_path):
    result = run_on_vulkan(["simulation.integrator=implicit"], tmp_path / "out")
    assert result.returncode == 2
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1 and "simulation.arch" in lines[0] and "implicit" in lines[0]
    assert not (tmp_path / "out").exists()
