"""The benchmark's NumPy step is an oracle for the Taichi force kernels and the symplectic step;
``bench`` writes valid JSON. No timing is asserted here: the figures live in the benchmark."""

import json
import math

import numpy as np
import pytest

from taichi_cloth.cli import main
from taichi_cloth.studies.bench import reference_cloth, reference_model
from taichi_cloth.studies.numpy_cloth import NumpyCloth
from taichi_cloth.effects.gravity import Gravity, GravitySettings
from taichi_cloth.physics.packed_grid import PACKED_PARTICLE_MINIMUM
from taichi_cloth.cloth.garment import build_garment
from taichi_cloth.config.materials import PRESETS
from taichi_cloth.physics.model import Model
from taichi_cloth.config.tables import ClothConfig

import taichi as ti
from systems import assemble

G = GravitySettings().g


def skirt_model(around: int, down: int) -> Model:
    """A periodic grid (the skirt) with dashpots: the halo and the damping term."""
    cloth = ClothConfig(shape="skirt", resolution=(around, down), pin="waist",
                        bending="springs")
    return Model(build_garment(cloth, PRESETS["silk"]), "f32", 1.0)


@pytest.fixture(params=["reference", "skirt"])
def model(request):
    """Grids of at least PACKED_PARTICLE_MINIMUM particles, so the packed pass runs."""
    if request.param == "reference":
        return reference_model(33)
    return skirt_model(64, 17)


@pytest.mark.parametrize("packed", [True, False])
def test_numpy_and_taichi_forces_agree(model, packed):
    """Spring (+ dashpot) forces and gravity at a strained, moving state: the packed SIMD pass
    and the CSR gather both match NumPy to float32 rounding."""
    assert model.particle_count >= PACKED_PARTICLE_MINIMUM and model.grid is not None
    forces = assemble(model, [(Gravity, GravitySettings())], packed).forces
    assert forces.has_packed == packed
    rng = np.random.default_rng(3)
    x = (model.garment.positions
         + 0.002 * rng.standard_normal((model.particle_count, 3))).astype(np.float32)
    v = (0.1 * rng.standard_normal((model.particle_count, 3))).astype(np.float32)
    state = model.state()
    state.x.from_numpy(x)
    state.v.from_numpy(v)
    out = ti.Vector.field(3, ti.f32, model.particle_count)
    forces.evaluate(state.x, state.v, 0.0, out)
    expected = NumpyCloth(model, G).forces(x.astype(np.float64), v.astype(np.float64))
    scale = np.abs(expected).max()
    assert scale > 1e-3  # the springs are strained
    np.testing.assert_allclose(out.to_numpy(), expected, atol=2e-5 * scale)


def test_numpy_and_taichi_positions_agree_after_substeps():
    """The reference sheet after 200 symplectic substeps at 1/1920 s from rest: it starts to
    swing down about its pinned edge (a smooth motion, so float32 rounding does not grow)."""
    model = reference_model(40)
    integrator = assemble(model, [(Gravity, GravitySettings())], True, "symplectic").integrator
    x = model.garment.positions.astype(np.float32)
    v = np.zeros_like(x)
    a, b = model.state(), model.state()
    steps, dt = 200, 1.0 / 1920.0
    newest, _ = integrator.advance(a, b, 0.0, dt, steps)
    cloth = NumpyCloth(model, G)
    for _ in range(steps):
        x, v = cloth.step(x, v, dt)
    moved = np.abs(x - model.garment.positions).max()
    assert moved > 1e-3  # it swung
    np.testing.assert_allclose(newest.x.to_numpy(), x, atol=1e-4 * moved)


def test_reference_sheet_is_a_packed_grid():
    cloth = reference_cloth(32)
    assert cloth.resolution == (32, 32)
    model = reference_model(32)
    assert model.grid is not None and model.grid.slot_count == 12


