"""The fused grid substep of the Euler integrators (SIMD spring pass, update and re-pack in one
loop, the packed state carried between substeps) against the CSR gather, which shares no code
with it but ``particle_force``'s effects: the same motion to float32 rounding, on a periodic grid
with dashpots (halo columns) and with a projection pass after every substep (re-pack)."""

import dataclasses
import functools

import numpy as np
import pytest
import taichi as ti

from taichi_cloth.bench import REFERENCE_MATERIAL
from taichi_cloth.effects import Gravity
from taichi_cloth.forces import Forces
from taichi_cloth.garment import build_garment
from taichi_cloth.integrators import make_integrator
from taichi_cloth.model import Model
from taichi_cloth.scene import ClothConfig, GravityEffect

FLOOR_Y = 0.55  # m: the projection below holds the hem above it


@ti.data_oriented
class FloorProjection:
    """A post step: a particle below y = FLOOR_Y moves up to it and loses its downward speed."""

    def __init__(self, model: Model):
        self.model = model

    @ti.func
    def apply(self, state, t):
        for i_p in range(self.model.particle_count):
            if state.x[i_p][1] < FLOOR_Y:
                state.x[i_p][1] = FLOOR_Y
                state.v[i_p][1] = ti.max(state.v[i_p][1], 0.0)


@functools.cache
def skirt_model() -> Model:
    """A 64 × 17 skirt (periodic columns, above the packed minimum) of the benchmark's soft
    fabric with dashpots (β = 2 ms)."""
    cloth = ClothConfig(shape="skirt", resolution=(64, 17), pin="waist")
    material = dataclasses.replace(REFERENCE_MATERIAL, damping=2e-3)
    return Model(build_garment(cloth, material), "f32", 1.0)


@functools.cache
def run(packed: bool, serial: bool, projection: bool, steps: int = 120):
    """(x, v) after ``steps`` symplectic substeps of 0.5 ms from a strained, moving start: the
    skirt's radius shrunk by 10 % and a random velocity field. Cached: each packed kernel takes
    seconds to compile."""
    model = skirt_model()
    forces = Forces(model, [Gravity(GravityEffect())], packed)
    assert forces.has_grid == packed
    integrator = make_integrator("symplectic", forces,
                                 FloorProjection(model) if projection else None)
    integrator.serial = serial
    a, b = model.state(), model.state()
    rng = np.random.default_rng(5)
    a.x.from_numpy(start_positions(model).astype(np.float32))
    a.v.from_numpy((0.5 * rng.standard_normal((model.particle_count, 3))).astype(np.float32))
    newest, _ = integrator.advance(a, b, 0.0, 5e-4, steps)
    return newest.x.to_numpy(), newest.v.to_numpy()


def start_positions(model: Model) -> np.ndarray:
    return model.garment.positions * np.array([0.9, 1.0, 0.9])


@pytest.mark.parametrize("projection", [False, True])
def test_fused_grid_step_matches_the_gather(projection):
    x_gather, v_gather = run(packed=False, serial=True, projection=projection)
    assert np.abs(x_gather - start_positions(skirt_model())).max() > 5e-3  # it moved
    if projection:
        assert np.isclose(x_gather[:, 1].min(), FLOOR_Y)  # the projection held some hem up
    x, v = run(packed=True, serial=True, projection=projection)
    np.testing.assert_allclose(x, x_gather, atol=2e-5)
    np.testing.assert_allclose(v, v_gather, atol=2e-3 * np.abs(v_gather).max())


def test_serial_and_parallel_grid_steps_are_bit_identical():
    """Both launch modes gather every particle's springs in the same order."""
    serial = run(packed=True, serial=True, projection=False)
    parallel = run(packed=True, serial=False, projection=False)
    for a, b in zip(serial, parallel):
        assert np.array_equal(a, b)
