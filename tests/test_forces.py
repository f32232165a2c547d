"""The shared force evaluation: gradients, internal-force balance, effects compiled on demand."""

import numpy as np
import pytest

from taichi_cloth.effects.drag import Drag, DragSettings
from taichi_cloth.effects.wind import Wind, WindSettings
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


def numpy_air_forces(x, v, triangles, t, wind: WindSettings, drag: DragSettings):
    """Drag and wind in NumPy, apart from the kernels (seed §2.3; ``effects.aerodynamics``):
    on each face the flat plate's ½ρC·A·(u·n)|u·n|·n of the air relative to it (u = −v_face
    for drag, w − v_face minus −v_face for the wind, w the gusty wind at the face's centroid),
    a third to each corner [N]."""
    a, b, c = (x[triangles[:, k]] for k in range(3))
    cross = np.cross(b - a, c - a)
    twice_area = np.linalg.norm(cross, axis=1)
    n = cross / twice_area[:, None]
    v_face = v[triangles].mean(axis=1)
    beta, gamma = np.radians(wind.azimuth), np.radians(wind.elevation)
    direction = np.array([np.cos(gamma) * np.cos(beta), np.sin(gamma),
                          np.cos(gamma) * np.sin(beta)])
    omega = 2 * np.pi * wind.gust_frequency
    tau = t - (a + b + c) / 3 @ direction / max(wind.strength, 0.1)
    gust = (np.sin(omega * tau) + 0.5 * np.sin(2.3 * omega * tau + 1.3)
            + 0.25 * np.sin(4.7 * omega * tau + 0.7)) / 1.75
    w = wind.strength * (1 + wind.gusts * gust)[:, None] * direction

    def pressure(u, density, coefficient):
        along = (u * n).sum(axis=1)
        return (0.5 * density * coefficient * 0.5 * twice_area * along * np.abs(along))[:, None] * n

    face = pressure(-v_face, drag.air_density, drag.coefficient) \
        + pressure(w - v_face, wind.air_density, wind.coefficient) \
        - pressure(-v_face, wind.air_density, wind.coefficient)
    out = np.zeros_like(x)
    for k in range(3):
        np.add.at(out, triangles[:, k], face / 3)
    return out


def test_drag_and_gusty_wind_agree_with_numpy_and_their_damping_blocks_with_differences():
    """Each face computed once (``aerodynamics.FaceAir``): the air's forces on a crumpled,
    fast-moving sheet (some faces outrun the wind) equal the NumPy faces', and each particle's
    ∂f_i/∂v_i (drag's and the wind's face blocks, exact in v: the normal does not depend on v)
    equals central differences of its force in its own velocity."""
    scene = small_sheet()
    garment = build_garment(scene.cloth, scene.material)
    wind = WindSettings(strength=3.0, azimuth=30.0, elevation=20.0, gusts=0.5)
    drag = DragSettings(coefficient=1.3)
    springs_only = assemble(Model(garment, "f64", None)).forces
    model = Model(garment, "f64", None)
    forces = assemble(model, [(Drag, drag), (Wind, wind)]).forces
    rng = np.random.default_rng(5)
    x = garment.positions + 0.02 * rng.standard_normal(garment.positions.shape)
    v = 2.0 * rng.standard_normal(garment.positions.shape)
    t = 0.7
    n = model.particle_count
    state = model.state()
    out, u_field, stiffness_u, damping_u = (ti.Vector.field(3, ti.f64, n) for _ in range(4))

    def force_at(evaluated, velocity):
        state.x.from_numpy(x)
        state.v.from_numpy(velocity)
        evaluated.evaluate(state.x, state.v, t, out)
        return out.to_numpy()

    def air_at(velocity):  # the springs' (large, velocity-free) force taken out exactly
        return force_at(forces, velocity) - force_at(springs_only, velocity)

    air = air_at(v)
    expected = numpy_air_forces(x, v, garment.triangles, t, wind, drag)
    assert np.abs(expected).max() > 1e-3
    np.testing.assert_allclose(air, expected, atol=1e-9 * np.abs(expected).max())
    eps = 1e-4  # the two kernels' spring forces (~10² N) round apart at ~10⁻¹⁴ N
    for i_p in rng.choice(n, 6, replace=False):
        u = np.zeros_like(x)
        u[i_p] = rng.standard_normal(3)
        state.x.from_numpy(x)
        state.v.from_numpy(v)
        u_field.from_numpy(u)
        forces.evaluate_jacobian_products(state.x, state.v, u_field, t, False, stiffness_u,
                                          damping_u)
        numeric = (air_at(v + eps * u) - air_at(v - eps * u)) / (2 * eps)
        assert np.abs(numeric[i_p]).max() > 1e-4
        np.testing.assert_allclose(damping_u.to_numpy()[i_p], numeric[i_p],
                                   atol=1e-6 * np.abs(numeric[i_p]).max())