def test_bench_sizes_writes_valid_json(tmp_path, capsys):
    target = tmp_path / "bench.json"
    code = main(["bench", "--sizes", "16", "--integrators", "symplectic", "--seconds", "0.05",
                 "--repeats", "2", "--quiet", "--json", str(target)])
    assert code == 0
    rows = json.loads(target.read_text())
    assert rows[0] == {"benchmark": "machine", "arch": "cpu",
                       "cpu_threads": ti.lang.impl.current_cfg().cpu_max_num_threads}
    reference = [r for r in rows if r["benchmark"] == "reference"]
    assert {r["integrator"] for r in reference} == {"symplectic", "numpy-symplectic"}
    for row in reference:
        assert row["size"] == 16 and row["particles"] == 256
        assert row["substeps_per_second"] > 0
        assert row["particle_substeps_per_second"] == pytest.approx(
            256 * row["substeps_per_second"])
    assert "particle-substeps per second" in capsys.readouterr().out


def test_bench_rejects_bad_sizes(capsys):
    assert main(["bench", "--sizes", "3"]) == 2
    assert "--sizes" in capsys.readouterr().err


def test_bench_rejects_a_thread_count_below_one(capsys):
    assert main(["bench", "--sizes", "16", "--threads", "0"]) == 2
    assert "--threads" in capsys.readouterr().err


def test_a_whole_run_reports_its_self_collision_builds_only_with_self_collision():
    """The scene-run line says how often self-collision's list was rebuilt (the cost that its
    kept-list pass alone would hide), and nothing of it for a scene without."""
    from taichi_cloth.studies.bench import report
    row = {"benchmark": "scene-run", "scene": "twirl", "size": "96x20", "integrator": "implicit",
           "simulated_seconds": 5.0, "wall_seconds": 15.4, "wall_seconds_per_simulated_second":
           3.08, "stepping_seconds": 11.4, "checks_seconds": 4.0, "startup_seconds": 0.5,
           "compile_seconds": 2.0, "settle_seconds": 10.0,
           "self_intersection_ms_per_frame": 3.0, "max_self_intersections": 0}
    with_builds = report([row | {"self_collision_builds": 1040, "steps": 1200}], {})
    assert "list built 1040 times in 1200 steps" in with_builds
    assert "list built" not in report([row], {})


def test_bench_with_scenes_takes_integrators_for_their_rows_alone(monkeypatch):
    """`--scene S --integrators I`: S's rows for I only, and no sizes table (asked for with
    `--sizes`); `--integrators` alone still means the sizes table. Each part is replaced by a
    recorder of its call: this checks which parts run, not what they measure."""
    from taichi_cloth.studies import bench
    calls = []

    def recorder(part, returns):
        def record(*args):  # the scene or size, and the integrators asked of a scene
            calls.append((part, args[0], *args[3:]) if part == "scene_integrators"
                         else (part, args[0]))
            return returns
        return record
    row = {"benchmark": "recorded"}
    for function, returns in [("bench_reference", row), ("bench_numpy", row),
                              ("bench_effects", []), ("bench_passes", row),
                              ("bench_scene_integrators", []), ("bench_scene_run", row)]:
        monkeypatch.setattr(bench, function, recorder(function[len("bench_"):], returns))
    bench.run_bench(None, ["rk4"], ["drape"], 0.1, 1)
    assert calls == [("effects", "drape"), ("passes", "drape"),
                     ("scene_integrators", "drape", ["rk4"]), ("scene_run", "drape")]
    calls.clear()
    bench.run_bench([16], ["rk4"], ["drape"], 0.1, 1)
    assert calls[:2] == [("reference", 16), ("numpy", 16)]
    assert ("scene_integrators", "drape", ["rk4"]) in calls
    calls.clear()
    bench.run_bench(None, ["rk4"], None, 0.1, 1)
    assert calls == [(part, size) for size in bench.DEFAULT_SIZES
                     for part in ("reference", "numpy")]


