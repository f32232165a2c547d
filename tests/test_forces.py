"""The shared force evaluation: gradients, internal-force balance, effects compiled on demand."""

import numpy as np
import pytest

from taichi_cloth.effects.wind import Wind
from taichi_cloth.physics.metrics import spring_energy
from taichi_cloth.cloth.garment import build_garment
from taichi_cloth.physics.model import Model
from taichi_cloth.config.scene import load_scene
from taichi_cloth.physics.simulation import Simulation

import taichi as ti
from systems import assemble, energy_gradient


def small_sheet(*overrides):
    return load_scene("sheet", ("cloth.resolution=[5, 4]",) + overrides)


def test_spring_force_is_minus_the_energy_gradient():
    """f = −∂E/∂x, E = Σ ½k(|x_i − x_j| − L)², by central differences (ipc-toolkit style)."""
    scene = small_sheet("simulation.precision='f64'", "cloth.material.stretch_stiffness=300",
                        "cloth.material.shear_stiffness=40", "cloth.material.bend_stiffness=0.01")
    garment = build_garment(scene.cloth, scene.material)
    model = Model(garment, "f64", None)
    forces = assemble(model).forces
    rng = np.random.default_rng(1)
    x = garment.positions + 0.02 * rng.standard_normal(garment.positions.shape)
    state = model.state()
    state.x.from_numpy(x)
    out = ti.Vector.field(3, ti.f64, model.particle_count)
    forces.evaluate(state.x, state.v, 0.0, out)
    force = out.to_numpy()
    assert np.abs(force).max() > 1.0  # a non-trivial gradient first
    numeric = -energy_gradient(lambda y: spring_energy(model, y), x, 1e-6)
    np.testing.assert_allclose(force, numeric, atol=1e-6 * np.abs(force).max())
    np.testing.assert_allclose(force.sum(axis=0), 0.0, atol=1e-9)  # internal forces balance


@pytest.mark.parametrize("integrator, error_sign", [("euler", 1), ("symplectic", -1), ("rk4", 0)])
def test_unpinned_sheet_centre_of_mass_falls_freely(integrator, error_sign):
    """Springs and dashpots are internal: the centre of mass follows y₀ − ½gt², off by exactly
    ±½·g·h·t for the Euler methods and not at all for RK4 (docs/physics.md, closed forms)."""
    scene = small_sheet("cloth.pin='none'", "effects.drag=false", "simulation.precision='f64'",
                        f"simulation.integrator='{integrator}'", "simulation.dt=0.0002",
                        "cloth.material.stretch_stiffness=50", "cloth.material.shear_stiffness=5")
    simulation = Simulation(scene)
    rng = np.random.default_rng(2)  # a strained start, so the springs work while it falls
    strained = simulation.garment.positions + 0.01 * rng.standard_normal(
        (simulation.model.particle_count, 3))
    simulation.states.write(simulation.state_in, strained, np.zeros_like(strained))
    mass = simulation.garment.mass
    y0 = float(np.sum(mass * simulation.positions()[:, 1]) / np.sum(mass))
    record = simulation.run(4)
    g, h = scene.effects["gravity"].g, simulation.time_step.dt
    for metrics in record.frames:
        t = metrics.t
        expected = y0 - 0.5 * g * t * t + error_sign * 0.5 * g * h * t
        assert metrics.center_of_mass[1] == pytest.approx(expected, abs=1e-9)
    assert record.max_strain > 1e-3  # the springs did work while it fell


def test_grid_refinement_keeps_total_mass_and_membrane_stiffness():
    """Mass lumps ρ·area; a square grid's stretch springs carry k_m whatever the spacing (the
    warp's down the columns, the weft's along the rows)."""
    for resolution in ([5, 5], [17, 17]):
        scene = load_scene("sheet", (f"cloth.resolution={resolution}",))
        garment = build_garment(scene.cloth, scene.material)
        assert garment.mass.sum() == pytest.approx(scene.material.density * 1.0, rel=1e-12)
        ends = garment.springs["stretch"]
        down = ends[:, 0] // resolution[0] != ends[:, 1] // resolution[0]
        np.testing.assert_allclose(garment.spring_stiffness["stretch"],
                                   np.where(down, scene.material.stretch_stiffness,
                                            scene.material.stretch_weft), rtol=1e-12)


def flag_positions(*overrides, frames=3):
    scene = load_scene("flag", ("cloth.resolution=[8, 5]", "simulation.precision='f64'",
                                "simulation.dt=0.0002") + overrides)
    simulation = Simulation(scene)
    simulation.run(frames)
    return simulation, simulation.positions()


def test_undeclared_wind_is_not_compiled_and_declared_wind_acts():
    calm, calm_x = flag_positions("effects.wind=false")
    assert "wind" not in calm.effect_names
    assert not any(isinstance(effect, Wind) for effect in calm.forces.effects)
    windy, windy_x = flag_positions()
    assert "wind" in windy.effect_names
    assert np.abs(windy_x - calm_x).max() > 1e-3  # the breeze moves the flag
    zero, zero_x = flag_positions("effects.wind.strength=0")
    assert "wind" in zero.effect_names
    np.testing.assert_allclose(zero_x, calm_x, atol=1e-12)
