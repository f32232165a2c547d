"""The hard-case library (scenes/hard/): each case run small, checked against its stated bounds.

Every case file says what it stresses and which integrators must pass it; this table holds the
runs and the bounds: a finite state, max strain, max penetration (below the contact thickness plus
a margin of 1 cm) and a bounded energy (mean particle speed √(2·KE/M) below a stated speed).
Cases that push an integrator past its stability limit must end in guarded retries or a clean
exit 3, never in NaN output.
"""

import json
import math
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from taichi_cloth.config.scene import load_scene
from taichi_cloth.physics.simulation import Simulation

HARD = Path(__file__).resolve().parent.parent / "scenes" / "hard"
PENETRATION_MARGIN = 0.01  # m, on top of the contact thickness

# (case, overrides, max strain, max mean speed [m/s])
PASSING_RUNS = [
    ("stiff-denim", (), 0.10, 2.0),
    ("fast-dance", (), 0.10, 3.0),
    ("frame-steps", (), 0.15, 3.0),
    ("gale", (), 0.10, 15.0),
    ("gale", ("simulation.integrator=rk4",), 0.10, 15.0),
    ("gale", ("simulation.integrator=implicit", "simulation.max_retries=0"), 0.10, 15.0),
    ("tight-skirt", (), 0.30, 3.0),
    ("tight-skirt", ("simulation.integrator=implicit", "simulation.dt=0.016667"), 0.30, 3.0),
    ("ball-drape", (), 0.10, 3.0),
    ("fine-mesh", (), 0.10, 2.0),
    ("long-run", (), 0.10, 3.0),
]


def test_every_case_file_is_in_the_table_and_documents_itself():
    cases = {path.stem for path in HARD.glob("*.toml")}
    covered = {case for case, *_ in PASSING_RUNS} | {"euler-too-big", "rk4-too-big"}
    assert cases == covered
    for path in HARD.glob("*.toml"):
        header = path.read_text().split("[scene]")[0]
        assert "Stresses:" in header and "must" in header.lower()


@pytest.mark.parametrize("case, overrides, strain_bound, speed_bound", PASSING_RUNS,
                         ids=[f"{c}-{'-'.join(o) or 'default'}" for c, o, *_ in PASSING_RUNS])
def test_hard_case_stays_within_its_bounds(case, overrides, strain_bound, speed_bound):
    scene = load_scene(str(HARD / f"{case}.toml"), overrides)
    simulation = Simulation(scene)
    record = simulation.run(scene.frame_count)
    stats = simulation.stats(record)
    json.dumps(stats, allow_nan=False)  # finite, or it would not serialise
    assert len(record.frames) == scene.frame_count + 1  # frame 0 (the start) and every frame
    assert record.max_strain < strain_bound
    if "collision" in scene.effects:  # frame 0 is the start as given (tight-skirt: in the hips)
        deepest = max(f.max_penetration for f in record.frames[1:])
        assert deepest < scene.effects["collision"].thickness + PENETRATION_MARGIN
    total_mass = simulation.garment.mass.sum()
    kinetic = max(f.kinetic_energy for f in record.frames)
    assert math.sqrt(2 * kinetic / total_mass) < speed_bound


@pytest.mark.parametrize("case", ["euler-too-big", "rk4-too-big"])
def test_integrator_past_its_limit_ends_in_retries_or_exit_3_never_nan(case, tmp_path):
    result = subprocess.run([sys.executable, "-m", "taichi_cloth", "simulate",
                             str(HARD / f"{case}.toml"), "--out", str(tmp_path), "--quiet"],
                            capture_output=True, text=True, timeout=300)
    assert result.returncode in (0, 3), result.stderr
    assert "Traceback" not in result.stderr
    if result.returncode == 3:
        assert len(result.stderr.strip().splitlines()) == 1
        assert "halvings" in result.stderr and "dt =" in result.stderr
    stats_file = tmp_path / "stats.json"
    if result.returncode == 3 and not stats_file.exists():
        return  # it failed in its first frame: nothing to keep
    text = stats_file.read_text()
    assert "NaN" not in text and "Infinity" not in text
    stats = json.loads(text)
    assert stats["retries"] >= 1
    if result.returncode == 3:  # the whole frames before the failure, marked as stopped
        assert stats["stopped"] == "unstable" and stats["frames"] < 30
    else:
        assert "stopped" not in stats
    positions = np.array([f["center_of_mass"] for f in stats["per_frame"]])
    assert np.isfinite(positions).all()
