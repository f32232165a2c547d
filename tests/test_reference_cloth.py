"""The Taichi force evaluation against a slow NumPy reference written from the physics alone:
springs f_i = k(l − L)n with dashpots c((v_j − v_i)·n)n (c = β·k), gravity m·g, still-air drag
½ρC_d·A·(u·n)|u·n|·n per face shared by its corners, and penalty contact with a moving capsule
(damped normal spring clamped at zero, regularised Coulomb friction), in float64 on random
states, to 1e-10 of the largest force."""

import math
from collections import Counter

import numpy as np
import pytest
import taichi as ti

from taichi_cloth.cloth.garment import build_garment
from taichi_cloth.config.scene import load_scene
from taichi_cloth.effects.collision import CapsuleContact, CollisionSettings
from taichi_cloth.effects.drag import Drag, DragSettings
from taichi_cloth.effects.gravity import Gravity, GravitySettings
from taichi_cloth.physics.model import Model

from systems import assemble

GRAVITY = GravitySettings(g=9.81)
DRAG = DragSettings(coefficient=1.3, air_density=1.2)
CONTACT = CollisionSettings(stiffness=2500.0, damping=0.5, friction=0.3, thickness=0.01, surface=False)
RADIUS = 0.28  # m; the axis runs along x through the middle row of the sheet
CAPSULE_A, CAPSULE_B = np.array([-0.3, 1.1, 0.04]), np.array([0.3, 1.05, -0.02])
CAPSULE_VELOCITY_A, CAPSULE_VELOCITY_B = np.array([0.2, -0.1, 0.4]), np.array([-0.3, 0.0, 0.5])
TIME = 0.25  # s: the capsule has moved on since the track's first sample
RELATIVE_TOLERANCE = 1e-10


@pytest.fixture(scope="module")
def garment():
    """A 6 × 5 sheet hanging in the x-y plane (y from 1.6 down to 0.6 m) from its two top
    corners; heavy, with soft springs and a long damping time, so that every term counts."""
    scene = load_scene("sheet", ("cloth.resolution=[6, 5]", "simulation.precision='f64'",
                                 "cloth.material.density=0.5",
                                 "cloth.material.stretch_stiffness=50",
                                 "cloth.material.shear_stiffness=20",
                                 "cloth.material.bend_stiffness=0.002",
                                 "cloth.material.damping=0.02"))
    return build_garment(scene.cloth, scene.material)


def random_state(garment, seed):
    rng = np.random.default_rng(seed)
    x = garment.positions + 0.02 * rng.standard_normal(garment.positions.shape)
    v = 1.5 * rng.standard_normal(garment.positions.shape)
    return x, v


# --- the reference: plain loops, float64, nothing shared with the package ----------------------


def spring_reference(garment, x, v, dashpots):
    force = np.zeros_like(x)
    for family, pairs in garment.springs.items():
        for (i, j), k in zip(pairs, garment.spring_stiffness[family]):
            rest = math.dist(garment.positions[i], garment.positions[j])
            d = x[j] - x[i]
            n = d / np.linalg.norm(d)
            magnitude = k * (np.linalg.norm(d) - rest)
            if dashpots:
                magnitude += garment.damping_time * k * np.dot(v[j] - v[i], n)
            force[i] += magnitude * n
            force[j] -= magnitude * n
    return force


def gravity_reference(garment, x):
    force = np.zeros_like(x)
    for i, mass in enumerate(garment.mass):
        force[i, 1] = -mass * GRAVITY.g
    return force


def drag_reference(garment, x, v):
    force = np.zeros_like(x)
    for corners in garment.triangles:
        p0, p1, p2 = x[corners]
        twice_area_normal = np.cross(p1 - p0, p2 - p0)
        area = 0.5 * np.linalg.norm(twice_area_normal)
        n = twice_area_normal / (2 * area)
        air = -np.mean(v[corners], axis=0)  # still air seen from the moving face
        speed = np.dot(air, n)
        face = 0.5 * DRAG.air_density * DRAG.coefficient * area * speed * abs(speed) * n
        for i in corners:
            force[i] += face / 3
    return force


def capsule_at(t):
    """Endpoints and their velocities at time t: each end moves in a straight line."""
    return (CAPSULE_A + t * CAPSULE_VELOCITY_A, CAPSULE_B + t * CAPSULE_VELOCITY_B,
            CAPSULE_VELOCITY_A, CAPSULE_VELOCITY_B)


