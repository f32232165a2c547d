"""Settling before the dance and frame 0: a cotton skirt comes to rest on the still dancer
(kinetic damping, a ripple to leave the cone), the run's frame 0 is that state at t = 0, and the
whole-surface penetration metric sees a capsule that passes between particles."""

import numpy as np
import pytest

from taichi_cloth.cloth.garment import build_garment, settling_ripple
from taichi_cloth.cloth.topology import grid_triangles, triangle_edges
from taichi_cloth.effects.penalty import capsule_penetration_depths
from taichi_cloth.config.scene import load_scene
from taichi_cloth.physics.metrics import RunRecord, surface_samples
from taichi_cloth.physics.settling import settle
from taichi_cloth.physics.simulation import Simulation

SETTLE_SPEED = 0.02  # m/s: the coarse skirt's contacts at the hips chatter at ~7 mm/s
SMALL_SKIRT = ("cloth.resolution=[24, 10]", "simulation.integrator=implicit",
               "simulation.dt=0.0166667", "simulation.settle=3", "body.ease_in=0.5",
               f"simulation.settle_speed={SETTLE_SPEED}")


@pytest.fixture(scope="module")
def settled():
    """A 24 × 10 cotton skirt settled on the hula dancer, then 2 frames of the dance."""
    simulation = Simulation.from_scene("hula", SMALL_SKIRT)
    pattern = simulation.positions()
    record = RunRecord()
    report = settle(simulation, record)
    start = simulation.positions()
    record = simulation.run(2, record=record)
    return simulation, pattern, start, report, record


def hem_radius(simulation, positions):
    hem = positions[-simulation.garment.columns:]
    return np.hypot(hem[:, 0], hem[:, 2])


def test_the_skirt_comes_to_rest_hanging_in_folds(settled):
    simulation, pattern, start, report, _ = settled
    assert report["at_rest"] and report["mean_speed"] < SETTLE_SPEED
    assert 0.1 < report["simulated_seconds"] < 3.0  # it moved, and stopped before the cap
    radius = hem_radius(simulation, start)
    # no longer the pattern's cone: the hem has fallen inwards and folds in and out
    assert radius.mean() < hem_radius(simulation, pattern).mean() - 0.02
    assert radius.max() - radius.min() > 0.02
    assert "settle" in settled[4].wall_seconds


def test_frame_zero_is_the_settled_state_at_time_zero(settled):
    simulation, _, start, _, record = settled
    assert [f.frame for f in record.frames] == [0, 1, 2]
    assert [f.t for f in record.frames] == pytest.approx([0.0, 1 / 30, 2 / 30])
    first = record.frames[0]
    assert first.mean_speed < 0.05 and first.cg_iterations is None
    mass = simulation.model.host_mass
    com = np.sum(mass[:, None] * start, axis=0) / mass.sum()
    np.testing.assert_allclose(first.center_of_mass, com, rtol=1e-9)


def test_the_ripple_pushes_a_skirt_out_radially_and_a_flat_circle_skirt_up(settled):
    """The settling ripple leaves the waist ring and moves the hem by up to the amplitude:
    radially on a cone steeper than 45°, across the cone on a flatter one (a full circle skirt
    lies flat: vertically)."""
    garment = settled[0].garment
    ripple = settling_ripple(garment, folds=8, amplitude=0.01)
    assert np.abs(ripple[:garment.columns]).max() == 0  # the waist ring stays
    hem = ripple[-garment.columns:]
    assert np.abs(hem[:, 1]).max() == 0
    # sin(8θ) at 24 columns peaks at sin(2π/3): 0.866 of the amplitude
    assert np.linalg.norm(hem, axis=1).max() == pytest.approx(0.01 * np.sin(2 * np.pi / 3))
    scene = load_scene("skirt", ("cloth.shape='circle-skirt'", "cloth.resolution=[24, 6]"))
    circle = build_garment(scene.cloth, scene.material, source=scene.path)
    hem = settling_ripple(circle, folds=8, amplitude=0.01)[-circle.columns:]
    np.testing.assert_allclose(hem[:, [0, 2]], 0.0, atol=1e-15)
    assert np.abs(hem[:, 1]).max() == pytest.approx(0.01 * np.sin(2 * np.pi / 3))


