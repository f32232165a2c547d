"""The skirt on the dancer: worn at the waist, never through the body, at the paper's step."""

import numpy as np
import pytest

from taichi_cloth.effects.penalty import closest_points_numpy
from taichi_cloth.config.scene import load_scene
from taichi_cloth.physics.simulation import Simulation


def run_scene(name, *overrides, frames=None):
    scene = load_scene(name, overrides)
    simulation = Simulation(scene)
    rig = simulation.body_rig
    waist_errors = []

    def check_waist(frame, metrics):
        """The pinned ring sits on the waist circle of the pelvis frame at the frame's end."""
        pose = rig.pose_at_frame_end
        ring = simulation.positions()[simulation.control.pinned_particles]
        if not len(ring):
            return
        local = (ring - pose.pelvis_position) @ pose.pelvis_rotation
        waist_errors.append(max(np.abs(local[:, 1]).max(),
                                np.abs(np.hypot(local[:, 0], local[:, 2])
                                       - scene.cloth.waist_radius).max()))

    record = simulation.run(frames or scene.frame_count, check_waist)
    return simulation, record, np.array(waist_errors or [0.0])


def test_hula_at_the_papers_step_stays_finite_on_the_waist_and_outside_the_body():
    """Seed §4.2: FB (symplectic) Euler at Δt = 0.002 s is stable; the whole 5 s dance."""
    simulation, record, waist_errors = run_scene("hula-paper", "simulation.dt=0.002",
                                                 "simulation.integrator=symplectic")
    assert simulation.time_step.dt <= 0.002
    assert len(record.frames) == simulation.scene.frame_count + 1 == 151  # frames 0–150
    assert record.max_penetration < 0.01
    assert record.max_strain < 0.10
    assert waist_errors.max() < 1e-5  # the ring follows the pelvis frame
    moved = np.linalg.norm(np.array(record.frames[-1].center_of_mass)
                           - np.array(record.frames[0].center_of_mass))
    assert moved > 0.01  # the dance really carried the skirt


def test_skirt_is_in_contact_with_the_legs_while_dancing():
    """Contact is exercised, not vacuous: particles come within the margin of some capsule."""
    scene = load_scene("hula", ("cloth.resolution=[32, 14]",))
    simulation = Simulation(scene)
    rig = simulation.body_rig
    clearances = []
    simulation.run(60, lambda frame, metrics: clearances.append(
        (closest_points_numpy(simulation.positions(), rig.pose_at_frame_end.capsule_a,
                              rig.pose_at_frame_end.capsule_b)[2]
         - rig.body.capsule_radius[None]).min()))
    margin = scene.effects["collision"].thickness
    assert min(clearances) < margin  # touching (inside the contact margin) ...
    assert min(clearances) > -0.01   # ... but never 1 cm inside a leg


def test_drape_comes_to_rest_on_the_bar():
    simulation, record, _ = run_scene("drape", "cloth.resolution=[10, 10]", frames=75)
    kinetic = np.array([f.kinetic_energy for f in record.frames])
    assert kinetic[-5:].max() < 1e-2 * kinetic.max()  # decayed by orders of magnitude
    assert record.max_penetration < simulation.scene.effects["collision"].thickness
    final_height = record.frames[-1].center_of_mass[1]
    bar_height = simulation.body_rig.body.waist_height
    assert bar_height - 0.3 < final_height < bar_height  # hanging over the bar, not fallen


@pytest.mark.parametrize("layout", ["coarse", "split"])
def test_both_capsule_layouts_run(layout):
    simulation, record, _ = run_scene("hula", f"body.capsules={layout}",
                                      "cloth.resolution=[32, 14]", frames=10)
    assert simulation.body_rig.capsule_count == {"coarse": 7, "split": 14}[layout]
    assert record.max_penetration < 0.01