def contact_reference(garment, x, v, t, regimes=None):
    """Penalty contact; ``regimes`` (a Counter) counts which branch of the law each contact
    took."""
    a, b, velocity_a, velocity_b = capsule_at(t)
    k, zeta, mu = CONTACT.stiffness, CONTACT.damping, CONTACT.friction
    force = np.zeros_like(x)
    for i, mass in enumerate(garment.mass):
        axis = b - a
        s = min(max(np.dot(x[i] - a, axis) / np.dot(axis, axis), 0.0), 1.0)
        offset = x[i] - (a + s * axis)
        distance = np.linalg.norm(offset)
        depth = RADIUS + CONTACT.thickness - distance
        if depth <= 0 or distance == 0:
            continue
        n = offset / distance
        relative = v[i] - (velocity_a + s * (velocity_b - velocity_a))
        normal_speed = np.dot(relative, n)
        normal = max(mass * (k * depth - 2 * zeta * math.sqrt(k) * normal_speed), 0.0)
        slip = relative - normal_speed * n
        slip_speed = np.linalg.norm(slip)
        coulomb, viscous = mu * normal, 2 * mass * math.sqrt(k) * slip_speed
        friction = -min(coulomb, viscous) * slip / slip_speed
        force[i] += normal * n + friction
        if regimes is not None:
            regimes["released" if normal == 0 else "sliding" if coulomb < viscous
                    else "sticking"] += 1
            regimes["cap" if s in (0.0, 1.0) else "cylinder"] += 1
    return force


# --- the Taichi side ------------------------------------------------------------------------

SYSTEMS = {
    "springs and dashpots": (),
    "drag": ((Drag, DRAG),),
    "contact": ((CapsuleContact, CONTACT),),
    "everything": ((Gravity, GRAVITY), (Drag, DRAG), (CapsuleContact, CONTACT)),
}


class TaichiCloth:
    """The garment's physics with ``effects``, springs and dashpots (c = 1·β·k) always in."""

    def __init__(self, garment, effects):
        self.model = Model(garment, "f64", 1.0)
        self.physics = assemble(self.model, effects, capsule_radius=[RADIUS])
        self.state = self.model.state()
        self.out = ti.Vector.field(3, ti.f64, self.model.particle_count)
        track = self.physics.control.capsule_track
        a, b, velocity_a, velocity_b = capsule_at(0.0)
        later_a, later_b, _, _ = capsule_at(1.0)
        track.upload(0.0, 1.0, np.array([[a, b], [later_a, later_b]]),
                     np.array([[velocity_a, velocity_b]] * 2))

    def forces(self, x, v, t):
        self.state.x.from_numpy(x)
        self.state.v.from_numpy(v)
        self.physics.forces.evaluate(self.state.x, self.state.v, t, self.out)
        return self.out.to_numpy()


@pytest.fixture(scope="module", params=list(SYSTEMS))
def system(request, garment):
    return request.param, TaichiCloth(garment, SYSTEMS[request.param])


def reference(name, garment, x, v, t):
    springs = spring_reference(garment, x, v, dashpots=True)
    if name == "springs and dashpots":
        return springs
    if name == "drag":
        return springs + drag_reference(garment, x, v)
    if name == "contact":
        return springs + contact_reference(garment, x, v, t)
    return springs + gravity_reference(garment, x) + drag_reference(garment, x, v) \
        + contact_reference(garment, x, v, t)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_taichi_forces_equal_the_reference(system, garment, seed):
    name, cloth = system
    x, v = random_state(garment, seed)
    expected = reference(name, garment, x, v, TIME)
    got = cloth.forces(x, v, TIME)
    np.testing.assert_allclose(got, expected, rtol=0,
                               atol=RELATIVE_TOLERANCE * np.abs(expected).max())


def test_every_term_is_large_enough_to_be_checked(garment):
    """Springs, dashpots, gravity, drag and contact each reach a thousandth of the largest total
    force, so the 1e-10 tolerance checks each to 1e-7 of itself or better: a wrong term could
    not hide under it."""
    x, v = random_state(garment, 0)
    total = np.abs(reference("everything", garment, x, v, TIME)).max()
    springs = spring_reference(garment, x, v, dashpots=False)
    for term in (springs, spring_reference(garment, x, v, dashpots=True) - springs,
                 gravity_reference(garment, x), drag_reference(garment, x, v),
                 contact_reference(garment, x, v, TIME)):
        assert np.abs(term).max() > 1e-3 * total


def test_the_random_states_exercise_every_branch_of_the_contact_law(garment):
    """Pushing out and released (the damper would pull), sliding (Coulomb) and sticking (the
    viscous regularisation), on the cylinder and on a cap."""
    regimes = Counter()
    for seed in (0, 1, 2):
        x, v = random_state(garment, seed)
        contact_reference(garment, x, v, TIME, regimes)
    assert set(regimes) == {"released", "sliding", "sticking", "cap", "cylinder"}


def test_internal_forces_balance_and_drag_opposes_the_motion(garment):
    """Checks of the reference itself: springs and dashpots sum to zero; drag never adds
    energy (Σ f·v ≤ 0)."""
    x, v = random_state(garment, 3)
    np.testing.assert_allclose(spring_reference(garment, x, v, dashpots=True).sum(axis=0), 0.0,
                               atol=1e-12)
    assert np.sum(drag_reference(garment, x, v) * v) < 0