def test_whole_surface_samples_catch_a_capsule_between_particles():
    """A unit grid square (two triangles) in the plane y = 0 and a vertical capsule of radius
    0.3 through its centre: every particle is 0.707 from the axis (outside), while the diagonal's
    midpoint lies on the axis (0.3 deep) and both centroids √2/6 from it (0.3 − √2/6 deep)."""
    positions = np.array([[0.0, 0, 0], [1, 0, 0], [0, 0, 1], [1, 0, 1]])
    triangles = grid_triangles(2, 2, False)
    edges = triangle_edges(triangles)
    samples = surface_samples(positions, edges, triangles)
    assert len(samples) == 4 + 5 + 2
    a, b = np.array([[0.5, -1.0, 0.5]]), np.array([[0.5, 1.0, 0.5]])
    depth = capsule_penetration_depths(samples, a, b, np.array([0.3]))
    assert np.all(depth[:4] == 0)  # the particles alone see nothing
    centre_distance = np.hypot(samples[:, 0] - 0.5, samples[:, 2] - 0.5)
    np.testing.assert_allclose(depth, np.maximum(0.3 - centre_distance, 0.0), atol=1e-15)
    assert depth.max() == pytest.approx(0.3)
    assert np.count_nonzero(depth) == 3
    assert sorted(depth[-2:]) == pytest.approx([0.3 - np.sqrt(2) / 6] * 2)


def test_a_skirt_that_keeps_moving_at_the_scenes_step_settles_and_dances_at_a_smaller_one():
    """Light and stiff in-plane (polyester at half its density, 50 g/m²), the shipped 64 × 28
    hula skirt hanging from the waist (no contact) under backward Euler at 1/60 s buzzes at
    ~0.45 m/s and never comes to rest within the cap (so does polyester itself, 100 g/m², on
    the dancer as the product compiles it, crossing itself in thousands of triangle pairs; as
    the test session compiles it, it is just stable); settling again from the start at half
    the step, it comes to rest, and the dance takes that step (stats.json's ``dt``), frame 0
    hanging still."""
    simulation = Simulation.from_scene("hula", ("cloth.material=polyester",
                                                "cloth.material.density=0.05",
                                                "effects.collision=false"))
    scene_dt = simulation.time_step.dt
    record = RunRecord()
    report = settle(simulation, record)
    assert report["at_rest"] and report["step_halvings"] >= 1
    assert report["dt"] == simulation.time_step.dt == pytest.approx(
        scene_dt / 2 ** report["step_halvings"])
    assert simulation.time_step.substeps_per_frame * simulation.time_step.dt == pytest.approx(
        simulation.frame_duration)
    record = simulation.run(1, record=record)
    assert record.frames[0].mean_speed < 0.05 and record.frames[1].max_strain < 0.03


def test_a_garment_that_no_step_brings_to_rest_goes_on_from_the_scenes_step(monkeypatch):
    """Where rest cannot be reached (a settle speed no skirt reaches), settling tries the
    scene's step, half and a quarter of it, and then goes on from the scene's step's try: the
    same state, bit for bit, as settling at that step alone, and the dance at that step."""
    from taichi_cloth.physics import settling
    simulation = Simulation.from_scene("hula", SMALL_SKIRT + ("simulation.settle=1",
                                                              "simulation.settle_speed=1e-9"))
    fresh = simulation.snapshot(effects=True)
    scene_step = (simulation.time_step.dt, simulation.time_step.substeps_per_frame)
    tried = []
    settle_at = settling.settle_at
    monkeypatch.setattr(settling, "settle_at", lambda sim, start, dt, record: (
        tried.append(dt) or settle_at(sim, start, dt, record)))
    report = settle(simulation, RunRecord())
    assert tried == pytest.approx([scene_step[0], scene_step[0] / 2, scene_step[0] / 4])
    assert not report["at_rest"] and report["step_halvings"] == 0
    assert (simulation.time_step.dt, simulation.time_step.substeps_per_frame) == scene_step
    after_three_tries = simulation.positions()
    simulation.restore(fresh)
    monkeypatch.setattr(settling, "SETTLE_STEP_HALVINGS", 0)
    assert settle(simulation, RunRecord()) == report
    np.testing.assert_array_equal(simulation.positions(), after_three_tries)