def test_an_effect_cost_is_the_median_paired_difference_or_at_most_a_bound():
    """``effect_cost``: a clear difference is the median of the pairs' differences, inside
    its interval; differences that straddle 0 (noise) are no cost, only a bound that is never
    negative; differences all below 0 (the scene is faster with the effect) are no cost
    either, and said to be faster. Both runs of a pair share the machine's moment (``base``,
    ±0.5 ms), far wider than the shift: only pairing tells it."""
    from taichi_cloth.studies.bench_scene import effect_cost
    rng = np.random.default_rng(7)
    base = 7e-3 + 1e-3 * rng.random(60)  # seconds a substep, the machine's ±0.5 ms
    paired_noise = 30e-6 * rng.standard_normal(60)
    cost = effect_cost(list(base + 200e-6 + paired_noise), list(base))
    low, high = cost["interval_us_per_substep"]
    assert not cost["below_noise"]
    assert cost["cost_us_per_substep"] == pytest.approx(200, abs=15)
    assert 0 < low < cost["cost_us_per_substep"] < high < 250
    noise = effect_cost(list(base + paired_noise), list(base))
    assert noise["below_noise"] and noise["cost_us_per_substep"] is None
    assert noise["interval_us_per_substep"][0] <= 0 <= noise["noise_us_per_substep"] < 30
    faster = effect_cost(list(base - 100e-6 + paired_noise), list(base))
    assert faster["faster_with_effect"] and not faster["below_noise"]
    assert faster["cost_us_per_substep"] is None and faster["noise_us_per_substep"] == 0


@pytest.mark.parametrize("count", [20, 45, 100])
def test_an_effect_costs_interval_holds_the_median_95_percent_of_the_time(count):
    """The order-statistic interval of ``effect_cost`` covers the true median of the
    differences in at least 95 % of samples of ``count`` pairs (skewed noise, as a machine's
    slow moments are), and is no wider than it must be: the next ranks inwards cover less than
    95 % (their exact binomial coverage)."""
    from taichi_cloth.studies.bench_scene import effect_cost, median_interval_ranks
    rng = np.random.default_rng(count)
    true_median = 50e-6 + 20e-6 * np.log(2)  # of 50 µs + an exponential of mean 20 µs
    trials, covered = 2000, 0
    for _ in range(trials):
        differences = 50e-6 + rng.exponential(20e-6, count)
        low, high = effect_cost(list(differences), [0.0] * count)["interval_us_per_substep"]
        covered += low <= 1e6 * true_median <= high
    assert covered / trials >= 0.95
    rank = median_interval_ranks(count)
    inner = rank + 1  # P(the (r+1)-th and (n−r)-th smallest hold the median)
    assert 1 - 2 * sum(math.comb(count, k) for k in range(inner)) / 2 ** count < 0.95


def test_a_scene_with_self_collision_is_run_again_without_it_for_its_cost_per_step(monkeypatch):
    """`--scene fold` (it declares self-collision): after its whole run, a second one with
    ``effects.self_collision=false``; the row that follows says the difference in stepping
    seconds per step beside the scene's spring pass, and the report prints it. A scene without
    self-collision is run once. The parts are replaced by stand-ins (this checks what is run and
    the arithmetic, not what is measured)."""
    from taichi_cloth.studies import bench
    runs = []

    def scene_run(name, overrides=()):
        runs.append((name, tuple(overrides)))
        stepping = 2.0 if overrides else 2.6
        return {"benchmark": "scene-run", "scene": name, "stepping_seconds": stepping,
                "steps": 480, "frames": 60}
    monkeypatch.setattr(bench, "bench_effects", lambda *args: [])
    monkeypatch.setattr(bench, "bench_passes", lambda name, *args: {
        "benchmark": "passes", "scene": name, "springs_us_per_substep": 75.8})
    monkeypatch.setattr(bench, "bench_scene_integrators", lambda *args: [])
    monkeypatch.setattr(bench, "bench_scene_run", scene_run)
    rows, _ = bench.run_bench(None, ["implicit"], ["fold", "drape"], 0.1, 1)
    assert runs == [("fold", ()), ("fold", ("effects.self_collision=false",)), ("drape", ())]
    cost = [row for row in rows if row["benchmark"] == "self-collision-run"]
    assert len(cost) == 1 and cost[0]["scene"] == "fold" and cost[0]["steps"] == 480
    assert cost[0]["us_per_step"] == pytest.approx(1e6 * 0.6 / 480, abs=0.05)  # 1,250 µs
    line = bench.report(cost, {})
    assert "fold self-collision over the whole run: 1250.0 µs a step (the spring pass: " \
        "75.80 µs)" in line
