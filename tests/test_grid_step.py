"""The grid substeps of the Euler integrators against the CSR gather, which shares no code with
them but the effects: the same motion to float32 rounding, on a periodic grid with dashpots
(halo columns, a group of lanes holding own and wrapped ones). The whole step in SIMD lanes
(``steps_in_lanes``: the packed state unpacked at the end of a launch) with gravity only, and
with curvature bending (a linear stencil in the SIMD pass) and air drag (faces in the SIMD
pass) together; with gusty wind as well, an effect the particles gather (``gathers_for_lanes``:
the state unpacked, the wind's faces made and each particle's force packed into lanes every
substep), serial and parallel; with capsule contact instead of wind, an effect that lists the
particles it acts on (``gathers_listed``: only positions unpacked, the velocities read from
the lanes, only the touched particles' forces packed), serial and parallel; drag and wind also
on an open grid whose width is not a multiple of the lanes ("open-drag-wind"), and bending
with its dashpot there (its y = x + β·v in lanes whose halo is not refreshed); bending and drag
on a skirt of whole groups of lanes (64 columns), whose shifted reads wrap round with no halo
kept ("round-bending-drag"); and the per-particle update (packed each substep)
with a projection pass after every substep. Drag moves the skirt 1.9 mm and a falling sheet
more over these runs: a pass that lost it would miss the gather by far more than the
tolerance."""

import dataclasses
import functools

import numpy as np
import pytest
import taichi as ti
from systems import assemble

from taichi_cloth.studies.bench import REFERENCE_MATERIAL
from taichi_cloth.effects.bending import Bending, BendingSettings
from taichi_cloth.effects.collision import CapsuleContact, CollisionSettings
from taichi_cloth.effects.drag import Drag, DragSettings
from taichi_cloth.effects.gravity import Gravity, GravitySettings
from taichi_cloth.effects.wind import Wind, WindSettings
from taichi_cloth.cloth.garment import build_garment
from taichi_cloth.physics.model import Model
from taichi_cloth.config.tables import ClothConfig

FLOOR_Y = 0.55  # m: the projection below holds the hem above it
STEPS, DT = 120, 5e-4  # substeps of the runs, and their length [s]
RUN_SECONDS = STEPS * DT
WAIST_SPEED = 0.2  # m/s
# a leg inside the skirt, 1 cm from its hem (its margin 5 mm): the swinging hem meets it, until
# the leg jumps away halfway, leaving particles that it pushed on at once (whose lanes must not
# keep its force)
LEG, LEG_RADIUS = np.array([[0.29, 0.4, 0.0], [0.29, 0.8, 0.0]]), 0.03  # m
# rows per block of a parallel launch (``PackedGrid.block_rows``): 17 rows in five blocks, each
# block's first row reading the two rows before it (the bending springs' Δrow = 2)
ROWS_PER_BLOCK = 4


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
    """A 72 × 17 skirt (periodic columns, above the packed minimum; 4.5 groups of lanes, so
    that a group holds both own and wrapped columns) of the benchmark's soft fabric with
    dashpots (β = 2 ms)."""
    cloth = ClothConfig(shape="skirt", resolution=(72, 17), pin="waist", bending="springs")
    material = dataclasses.replace(REFERENCE_MATERIAL, damping=2e-3)
    return Model(build_garment(cloth, material), "f32", 1.0)


@functools.cache
def sheet_model() -> Model:
    """A 40 × 30 sheet (an open grid, 40 columns: 2.5 groups of lanes), top edge pinned."""
    cloth = ClothConfig(shape="sheet", resolution=(40, 30), pin="top-edge", bending="springs")
    material = dataclasses.replace(REFERENCE_MATERIAL, damping=2e-3)
    return Model(build_garment(cloth, material), "f32", 1.0)


@functools.cache
def round_skirt_model() -> Model:
    """A 64 × 17 skirt: four whole groups of lanes, no halo (``GridStencil.wrapped_groups``)."""
    cloth = ClothConfig(shape="skirt", resolution=(64, 17), pin="waist", bending="springs")
    material = dataclasses.replace(REFERENCE_MATERIAL, damping=2e-3)
    return Model(build_garment(cloth, material), "f32", 1.0)


def model_for(variant: str) -> Model:
    if variant.startswith("open"):
        return sheet_model()
    return round_skirt_model() if variant.startswith("round") else skirt_model()


def waist(model: Model) -> np.ndarray:
    return model.garment.positions[model.garment.pinned]