def test_a_step_halved_while_settling_is_reported_and_the_dance_takes_the_scenes_step(
        settled, monkeypatch):
    """A settling frame that goes bad is redone at half the step (the frame guard); the halving
    is counted in the settle report, and the run afterwards steps at the scene's own step, not
    the halved one (which the guard would keep for the rest of a run). The first settling frame
    is made to fail here. Last in the file: it settles the shared skirt again."""
    simulation = settled[0]
    chosen = (simulation.time_step.dt, simulation.time_step.substeps_per_frame)
    advance = Simulation._advance_refining
    tried = []

    def first_try_fails(self, frame, record, still):
        tried.append(self.time_step.dt)
        if len(tried) == 1:
            return "failed on purpose", None, None, None, {}, None, None
        return advance(self, frame, record, still)

    monkeypatch.setattr(Simulation, "_advance_refining", first_try_fails)
    report = settle(simulation, RunRecord())
    assert tried[1] == pytest.approx(tried[0] / 2)  # redone at half the step
    assert all(dt == pytest.approx(tried[0] / 2) for dt in tried[1:])  # settled at it
    assert report["retries"] == 1 and report["at_rest"]
    assert (simulation.time_step.dt, simulation.time_step.substeps_per_frame) == chosen


def test_settling_solves_from_cold_and_the_dance_from_the_last_step(settled, monkeypatch):
    """While settling, every implicit step's solve starts from δ = 0 (started from the last
    step's velocity change, CG's stopping error recurs alike on a garment near rest: silk and
    polyester skirts buzzed instead of coming to rest at 9 of 25 tolerances and layouts, cold
    at 1); the dance afterwards starts each solve from the last step's change again. Settles
    the shared skirt again."""
    simulation = settled[0]
    integrator = simulation.integrator
    weights = []
    start_weight = type(integrator)._start_weight
    monkeypatch.setattr(type(integrator), "_start_weight",
                        lambda self, dt: weights.append(start_weight(self, dt)) or weights[-1])
    settle(simulation, RunRecord())
    assert len(weights) > 10 and not any(weights)
    assert integrator.warm_start
    weights.clear()
    simulation.run(1, record=RunRecord())
    assert weights[1:] and all(weight > 0 for weight in weights[1:])


def test_bench_runs_a_frame_again_from_one_state_at_held_iterations(settled):
    """`bench`'s effect costs (``studies.bench_scene``): each run of a frame starts again from
    one snapshot, and with CG held at K iterations every step takes exactly K, so the runs with
    and without an effect do the same solver work whatever their trajectories; two runs from
    the snapshot end in the same state, bit for bit. Puts the shared skirt back afterwards."""
    from taichi_cloth.studies.bench_scene import frame_iterations, frame_seconds, hold_iterations
    simulation = settled[0]
    integrator = simulation.integrator
    kept = integrator.tolerance, integrator.max_iterations
    snapshot = simulation.snapshot(effects=True)
    try:
        free = frame_iterations(simulation, snapshot, 3)
        held = round(free) + 7
        hold_iterations(simulation, held)
        frame_seconds(simulation, snapshot, 3)
        first = simulation.host_state()
        frame_seconds(simulation, snapshot, 3)
        steps = 2 * simulation.time_step.substeps_per_frame
        assert integrator.take_iterations() == [held] * steps
        for a, b in zip(first, simulation.host_state()):
            np.testing.assert_array_equal(a, b)
    finally:
        integrator.tolerance, integrator.max_iterations = kept
        simulation.restore(snapshot)