@functools.cache
def run(packed: bool, serial: bool, variant: str):
    """(x, v) after STEPS symplectic substeps of DT from a strained, moving start: the
    skirt's radius shrunk by 10 % and a random velocity field. Cached: each packed kernel takes
    seconds to compile."""
    model = model_for(variant)
    effects = [(Gravity, GravitySettings())] + \
        ([(Drag, DragSettings())] if "drag" in variant else []) + \
        ([(Wind, WindSettings(strength=4.0, azimuth=30.0, gusts=0.5, gust_frequency=40.0))]
         if variant.endswith("wind") else []) + \
        ([(Bending, BendingSettings())] if "bending" in variant else []) + \
        ([(CapsuleContact, CollisionSettings())] if variant.endswith("contact") else [])
    physics = assemble(model, effects, packed, "symplectic",
                       capsule_radius=[LEG_RADIUS] if variant.endswith("contact") else [],
                       post_step=FloorProjection(model) if variant == "projection" else None,
                       rows_per_block=ROWS_PER_BLOCK)
    if variant.endswith("contact"):
        physics.control.capsule_track.hold(LEG)
    # the waist ring slides along x at WAIST_SPEED during the run: moving pins
    track = np.stack([waist(model), waist(model) + [WAIST_SPEED * RUN_SECONDS, 0.0, 0.0]])
    physics.control.pin_track.upload(0.0, RUN_SECONDS, track,
                                     np.broadcast_to([WAIST_SPEED, 0.0, 0.0], track.shape))
    assert physics.forces.has_packed == packed
    integrator = physics.integrator
    assert integrator.steps_in_lanes == (packed and variant != "projection")
    assert integrator.gathers_for_lanes == (packed and variant.endswith(("wind", "contact")))
    assert integrator.gathers_listed == (packed and variant.endswith("contact"))
    if packed:  # the effects act in the pass, not gathered
        lanes = [effect.name for effect in physics.forces.packed.lane_effects]
        assert sorted(lanes) == sorted(name for name in ("bending", "drag") if name in variant)
        assert physics.forces.packed.copies_halo == (model is skirt_model())  # (round: wraps)
    integrator.serial = serial
    if not serial:  # 2 unrolled substeps a launch, not 8: the same code, a quarter the compile
        integrator.substep_batch = 2
    a, b = model.state(), model.state()
    rng = np.random.default_rng(5)
    a.x.from_numpy(start_positions(model).astype(np.float32))
    a.v.from_numpy((0.5 * rng.standard_normal((model.particle_count, 3))).astype(np.float32))
    if variant.endswith("contact"):
        a, b = integrator.advance(a, b, 0.0, DT, STEPS // 2)
        physics.control.capsule_track.hold(LEG + [1.0, 0.0, 0.0])
        newest, _ = integrator.advance(a, b, STEPS // 2 * DT, DT, STEPS - STEPS // 2)
    else:
        newest, _ = integrator.advance(a, b, 0.0, DT, STEPS)
    return newest.x.to_numpy(), newest.v.to_numpy()


def start_positions(model: Model) -> np.ndarray:
    return model.garment.positions * np.array([0.9, 1.0, 0.9])


@pytest.mark.parametrize("variant", ["gravity", "bending-drag", "bending-drag-wind",
                                     "bending-drag-contact", "open-drag-wind",
                                     "open-bending-drag", "round-bending-drag", "projection"])
def test_grid_steps_match_the_gather(variant):
    model = model_for(variant)
    x_gather, v_gather = run(packed=False, serial=True, variant=variant)
    assert np.abs(x_gather - start_positions(model)).max() > 5e-3  # it moved
    if variant == "projection":
        assert np.isclose(x_gather[:, 1].min(), FLOOR_Y)  # the projection held some hem up
    if variant == "bending-drag":  # they bend the skirt (2.8 cm from gravity's run): the lanes
        # have it
        assert np.abs(x_gather - run(packed=False, serial=True, variant="gravity")[0]).max() > 0.01
    if variant == "bending-drag-wind":  # the wind moves it too
        wind_moved = np.abs(x_gather - run(packed=False, serial=True, variant="bending-drag")[0])
        assert wind_moved.max() > 1e-3
    if variant == "bending-drag-contact":  # the leg holds the hem out
        leg_moved = np.abs(x_gather - run(packed=False, serial=True, variant="bending-drag")[0])
        assert leg_moved.max() > 1e-3
    waist_end = waist(model) + [WAIST_SPEED * RUN_SECONDS, 0, 0]
    np.testing.assert_allclose(x_gather[model.garment.pinned], waist_end, atol=1e-5)  # pins
    x, v = run(packed=True, serial=True, variant=variant)
    np.testing.assert_allclose(x, x_gather, atol=2e-5)
    np.testing.assert_allclose(v, v_gather, atol=2e-3 * np.abs(v_gather).max())


@pytest.mark.parametrize("variant", ["gravity", "bending-drag-wind", "bending-drag-contact",
                                     "projection"])
def test_serial_and_parallel_grid_steps_are_bit_identical(variant):
    """Both launch modes gather every particle's springs (and its gathered effects) in the
    same order: a parallel launch's blocks of rows (``ROWS_PER_BLOCK``) compute the forward
    forces of the rows before their first again, the same bits."""
    serial = run(packed=True, serial=True, variant=variant)
    parallel = run(packed=True, serial=False, variant=variant)
    for a, b in zip(serial, parallel):
        assert np.array_equal(a, b)
