"""Self-collision (effects/self_collision.py): the forces of a vertex over a triangle and of two
crossing edges against −∇ of the penalty energy ½·m·k̂·(thickness − d)², with d from closed forms
(the distance to a plane, the distance between two lines), and momentum conserved; the scene
`fold` keeps every frame free of intersecting triangles where the metric sees them without it."""

import collections
import functools
import json
import math
import subprocess

import meshio
import numpy as np
import pytest
import taichi as ti
from systems import assemble, energy_gradient

from taichi_cloth.cli import main
from taichi_cloth.cloth.garment import Garment
from taichi_cloth.effects.penalty import ContactMode
from taichi_cloth.effects.self_collision import SEPARATION, SelfCollision, SelfCollisionSettings
from taichi_cloth.physics.metrics import RunRecord
from taichi_cloth.physics.model import Model
from taichi_cloth.physics.settling import settle
from taichi_cloth.physics.simulation import Simulation
from taichi_cloth.physics.timestep import TimeStep, fixed_time_step

THICKNESS, K_HAT = 0.01, 1e4  # m, 1/s²
MASS = np.array([0.1, 0.2, 0.3, 0.4, 0.5, 0.6])  # kg
SETTINGS = SelfCollisionSettings(thickness=THICKNESS, stiffness=K_HAT, damping=0.0, friction=0.0)


def triangle_mesh(positions: np.ndarray, triangles: list, mass: np.ndarray) -> Garment:
    """A free mesh of ``triangles`` with springs of zero stiffness on their edges (the mesh
    needs them; the tests no force but self-collision's)."""
    triangles = np.array(triangles, np.int32)
    edges = np.unique(np.sort(np.concatenate([triangles[:, [0, 1]], triangles[:, [1, 2]],
                                              triangles[:, [0, 2]]]), axis=1), axis=0)
    count = len(positions)
    return Garment(positions=positions, uvs=np.zeros((count, 2)), triangles=triangles,
                   springs={"stretch": edges}, spring_stiffness={"stretch": np.zeros(len(edges))},
                   mass=mass, pinned=np.zeros(count, bool), columns=count, rows=1,
                   periodic=False, damping_time=0.0)


def two_triangles(positions: np.ndarray) -> Garment:
    """Triangles (0, 1, 2) and (3, 4, 5), unconnected, with the masses of ``MASS``."""
    return triangle_mesh(positions, [[0, 1, 2], [3, 4, 5]], MASS)


@functools.cache
def two_triangle_physics():
    """The two triangles' model with only the effect, built once (every test moves the same
    six particles): (forces, state, output field, the effect)."""
    rest = np.array([[-1.0, 0, -1], [1, 0, -1], [0, 0, 1], [0, 1, 0], [1, 1, 0], [0, 1, 1]])
    model = Model(two_triangles(rest), "f64")
    physics = assemble(model, [(SelfCollision, SETTINGS)])
    return physics.forces, model.state(), ti.Vector.field(3, ti.f64, 6), physics.effects[0]


@ti.kernel
def finish_step(effect: ti.template(), state: ti.template()):
    """What an integrator does after each step: the effect's post step (its side records)."""
    effect.apply(state, 0.0)


def self_collision_force(*steps: np.ndarray) -> np.ndarray:
    """The effect's force on every particle at rest at the last positions of ``steps``, each
    earlier one a finished step (springs of zero stiffness: the mesh needs edges, the test no
    other force); a fresh start: no side records."""
    forces, state, out, effect = two_triangle_physics()
    effect.forget_history()
    state.v.fill(0.0)
    for k, positions in enumerate(steps):
        if k:
            finish_step(effect, state)
        state.x.from_numpy(positions)
        forces.evaluate(state.x, state.v, 0.0, out)
    return out.to_numpy()


def penalty(distance: float, mass: float) -> float:
    return 0.5 * mass * K_HAT * max(THICKNESS - distance, 0.0) ** 2


def test_vertex_over_a_triangle_is_pushed_off_it_by_minus_the_energy_gradient():
    """Vertex 3 hovers 4 mm above the inside of triangle (0, 1, 2) in the plane y = 0."""
    positions = np.array([[-1.0, 0, -1], [1, 0, -1], [0, 0, 1],
                          [0.1, 0.004, 0.2], [0.1, 1.0, 0.2], [0.6, 1.0, 0.4]])

    def energy(x):
        normal = np.cross(x[1] - x[0], x[2] - x[0])
        normal /= np.linalg.norm(normal)
        return penalty(abs((x[3] - x[0]) @ normal), MASS[3])

    force = self_collision_force(positions)
    np.testing.assert_allclose(force, -energy_gradient(energy, positions, 1e-7), atol=1e-6)
    assert force[3, 1] == pytest.approx(MASS[3] * K_HAT * 0.006, rel=1e-9)
    np.testing.assert_allclose(force.sum(axis=0), 0.0, atol=1e-12)


def test_a_frame_redone_by_the_tunnelling_guard_stiffens_the_penalty_four_times_a_halving():
    """``follow_redo(h)``: the stiffness the kernels read is 4^h times the run's (twice the
    closing speed stopped for each halving of the step), and the run's again at h = 0: the
    vertex 4 mm above the triangle (6 mm deep in the band) is pushed with m·4^h·k̂·6 mm."""
    positions = np.array([[-1.0, 0, -1], [1, 0, -1], [0, 0, 1],
                          [0.1, 0.004, 0.2], [0.1, 1.0, 0.2], [0.6, 1.0, 0.4]])
    effect = two_triangle_physics()[3]
    try:
        for halvings in (1, 2, 0):
            effect.follow_redo(halvings)
            assert self_collision_force(positions)[3, 1] == pytest.approx(
                MASS[3] * 4 ** halvings * K_HAT * 0.006, rel=1e-9)
    finally:
        effect.follow_redo(0)


def test_crossing_edges_are_pushed_apart_by_minus_the_energy_gradient():
    """Edge 0–1 along x at y = 0 and edge 3–4 along z at y = 5 mm, the triangles turned away
    from each other: only the edge pair is within the thickness."""
    positions = np.array([[-1.0, 0, 0], [1, 0, 0], [0, -1, 0],
                          [0, 0.005, -1], [0.2, 0.005, 1], [0, 1, 0]])
    mean_mass = MASS[[0, 1, 3, 4]].mean()

    def energy(x):
        across = np.cross(x[1] - x[0], x[4] - x[3])
        return penalty(abs((x[3] - x[0]) @ across) / np.linalg.norm(across), mean_mass)

    force = self_collision_force(positions)
    np.testing.assert_allclose(force, -energy_gradient(energy, positions, 1e-7), atol=1e-6)
    np.testing.assert_allclose(force.sum(axis=0), 0.0, atol=1e-12)
    assert force[[3, 4], 1].sum() == pytest.approx(mean_mass * K_HAT * 0.005, rel=1e-6)


def test_far_apart_nothing_acts():
    positions = np.array([[-1.0, 0, -1], [1, 0, -1], [0, 0, 1],
                          [0.1, 0.02, 0.2], [0.1, 1.0, 0.2], [0.6, 1.0, 0.4]])
    assert np.all(self_collision_force(positions) == 0.0)


def tip_to_tip(gap: float) -> np.ndarray:
    """Two fans of six triangles, 2 cm across, their tips on the y axis ``gap`` [m] apart: the
    upper one (tip 0, rim 1–6) opening upwards, the lower one (tip 7, rim 8–13) downwards,
    turned 30° from it. Within the thickness only the tips meet."""
    angle = np.radians(60.0 * np.arange(6))
    rim = np.stack([np.cos(angle), np.full(6, 0.5), np.sin(angle)], axis=1) * 0.02
    turned = np.stack([np.cos(angle + np.radians(30)), np.full(6, -0.5),
                       np.sin(angle + np.radians(30))], axis=1) * 0.02
    return np.concatenate([[[0.0, gap, 0.0]], rim + [0.0, gap, 0.0], [[0.0, 0.0, 0.0]], turned])


@functools.cache
def tip_to_tip_physics(lower_tip_mass: float = 0.1):
    """The two fans' model (every particle 0.1 kg but the lower tip, ``lower_tip_mass``) with
    only the effect: (forces, state, output field, the effect)."""
    fan = [[0, 1 + k, 1 + (k + 1) % 6] for k in range(6)]
    triangles = fan + [[7 + corner for corner in triangle] for triangle in fan]
    mass = np.full(14, 0.1)
    mass[7] = lower_tip_mass
    model = Model(triangle_mesh(tip_to_tip(0.005), triangles, mass), "f64")
    physics = assemble(model, [(SelfCollision, SETTINGS)])
    return physics.forces, model.state(), ti.Vector.field(3, ti.f64, 14), physics.effects[0]


@pytest.mark.parametrize("lower_tip_mass", [0.1, 0.05])
def test_a_vertex_resting_on_a_vertex_is_pushed_by_every_pair_around_them(lower_tip_mass):
    """Tip on tip, 4 mm apart: the upper tip is within the thickness of the lower fan's six
    triangles (its tip their closest point), the lower tip of the upper fan's six, and each of
    the upper tip's six edges of each of the lower tip's six (their ends the closest points):
    6 + 6 + 36 = 48 pairs push the tips apart along y, k̂·(δ − 4 mm) times the upper tip's
    mass, the lower tip's, and the four particles' mean. So the mode of the tips moving apart,
    measured from the forces by central differences, is (1/m_0 + 1/m_7)·(their masses' sum)·k̂:
    2·48·k̂ for equal masses, 121.5·k̂ with the lower tip half as heavy. It is the mode that
    ``dt = "auto"`` and the split of a given step take (docs/physics.md, "Time step"), the
    tips the mesh's most pushed pair of vertices; counting four contacts a particle there,
    the skirt of `hula-paper` was launched."""
    forces, state, out, effect = tip_to_tip_physics(lower_tip_mass)
    mass, gap, nudge = 0.1, 0.004, 1e-7

    def tips_force(x):
        effect.forget_history()
        state.x.from_numpy(x)
        state.v.fill(0.0)
        forces.evaluate(state.x, state.v, 0.0, out)
        return out.to_numpy()

    x = tip_to_tip(gap)
    force = tips_force(x)
    pushing_mass = 6 * mass + 6 * lower_tip_mass + 36 * (3 * mass + lower_tip_mass) / 4
    assert force[0] == pytest.approx([0.0, pushing_mass * K_HAT * (THICKNESS - gap), 0.0],
                                     rel=1e-9, abs=1e-12)
    np.testing.assert_allclose(force.sum(axis=0), 0.0, atol=1e-12)
    apart, closer = x.copy(), x.copy()
    apart[0, 1] += nudge
    apart[7, 1] -= nudge
    closer[0, 1] -= nudge
    closer[7, 1] += nudge
    change = tips_force(apart) - tips_force(closer)  # the tips 4·nudge further apart
    mode = -(change[0, 1] / mass - change[7, 1] / lower_tip_mass) / (4 * nudge)
    contacts = (1 / mass + 1 / lower_tip_mass) * pushing_mass
    assert contacts == pytest.approx({0.1: 2 * 48, 0.05: 121.5}[lower_tip_mass], rel=1e-12)
    assert mode == pytest.approx(contacts * K_HAT, rel=1e-6)
    (stiffness, ratio, reported), = effect.stability_modes()
    assert (stiffness, ratio) == (K_HAT, 0.0) and reported == pytest.approx(contacts, rel=1e-12)


@pytest.mark.parametrize("thickness", [0.004, 0.001, 0.0005])
def test_unset_stiffness_stops_layers_closing_at_4_m_s_at_any_thickness(thickness):
    """Without a stiffness, k̂ = 10⁶·(4 mm / thickness)²: the penalty's energy over the whole
    thickness, ½·m·k̂·δ², is the kinetic energy ½·m·v² of layers closing at v = 4 m/s (the speed
    it stops: docs/physics.md, "Tunnelling"), and ``dt = "auto"`` sees that stiffness. Fitted to
    a step of 1/60 s: kept for an explicit integrator whose step was chosen for it ("auto"), at
    most 10⁶ for one whose step was given, at most 300/dt² for backward Euler (10⁶ at 4 mm, less
    than 1.6·10⁷ at 1 mm). A stiffness given is kept."""
    rest = np.array([[-1.0, 0, -1], [1, 0, -1], [0, 0, 1], [0, 1, 0], [1, 1, 0], [0, 1, 1]])
    unset = SelfCollisionSettings(thickness=thickness)
    *fitted, given = assemble(Model(two_triangles(rest), "f64"), [
        (SelfCollision, unset), (SelfCollision, unset), (SelfCollision, unset),
        (SelfCollision, SelfCollisionSettings(thickness=thickness, stiffness=2e5))]).effects
    stops_4_m_s = fitted[0].stiffness
    assert 0.5 * stops_4_m_s * thickness ** 2 == pytest.approx(0.5 * 4.0 ** 2, rel=1e-12)
    # a vertex p on a vertex q: the pairs of p with q's triangle (p's mass), of q with p's
    # (q's), of each edge at p with each at q (their four masses' mean), each pushing the
    # relative coordinate by (1/m_p + 1/m_q) per kilogram; the most over p ≠ q
    triangles, edges = [(0, 1, 2), (3, 4, 5)], [(0, 1), (1, 2), (0, 2), (3, 4), (4, 5), (3, 5)]
    contacts = max((1 / MASS[p] + 1 / MASS[q]) * (
        sum(MASS[p] for t in triangles if q in t) + sum(MASS[q] for t in triangles if p in t)
        + sum(MASS[[*e, *f]].mean() for e in edges if p in e for f in edges if q in f))
        for p in range(6) for q in range(6) if p != q)
    mode, = fitted[0].stability_modes()
    assert mode.stiffness == stops_4_m_s and mode.contacts == pytest.approx(contacts, rel=1e-12)
    chosen, given_step = TimeStep(1 / 60, 2, "auto"), fixed_time_step(1 / 60, 1 / 30)
    for effect, step, integrator, bound in ((fitted[0], chosen, "symplectic", math.inf),
                                            (fitted[1], given_step, "symplectic", 1e6),
                                            (fitted[2], chosen, "implicit", 300 * 60 ** 2)):
        assert effect.fit_time_step(step, integrator) == (stops_4_m_s > bound)
        assert effect.stiffness == min(stops_4_m_s, bound)
    assert not given.fit_time_step(chosen, "implicit") and given.stiffness == 2e5


def test_a_simulation_fits_the_unset_stiffness_to_its_step_before_its_kernels_read_it():
    """`fold` with backward Euler at a 1 mm thickness: ``Simulation`` gives its self-collision
    the stiffness fitted to the step it chose (at most 300/dt²), and its time step's report
    (the highest frequency with the contact modes) is the one of that stiffness given in the
    scene."""
    overrides = ("simulation.integrator=implicit", "effects.self_collision.thickness=0.001")
    simulation = Simulation.from_scene("fold", overrides)
    effect = next(e for e in simulation.effects if e.name == "self_collision")
    assert effect.stiffness == min(1.6e7, 300 / simulation.time_step.dt ** 2) < 1.6e7
    given = Simulation.from_scene("fold", overrides + (
        f"effects.self_collision.stiffness={effect.stiffness!r}",))
    assert given.time_step == simulation.time_step


def test_a_given_explicit_step_is_split_until_the_penalty_is_stable():
    """`hula-paper` (FB Euler at the paper's 2 ms) with self-collision: its penalty (10⁶ 1/s²)
    is unstable at 2 ms, where it stretched the skirt 42 % without ever blowing up
    (docs/physics.md, "Time step"). The run splits the step below the bound of the stiffest
    mode, a vertex on a vertex (48 pairs on its grid, n = 2·48 contacts for equal masses, more
    as its rows' masses differ: ω = √(n·10⁶)), whose frictions' regularised dampers add to
    ζ = √n: FB Euler is stable for ωh ≤ 2(√(ζ² + 1) − ζ) (its amplification matrix's trace and
    determinant); it keeps the 2 ms it was asked for."""
    simulation = Simulation.from_scene("hula-paper", ("effects.self_collision=true",))
    effect = next(e for e in simulation.effects if e.name == "self_collision")
    step = simulation.time_step
    assert effect.stiffness == 1e6 and step.requested == 0.002
    contacts = effect.stability_modes()[0].contacts
    assert 2 * 48 < contacts < 2 * 48 * 1.2  # its masses differ from row to row, and at the hem
    ratio = math.sqrt(contacts)
    assert step.stable_dt == pytest.approx(2 * (math.sqrt(ratio ** 2 + 1) - ratio)
                                           / math.sqrt(contacts * 1e6), rel=1e-6)
    assert step.dt <= simulation.scene.simulation.safety * step.stable_dt * (1 + 1e-9)


def test_rk4_stays_on_one_thread_with_self_collision_where_it_would_go_parallel():
    """RK4 goes parallel above 2,048 particles for its four force passes, but self-collision's
    passes are serial in any launch: on `walk-dress` (2,296 particles) it compiled the effect
    four times over (199 s) and stepped 6× slower, so with it RK4 stays on one thread."""
    with_it, without_it = (Simulation.from_scene("walk-dress", (
        "simulation.integrator=rk4", "simulation.settle=0", f"effects.self_collision={on}"))
        for on in ("true", "false"))
    assert with_it.model.particle_count > with_it.integrator.serial_particle_limit
    assert with_it.integrator.serial and not without_it.integrator.serial


def vertex_over_the_triangle(height: float, z: float = 0.2) -> np.ndarray:
    """Vertex 3 ``height`` [m] above the plane y = 0 of triangle (0, 1, 2) at (0.1, ·, z):
    inside the triangle for z > −1, outside beyond its edge z = −1."""
    return np.array([[-1.0, 0, -1], [1, 0, -1], [0, 0, 1],
                     [0.1, height, z], [0.1, 1.0, 0.2], [0.6, 1.0, 0.4]])


def test_a_vertex_that_crossed_the_face_within_a_step_is_pushed_back_by_minus_the_gradient():
    """Vertex 3 at 4 mm above the triangle after a step and 3 mm below it at the next: it went
    through the face, and the penalty of the side it belongs on, ½·m·k̂·(thickness − h)² with h
    its height above, pushes it back up through it with m·k̂·(thickness + 3 mm). Without that
    history (a fresh start 3 mm below) it is pushed on down."""
    above, below = vertex_over_the_triangle(0.004), vertex_over_the_triangle(-0.003)

    def energy(x):
        normal = np.cross(x[1] - x[0], x[2] - x[0])
        normal /= np.linalg.norm(normal)
        side = np.sign((above[3] - above[0]) @ normal)
        return penalty(side * ((x[3] - x[0]) @ normal), MASS[3])

    force = self_collision_force(above, below)
    np.testing.assert_allclose(force, -energy_gradient(energy, below, 1e-7), atol=1e-6)
    assert force[3, 1] == pytest.approx(MASS[3] * K_HAT * 0.013, rel=1e-9)
    np.testing.assert_allclose(force.sum(axis=0), 0.0, atol=1e-12)
    assert self_collision_force(below)[3, 1] == pytest.approx(-MASS[3] * K_HAT * 0.007, rel=1e-9)


@pytest.mark.parametrize("outside", [0.015, 0.003], ids=["beyond a thickness", "within one"])
def test_a_vertex_that_goes_round_the_edge_changes_side_without_crossing_beyond_a_thickness(
        outside):
    """Vertex 3 passes under the triangle's edge z = −1 from 4 mm above to 4 mm below, outside
    the face, then moves in under it. ``outside`` the edge by more than the thickness (10 mm),
    that is no crossing: it is pushed away, down, and the record says nothing crossed. Within a
    thickness of the edge it is (the cloth is that thick at its border too; a vertex passing a
    corner or an edge of a face closer than that is where the pairs around it are all at their
    borders): the post step put it back above, and the penalty pushes it up, back through the
    face, by m·k̂·(thickness + 4 mm)."""
    steps = [vertex_over_the_triangle(0.004, -1.0 - outside),
             vertex_over_the_triangle(-0.004, -1.0 - outside),
             vertex_over_the_triangle(-0.004, -0.99)]
    force = self_collision_force(*steps)[3, 1]
    if outside > THICKNESS:
        assert force == pytest.approx(-MASS[3] * K_HAT * 0.006, rel=1e-9)
        _, state, _, effect = two_triangle_physics()
        finish_step(effect, state)
        assert effect.frame_metrics(steps[-1], 0.0)["self_collision_crossed"] == 0
    else:
        assert force == pytest.approx(MASS[3] * K_HAT * (THICKNESS + 0.004), rel=1e-9)


def crossing_edges(height: float) -> np.ndarray:
    """Edge 3–4 along z at ``height`` [m] over edge 0–1 along x at y = 0, the triangles turned
    away from each other: only the edge pair is near."""
    return np.array([[-1.0, 0, 0], [1, 0, 0], [0, -1, 0],
                     [0, height, -1], [0.2, height, 1], [0, 1, 0]])


def test_edges_that_crossed_within_a_step_are_pushed_back():
    """Edge 3–4 passes from 5 mm above edge 0–1 to 3 mm below it in one step: pushed back up
    with the mean mass times k̂·(thickness + 3 mm)."""
    mean_mass = MASS[[0, 1, 3, 4]].mean()
    force = self_collision_force(crossing_edges(0.005), crossing_edges(-0.003))
    assert force[[3, 4], 1].sum() == pytest.approx(mean_mass * K_HAT * 0.013, rel=1e-6)


@pytest.mark.parametrize("before, after, kind", [
    (vertex_over_the_triangle(0.004), vertex_over_the_triangle(-0.002), "vertex"),
    (vertex_over_the_triangle(0.006, -1.015), vertex_over_the_triangle(-0.002, -0.95), "vertex"),
    (crossing_edges(0.005), crossing_edges(-0.002), "edges")],
    ids=["through the face", "in over the face and through it", "edge through edge"])
def test_a_step_that_crosses_ends_with_the_pair_a_thickness_apart_on_its_side(before, after,
                                                                            kind):
    """A vertex through a face, a vertex from outside beyond the face's edge (16 mm off it) in
    over the face and through it (inside and above it at ¼ and ½ of the step's path: only the
    path shows the crossing, its end alone is a vertex come in from outside), and an edge
    through an edge, 2 mm deep within one step, particle 3
    moving down at 1 m/s: the step's end (the post step) moves the pair's particles back until
    it is ``SEPARATION`` of the thickness apart (to first order) on the side it came from,
    keeping the momentum, and takes the approach out of the velocities; the record says it
    has not crossed, and the pair is counted once as put back."""
    forces, state, out, effect = two_triangle_physics()
    self_collision_force(before)
    finish_step(effect, state)
    separations = effect.frame_metrics(before, 0.0)["self_collision_separations"]
    state.x.from_numpy(after)
    velocity = np.zeros((6, 3))
    velocity[3, 1] = -1.0
    state.v.from_numpy(velocity)
    finish_step(effect, state)
    x, v = state.x.to_numpy(), state.v.to_numpy()
    if kind == "vertex":
        distance = closest_distance_point_triangle(x[3], x[0], x[1], x[2])
    else:
        distance = closest_distance_segments(x[3], x[4], x[0], x[1])
    assert distance == pytest.approx(SEPARATION * THICKNESS, rel=1e-3)
    assert x[3, 1] > x[0, 1] and x[0, 1] < 0  # particle 3 back above, the other side pushed down
    np.testing.assert_allclose(MASS @ (x - after), 0.0, atol=1e-12)
    np.testing.assert_allclose(MASS @ v, MASS @ velocity, atol=1e-12)
    assert -1.0 < v[3, 1] and v[0, 1] < 0  # the approach shared out
    metrics = effect.frame_metrics(x, 0.0)
    assert metrics["self_collision_crossed"] == 0
    assert metrics["self_collision_separations"] == separations + 1


def test_putting_a_pair_back_stretches_no_spring_past_its_length_before():
    """Vertex 3 through the face 1 cm inside its edge z = −1, 2 mm deep, its spring to particle
    4 already 50 % over its rest length and sloping 10° down from it across that edge (so that,
    put back, it passes the face's plane beyond the face: no edge left through it), so that
    lifting the vertex lengthens the spring by ~0.8 mm: the post step puts the vertex back above
    the face and shortens the spring to its length before the step's sweeps, moving both ends
    along it (vertex 3 stays above)."""
    forces, state, out, effect = two_triangle_physics()
    slope = np.radians(10.0)
    before = vertex_over_the_triangle(0.004, -0.99)
    after = vertex_over_the_triangle(-0.002, -0.99)
    for positions in (before, after):
        positions[4] = positions[3] + 1.5 * np.array([0.0, -np.sin(slope), -np.cos(slope)])
    self_collision_force(before)
    finish_step(effect, state)
    state.x.from_numpy(after)
    state.v.fill(0.0)
    finish_step(effect, state)
    x = state.x.to_numpy()
    assert np.linalg.norm(x[4] - x[3]) == pytest.approx(1.5, rel=1e-12)
    assert 0.5 * SEPARATION * THICKNESS < x[3, 1] - x[0, 1]  # above the face, still apart
    assert effect.frame_metrics(x, 0.0)["self_collision_crossed"] == 0
    np.testing.assert_allclose(MASS @ (x - after), 0.0, atol=1e-12)


def refused_step(physics, before: np.ndarray, after: np.ndarray, refusals: int = 1):
    """A step from ``before`` (a fresh start, its records taken there) to ``after`` whose pair
    may not be put back: checks that the post step leaves ``after`` as it is, counting
    ``refusals`` and no pair put back; returns (the metrics at the end, the forces there at
    rest). physics: (forces, state, output field, the effect)."""
    forces, state, out, effect = physics
    effect.forget_history()
    state.v.fill(0.0)
    state.x.from_numpy(before)
    forces.evaluate(state.x, state.v, 0.0, out)
    finish_step(effect, state)
    counts = effect.frame_metrics(before, 0.0)
    state.x.from_numpy(after)
    finish_step(effect, state)
    x = state.x.to_numpy()
    np.testing.assert_array_equal(x, after)
    metrics = effect.frame_metrics(x, 0.0)
    assert metrics["self_collision_refusals"] == counts["self_collision_refusals"] + refusals
    assert metrics["self_collision_separations"] == counts["self_collision_separations"]
    forces.evaluate(state.x, state.v, 0.0, out)
    return metrics, out.to_numpy()


def test_a_crossing_that_no_triangles_witness_is_not_undone_into_meeting_ones():
    """Triangle 3–4–5 goes from above triangle 0–1–2 to wholly below it in one step, vertex 3
    through the face, 4 and 5 past its sides (the way a hem goes round another layer's border):
    the record says the pair crossed, but no edge pierces a face around it: nothing witnesses
    the crossing, so the post step moves nothing, counts a refusal, and the pair takes the side
    it is on: the penalty then pushes vertex 3 down. (A second refusal: edge 3–4, ending on the
    face's side 1–2, within a thickness of it, is seen crossing that side the same way, and
    gives way too.)"""
    before = np.array([[-1.0, 0, -1], [1, 0, -1], [0, 0, 1],
                       [0.1, 0.004, 0.2], [1.4, 0.004, 0.2], [0.1, 0.004, 1.5]])
    after = before.copy()
    after[3:, 1] = -0.002
    after[4, 0], after[5, 2] = 0.4, 0.5
    metrics, force = refused_step(two_triangle_physics(), before, after, refusals=2)
    assert metrics["self_collision_crossed"] == 0
    assert force[3, 1] == pytest.approx(-MASS[3] * K_HAT * (THICKNESS - 0.002), rel=1e-9)


def fan_over_the_triangle(heights) -> np.ndarray:
    """Triangle (0, 1, 2) in the plane y = 0 and a fan of two, (3, 4, 5) and (3, 5, 6), lying
    over its face, particles 3–6 at ``heights`` [m] above it."""
    x = np.array([[-1.0, 0, -1], [1, 0, -1], [0, 0, 1], [0, 0, -0.3], [0.2, 0, -0.3],
                  [0.1, 0, -0.1], [-0.1, 0, -0.1]])
    x[3:, 1] = heights
    return x


@functools.cache
def fan_physics():
    """The triangle and the fan of ``fan_over_the_triangle`` (at rest flat on it), the masses
    of ``MASS`` and 0.7 kg, with only the effect, built once: (forces, state, output field,
    the effect)."""
    triangles = [[0, 1, 2], [3, 4, 5], [3, 5, 6]]
    model = Model(triangle_mesh(fan_over_the_triangle(np.zeros(4)), triangles,
                                np.append(MASS, 0.7)), "f64")
    physics = assemble(model, [(SelfCollision, SETTINGS)])
    return physics.forces, model.state(), ti.Vector.field(3, ti.f64, 7), physics.effects[0]


def test_a_crossing_inside_a_tangle_keeps_its_record_when_putting_it_back_would_tangle_more():
    """Vertex 3 goes 6 mm down through triangle 0–1–2 in one step, its two triangles (3, 4, 5)
    and (3, 5, 6) standing upright across that face: the first passes through it already
    (vertex 4 above, 5 below), the second hangs below it. Putting vertex 3 back above would take
    the second through the face too (more edges through faces around the pair than before, and
    some before: the record is witnessed), so the post step leaves the positions as they are,
    counts a refusal and keeps the record: the pair stays crossed, and the penalty pushes
    vertex 3 up, back to its side, by m·k̂·(thickness + 2 mm) (a record given way would push it
    down by m·k̂·(thickness − 2 mm))."""
    start = np.array([[-1.0, 0, -1], [1, 0, -1], [0, 0, 1], [0, 0.004, -0.3],
                      [0.05, 0.04, -0.3], [0.05, -0.04, -0.3], [-0.05, -0.04, -0.3]])
    end = start.copy()
    end[3, 1] = -0.002
    metrics, force = refused_step(fan_physics(), start, end)
    assert metrics["self_collision_pairs"] == 1  # vertex 3 and the face, nothing else
    assert metrics["self_collision_crossed"] == 1
    assert force[3, 1] == pytest.approx(MASS[3] * K_HAT * (THICKNESS + 0.002), rel=1e-9)


def test_a_put_back_that_trades_one_piercing_for_another_is_refused():
    """Vertex 3 goes 6 mm down through the face in one step while its neighbours 4 and 6 stay
    2 mm above it and 5 2 mm below: both fan triangles pass through the face, two edges of each.
    Putting vertex 3 back above would leave two edges of each through it still (others): no
    fewer, so the positions stay, a refusal is counted, and the record, witnessed, stays
    crossed."""
    before = fan_over_the_triangle([0.004, 0.002, -0.002, 0.002])
    after = fan_over_the_triangle([-0.002, 0.002, -0.002, 0.002])
    metrics, _ = refused_step(fan_physics(), before, after)
    assert metrics["self_collision_crossed"] == 1


def test_a_crossing_whose_witness_a_later_put_back_removes_takes_the_side_it_is_on():
    """In one step vertex 3 goes from 4 mm above the face to 2 mm below it and vertex 6 from
    4 mm below to 2 mm above, the fan's other particles staying 2 mm below. Vertex 3's pair,
    first in the list, has edges through the face around it (3–6, 5–6: a witness), and putting
    it back would leave more (3–4, 3–5), so it is refused and stays crossed; vertex 6's pair,
    put back below, takes those edges out. The last pass then finds vertex 3's record crossed
    with nothing witnessing it: it takes the side vertex 3 is on, below, and the penalty pushes
    it on down, clear of the face, not up through it."""
    forces, state, out, effect = fan_physics()
    effect.forget_history()
    state.v.fill(0.0)
    state.x.from_numpy(fan_over_the_triangle([0.004, -0.002, -0.002, -0.004]))
    forces.evaluate(state.x, state.v, 0.0, out)
    finish_step(effect, state)
    counts = effect.frame_metrics(state.x.to_numpy(), 0.0)
    after = fan_over_the_triangle([-0.002, -0.002, -0.002, 0.002])
    state.x.from_numpy(after)
    finish_step(effect, state)
    x = state.x.to_numpy()
    metrics = effect.frame_metrics(x, 0.0)
    assert metrics["self_collision_refusals"] == counts["self_collision_refusals"] + 1
    assert metrics["self_collision_separations"] == counts["self_collision_separations"] + 1
    assert metrics["self_collision_crossed"] == 0
    np.testing.assert_array_equal(x[3], after[3])
    assert x[6, 1] < x[0, 1]  # vertex 6 back below the face
    forces.evaluate(state.x, state.v, 0.0, out)
    force = out.to_numpy()[3]  # along the face's normal, tilted a little by the put-back
    distance = closest_distance_point_triangle(x[3], x[0], x[1], x[2])
    assert np.linalg.norm(force) == pytest.approx(MASS[3] * K_HAT * (THICKNESS - distance),
                                                  rel=1e-9)
    assert force[1] < 0


@pytest.mark.parametrize("mend", ["next step", "repair"])
def test_a_vertex_that_comes_through_the_face_from_beyond_the_reach_in_one_step_is_put_back(mend):
    """Vertex 3 three centimetres above the triangle (beyond the list's reach) after a step and
    3 mm below it after the next, with no force evaluation near it: the next step, or the
    frame-end ``repair``, lists the pair with its side from where the vertex was last seen with
    the list whole, and puts the vertex back above."""
    forces, state, out, effect = two_triangle_physics()
    self_collision_force(vertex_over_the_triangle(0.03))
    finish_step(effect, state)
    state.x.from_numpy(vertex_over_the_triangle(-0.003))
    finish_step(effect, state)
    if mend == "next step":
        forces.evaluate(state.x, state.v, 0.0, out)
        finish_step(effect, state)
    else:
        effect.repair(state)
    x = state.x.to_numpy()
    assert x[3, 1] > x[0, 1] and effect.frame_metrics(x, 0.0)["self_collision_crossed"] == 0


def test_a_redone_frame_gets_back_the_records_of_its_start():
    """Records kept at a frame's start with vertex 3 above the face (``back_up``); the frame
    takes it round the triangle's edge, 15 mm out, to below the face (no crossing: pushed on down
    there), then is rolled back: the side of the start is what counts again, so the vertex
    3 mm below is pushed back up; and the list's builds, its dropped pairs, the put-backs and
    the refusals counted in the discarded frame are not counted."""
    forces, state, out, effect = two_triangle_physics()
    below = vertex_over_the_triangle(-0.003)
    self_collision_force(vertex_over_the_triangle(0.004))
    finish_step(effect, state)
    effect.back_up()
    counters = (effect.pairs.rebuilds, effect.pairs.overflow, effect.separations, effect.refusals)
    counted = [counter[None] for counter in counters]
    for positions in (vertex_over_the_triangle(0.004, -1.015),
                      vertex_over_the_triangle(-0.004, -1.015), below):
        state.x.from_numpy(positions)
        effect.pairs.ask_rebuild()
        forces.evaluate(state.x, state.v, 0.0, out)
        finish_step(effect, state)
    for counter in counters[1:]:  # (as a discarded try may have counted them)
        counter[None] += 3
    assert effect.pairs.rebuilds[None] >= counted[0] + 3
    forces.evaluate(state.x, state.v, 0.0, out)
    assert out.to_numpy()[3, 1] == pytest.approx(-MASS[3] * K_HAT * 0.007, rel=1e-9)
    effect.roll_back()
    assert [counter[None] for counter in counters] == counted
    state.x.from_numpy(below)
    forces.evaluate(state.x, state.v, 0.0, out)
    assert out.to_numpy()[3, 1] == pytest.approx(MASS[3] * K_HAT * 0.013, rel=1e-9)


def test_thickness_of_half_the_median_edge_or_more_is_one_line_exit_2(capsys):
    assert main(["simulate", "fold", "--frames", "1", "--set",
                 "effects.self_collision.thickness=0.5", "--out", "/nonexistent/x"]) == 2
    message = capsys.readouterr().err.strip()
    assert "effects.self_collision.thickness" in message and "\n" not in message
    assert "below 0.02 m" in message  # the bound itself: half of fold's 4 cm edges


@pytest.mark.parametrize("distance", [0.004, 0.0015])
def test_the_pairs_left_out_are_every_pair_that_close_in_the_starting_shape(distance):
    """``rest_neighbours`` on a disc whose inner rings have edges of 1–2 mm (a drape tester's
    specimen round a small hole) against a brute-force search over every vertex and triangle it
    is not a corner of and every two edges that share no particle; and on two such discs laid 1
    mm apart, one over the other: layers, not neighbours, so only each disc's own pairs."""
    from taichi_cloth.cloth.garment import build_garment
    from taichi_cloth.config.materials import PRESETS
    from taichi_cloth.config.tables import ClothConfig
    from taichi_cloth.effects.rest_neighbours import rest_neighbours
    cloth = ClothConfig(shape="disc", resolution=(24, 6), waist_radius=0.005, hem_radius=0.05,
                        height=0.5, pin="none")
    garment = build_garment(cloth, PRESETS["cotton"])
    x, triangles, edges = garment.positions, garment.triangles, garment.edges
    vertex, triangle = (index.ravel() for index in np.indices((len(x), len(triangles))))
    apart = (triangles[triangle] != vertex[:, None]).all(axis=1)
    vertex, triangle = vertex[apart], triangle[apart]
    near = closest_distance_point_triangle(x[vertex], *(x[triangles[triangle][:, k]]
                                                        for k in range(3))) < distance
    first, second = np.triu_indices(len(edges), 1)
    apart = (edges[first][:, :, None] != edges[second][:, None, :]).all(axis=(1, 2))
    first, second = first[apart], second[apart]
    close = closest_distance_segments(*(x[edges[first][:, k]] for k in range(2)),
                                      *(x[edges[second][:, k]] for k in range(2))) < distance
    vertex_triangle, edge_edge = rest_neighbours(x, triangles, edges, distance)
    assert len(vertex_triangle) > 20 and len(edge_edge) > 20
    assert {tuple(p) for p in vertex_triangle} == set(zip(vertex[near], triangle[near]))
    assert {tuple(p) for p in edge_edge} == set(zip(first[close], second[close]))
    assert (np.diff(vertex_triangle[:, 0]) >= 0).all() and (np.diff(edge_edge[:, 0]) >= 0).all()
    n, t, e = len(x), len(triangles), len(edges)
    layered = rest_neighbours(np.concatenate([x, x + [0.0, 0.001, 0.0]]),
                              np.concatenate([triangles, triangles + n]),
                              np.concatenate([edges, edges + n]), distance)
    np.testing.assert_array_equal(layered[0], np.concatenate([vertex_triangle,
                                                              vertex_triangle + [n, t]]))
    np.testing.assert_array_equal(layered[1], np.concatenate([edge_edge, edge_edge + e]))


@pytest.mark.parametrize("columns", [11, 12, 13, 14, 15])
@pytest.mark.parametrize("distance", [0.0035, 0.004])
def test_the_pairs_left_out_do_not_depend_on_where_the_grid_cells_fall(columns, distance):
    """``rest_neighbours`` on a sheet of 1 cm cells, 8 rows, its fifth column onwards moved 8 mm
    closer (edges of 2 mm), at sizes and distances that put the grown boxes' extent either side
    of a whole number of cells (a grid keyed apart for particles and triangles once matched none
    at 12 and 14 columns and 4 mm, 15 and 3.5 mm), against the brute-force search."""
    from taichi_cloth.cloth.garment import build_garment
    from taichi_cloth.config.materials import PRESETS
    from taichi_cloth.config.tables import ClothConfig
    from taichi_cloth.effects.rest_neighbours import rest_neighbours
    cloth = ClothConfig(shape="sheet", resolution=(columns, 8), size=((columns - 1) * 0.01, 0.07),
                        height=1.0, orientation="horizontal", pin="none")
    garment = build_garment(cloth, PRESETS["cotton"])
    x, triangles = garment.positions.copy(), garment.triangles
    column_x = np.unique(x[:, 0])
    x[x[:, 0] >= column_x[4], 0] -= 0.008
    vertex, triangle = (index.ravel() for index in np.indices((len(x), len(triangles))))
    apart = (triangles[triangle] != vertex[:, None]).all(axis=1)
    vertex, triangle = vertex[apart], triangle[apart]
    near = closest_distance_point_triangle(x[vertex], *(x[triangles[triangle][:, k]]
                                                        for k in range(3))) < distance
    found = rest_neighbours(x, triangles, garment.edges, distance)[0]
    assert len(found) > 20
    assert {tuple(p) for p in found} == set(zip(vertex[near], triangle[near]))


FOLD = ("cloth.resolution=[12, 12]",)  # `fold` small: its halves meet at frame 13
FOLD_FRAMES, FOLD_KEPT = 16, 13


@pytest.fixture(scope="module")
def fold_runs(tmp_path_factory):
    """`fold` for 16 frames with and without self-collision: the stats of each; with it also
    the simulation, its state at frame 13 with what its effects carry (``snapshot(effects=
    True)``, as a checkpoint keeps it) and the last frame's positions."""
    simulation = Simulation.from_scene("fold", FOLD)
    record = RunRecord()
    settle(simulation, record)
    kept = {}

    def keep(frame, _metrics):
        if frame == FOLD_KEPT:
            kept["snapshot"] = simulation.snapshot(effects=True)

    simulation.run(FOLD_FRAMES, keep, record)
    out = tmp_path_factory.mktemp("fold_off")
    assert main(["simulate", "fold", "--quiet", "--frames", str(FOLD_FRAMES), "--set", FOLD[0],
                 "--out", str(out), "--set", "effects.self_collision=false",
                 "--meshes", "ply"]) == 0
    return {"on": simulation.stats(record), "off": json.loads((out / "stats.json").read_text()),
            "off_folder": out, "simulation": simulation, "kept": kept["snapshot"],
            "last": simulation.positions()}


def test_fold_never_passes_through_itself_and_does_without_self_collision(fold_runs):
    on, off = fold_runs["on"], fold_runs["off"]
    assert "self_collision" in on["effects"] and "self_collision" not in off["effects"]
    assert all(frame["self_intersections"] == 0 for frame in on["per_frame"])
    assert on["per_frame"][-1]["self_collision_overflow"] == 0
    assert on["max_strain"] < 0.1 and on["max_penetration"] < 0.004
    assert off["max_self_intersections"] > 0


def test_blender_counts_the_crossings_of_each_frame_as_the_metric_does(fold_runs,
                                                                        blender_python):
    """An independent reader: Blender's PLY importer and its BVH's triangle–triangle overlap
    (``scripts/check-crossings-blender.py``) count, in every written frame of `fold` without
    self-collision, as many pairs of triangles through each other as ``stats.json`` says."""
    assert fold_runs["off"]["max_self_intersections"] > 0  # (frames that cross to count)
    result = subprocess.run([str(blender_python), "scripts/check-crossings-blender.py",
                             str(fold_runs["off_folder"])], cwd=blender_python.parents[2],
                            capture_output=True, text=True, timeout=300)
    assert result.returncode == 0 and "differs" not in result.stdout, \
        result.stdout + result.stderr


def test_fold_restored_from_its_snapshot_takes_the_very_same_steps(fold_runs):
    """A checkpoint's snapshot of frame 13 (the halves met: pairs listed, sides recorded)
    put back: frames 14 to 16 again end bit for bit where they ended, with the same counts
    (without the effects' memory the list is built afresh at the restore: one build more)."""
    simulation, kept, on = fold_runs["simulation"], fold_runs["kept"], fold_runs["on"]
    assert kept.effect_memory["self_collision.found_count"].sum() > 0
    simulation.restore(kept)
    again = simulation.run(FOLD_FRAMES, record=RunRecord(), first_frame=FOLD_KEPT + 1)
    np.testing.assert_array_equal(simulation.positions(), fold_runs["last"])
    for name in ("self_collision_builds", "self_collision_separations", "self_collision_pairs"):
        assert again.frames[-1].as_dict()[name] == on["per_frame"][-1][name], name


def crossings_at_shared_vertices(positions: np.ndarray, triangles: np.ndarray) -> int:
    """Pairs of triangles sharing exactly one vertex v that pass through each other beyond it,
    which the metric (pairs sharing no vertex) leaves out. Independent of the simulator: two
    non-coplanar triangles sharing v meet along their planes' line through v, each in the
    direction ±(n₁ × n₂) that lies inside its corner angle at v (if any); they cross beyond v
    iff one direction lies inside both angles."""
    corner_of = {}
    for t, corners in enumerate(triangles.tolist()):
        for v in corners:
            corner_of.setdefault(v, []).append(t)
    pairs = [(t, u, v) for v, around in corner_of.items() for k, t in enumerate(around)
             for u in around[k + 1:] if len(set(triangles[t]) & set(triangles[u])) == 1]
    if not pairs:
        return 0
    t, u, v = np.array(pairs).T
    x = positions

    def corner(tri):  # (v, the other two corners) of each pair's triangle
        others = np.sort(np.where(triangles[tri] != v[:, None], triangles[tri], -1), axis=1)
        return x[v], x[others[:, 1]], x[others[:, 2]]

    def inside_angle(apex, a, b, normal, direction):
        return (dot(np.cross(a - apex, direction), normal) > 0) \
            & (dot(np.cross(direction, b - apex), normal) > 0)

    (apex, a, b), (_, c, d) = corner(t), corner(u)
    n_t, n_u = np.cross(a - apex, b - apex), np.cross(c - apex, d - apex)
    line = np.cross(n_t, n_u)
    crossing = np.zeros(len(pairs), dtype=bool)
    for sign in (1.0, -1.0):
        crossing |= inside_angle(apex, a, b, n_t, sign * line) \
            & inside_angle(apex, c, d, n_u, sign * line)
    return int(np.count_nonzero(crossing))


def test_the_shared_vertex_crossing_count_sees_a_fan_folded_through_itself():
    """Two triangles sharing vertex 0: apart in a plane (0), the second standing through the
    first's face (1), the second above the first plane touching it only at the vertex (0)."""
    triangles = np.array([[0, 1, 2], [0, 3, 4]])
    base = [[0, 0, 0], [1, 0, 0], [1, 1, 0]]
    assert crossings_at_shared_vertices(np.array(base + [[0, 1, 0.1], [-1, 0, 0.1]], float),
                                        triangles) == 0
    assert crossings_at_shared_vertices(np.array(base + [[1, 0.5, 1], [1, 0.5, -1]], float),
                                        triangles) == 1
    assert crossings_at_shared_vertices(np.array(base + [[1, 0.5, 1], [1, 0.6, 2]], float),
                                        triangles) == 0


def test_pile_folds_onto_itself_on_the_floor_without_passing_through(tmp_path):
    """`pile` (10 × 20, 1 s): the sheet dropped on its edge comes down, folds back and forth onto
    itself (the floor under it is much shorter than the sheet), and no two triangles cross in
    any frame, neither by the metric nor, in the exported meshes, two sharing a vertex; the
    tunnelling guard's halvings are reported per frame."""
    assert main(["simulate", "pile", "--quiet", "--frames", "30", "--set",
                 "cloth.resolution=[10, 20]", "--out", str(tmp_path), "--meshes", "obj"]) == 0
    stats = json.loads((tmp_path / "stats.json").read_text())
    assert all(frame["self_intersections"] == 0 for frame in stats["per_frame"])
    assert all("tunnelling_halvings" in frame for frame in stats["per_frame"])
    assert stats["max_strain"] < 0.03 and stats["max_penetration"] < 0.004
    meshes = [meshio.read(path) for path in sorted((tmp_path / "meshes").glob("cloth_*.obj"))]
    assert len(meshes) == 31
    triangles = meshes[0].cells_dict["triangle"]
    assert all(crossings_at_shared_vertices(mesh.points, triangles) == 0 for mesh in meshes)
    last = meshes[-1].points
    assert last[:, 1].max() < 0.25  # it has come down from 1.03 m
    footprint = np.ptp(last[:, 2]) + np.ptp(last[:, 1])
    assert footprint < 0.6  # a metre of fabric in under 0.6 m: folded onto itself


def dot(u, v):
    return np.sum(u * v, axis=-1)


def closest_distance_point_triangle(p, a, b, c):
    """Distance from p to triangle (a, b, c), points (..., 3) over any leading axes: to its plane
    where the projection falls inside, else to the nearest of its sides (an oracle independent
    of the effect's Voronoi regions)."""
    normal = np.cross(b - a, c - a)
    normal = normal / np.linalg.norm(normal, axis=-1, keepdims=True)
    height = dot(p - a, normal)
    projected = p - height[..., None] * normal
    sides = ((a, b), (b, c), (c, a))
    inside = np.all([dot(np.cross(q1 - q0, projected - q0), normal) >= 0 for q0, q1 in sides],
                    axis=0)
    nearest_side = np.min([closest_distance_point_segment(p, q0, q1) for q0, q1 in sides], axis=0)
    return np.where(inside, np.abs(height), nearest_side)[()]


def closest_distance_point_segment(p, a, b):
    t = np.clip(dot(p - a, b - a) / dot(b - a, b - a), 0.0, 1.0)
    return np.linalg.norm(p - (a + t[..., None] * (b - a)), axis=-1)


def closest_distance_segments(a, b, c, d):
    """Distance between segments ab and cd, points (..., 3) over any leading axes: the interior
    stationary point of |P(s) − Q(u)|² (Cramer's rule) when it lies in the unit square, else the
    smallest of the four end-to-segment distances."""
    candidates = [closest_distance_point_segment(a, c, d), closest_distance_point_segment(b, c, d),
                  closest_distance_point_segment(c, a, b), closest_distance_point_segment(d, a, b)]
    d1, d2, r = b - a, d - c, a - c
    m11, m12, m22 = dot(d1, d1), -dot(d1, d2), dot(d2, d2)
    right_s, right_u = -dot(d1, r), dot(d2, r)
    determinant = m11 * m22 - m12 * m12
    regular = np.abs(determinant) > 1e-14
    safe = np.where(regular, determinant, 1.0)
    s = (right_s * m22 - m12 * right_u) / safe
    u = (m11 * right_u - m12 * right_s) / safe
    interior = regular & (0 <= s) & (s <= 1) & (0 <= u) & (u <= 1)
    stationary = np.linalg.norm(a + s[..., None] * d1 - (c + u[..., None] * d2), axis=-1)
    candidates.append(np.where(interior, stationary, np.inf))
    return np.min(candidates, axis=0)[()]


@functools.cache
def folded_sheet_physics(columns: int = 8, side: float = 0.14, rewound: bool = False,
                         squeezed: bool = False):
    """A columns × columns sheet of ``side`` [m] (by default 2 cm spacing) with self-collision at
    its defaults (thickness 4 mm, reach 8 mm), built once each: (model, forces, state, output
    field, effect). ``rewound``: the triangles of the half that ``folded_positions`` turns over
    wound the other way (a garment file need not keep its winding). ``squeezed``: its third
    column of particles moved to 1.5 mm from the second (edges far shorter than the thickness,
    as a garment file's dart may have)."""
    from dataclasses import replace

    from taichi_cloth.cloth.garment import build_garment
    from taichi_cloth.config.materials import PRESETS
    from taichi_cloth.config.tables import ClothConfig
    cloth = ClothConfig(shape="sheet", resolution=(columns, columns), size=(side, side), height=1.0,
                        orientation="horizontal", pin="none")
    garment = build_garment(cloth, PRESETS["cotton"])
    if rewound:
        x = garment.positions
        turned = x[garment.triangles].mean(axis=1)[:, 0] > 0.5 * (x[:, 0].min() + x[:, 0].max())
        triangles = garment.triangles.copy()
        triangles[turned] = triangles[turned][:, ::-1]
        garment = replace(garment, triangles=triangles)
    if squeezed:
        x = garment.positions.copy()
        column_x = np.unique(x[:, 0])
        x[x[:, 0] == column_x[2], 0] = column_x[1] + 0.0015
        garment = replace(garment, positions=x)
    model = Model(garment, "f64")
    physics = assemble(model, [(SelfCollision, SelfCollisionSettings())])
    effect = physics.effects[0]
    return model, physics.forces, model.state(), ti.Vector.field(3, ti.f64, model.particle_count), \
        effect


def folded_positions(model, gap: float = 0.006, jitter: float = 0.002) -> np.ndarray:
    """The sheet folded in half across x (the right half turned back over the left, ``gap``
    [m] above it), every particle jittered by up to ``jitter`` [m]: pairs at every distance
    around the reach."""
    rest = model.garment.positions
    x = rest.copy()
    middle = 0.5 * (rest[:, 0].min() + rest[:, 0].max())
    right = rest[:, 0] > middle + 1e-9
    x[right, 0] = 2 * middle - rest[right, 0]
    x[right, 1] += gap
    return x + np.random.default_rng(7).uniform(-jitter, jitter, x.shape)


def flat_patch_pairs(x: np.ndarray, triangles: np.ndarray, triangle_patch: np.ndarray,
                     flat_degrees: float = 60.0):
    """Which pairs of patches (of the given cut) hold no layers at x, as a function of two
    patch indices (an oracle written apart from ``effects/mesh_patches.py``: sets of particles,
    angles from NumPy's arccos). A patch's cone: about its triangles' mean unit normal, as wide
    as the widest angle to one of them; a neighbourhood's (a patch and the patches sharing a
    particle with it): about the mean of their axes, as wide as the widest angle to one of
    their axes plus that cone's own half-angle. Two cones fit in one within 60° when both are
    and the angle between their axes plus both half-angles is at most 120°. Left out: a patch
    with itself when its cone is flat, patches sharing a particle when their cones fit in a flat
    one, patches sharing a particle with a common patch when their neighbourhoods' cones do.
    The triangles must be wound alike."""
    count = triangle_patch.max() + 1
    a, b, c = (x[triangles[:, k]] for k in range(3))
    normal = np.cross(b - a, c - a)
    normal /= np.linalg.norm(normal, axis=1, keepdims=True)

    def angle(u, v):
        return np.arccos(np.clip(u @ v, -1.0, 1.0))

    cones = []
    for p in range(count):
        mine = normal[triangle_patch == p]
        axis = mine.sum(axis=0) / np.linalg.norm(mine.sum(axis=0))
        cones.append((axis, max(angle(axis, n) for n in mine)))
    particles = [set(triangles[triangle_patch == p].ravel()) for p in range(count)]
    touching = [{q for q in range(count) if q != p and particles[p] & particles[q]}
                for p in range(count)]
    around = []
    for p in range(count):
        members = [cones[q] for q in [p, *sorted(touching[p])]]
        axis = sum(a for a, _ in members)
        axis = axis / np.linalg.norm(axis)
        around.append((axis, max(angle(axis, a) + h for a, h in members)))
    flat = np.radians(flat_degrees)

    def fit(first, second):
        return first[1] <= flat and second[1] <= flat and \
            angle(first[0], second[0]) + first[1] + second[1] <= 2 * flat

    def culled(p, q):
        if p == q:
            return cones[p][1] <= flat
        if q in touching[p]:
            return fit(cones[p], cones[q])
        if touching[p] & touching[q]:
            return fit(around[p], around[q])
        return False
    return culled


def mesh_hops(edges: np.ndarray, count: int) -> np.ndarray:
    """(count, count): how many edges apart each two particles are along the mesh."""
    hops = np.full((count, count), count)
    np.fill_diagonal(hops, 0)
    hops[edges[:, 0], edges[:, 1]] = hops[edges[:, 1], edges[:, 0]] = 1
    for middle in range(count):  # Floyd–Warshall
        hops = np.minimum(hops, hops[:, middle:middle + 1] + hops[middle:middle + 1, :])
    return hops


def listed_pairs(pairs) -> set:
    count = pairs.pair_count[None]
    kinds = pairs.pair_kind.to_numpy()[:count]
    particles = pairs.pair_particles.to_numpy()[:count]
    return {(int(kind), tuple(int(i) for i in ids)) for kind, ids in zip(kinds, particles)}


@pytest.mark.parametrize("columns, side, gap, jitter, squeezed", [
    (8, 0.14, 0.006, 0.002, False),  # 2 cm spacing, layers 6 mm apart
    (12, 0.0915, 0.004, 0.001, False),  # 8.3 mm spacing: the bound's largest reach, 4 mm apart
    (8, 0.14, 0.006, 0.001, True),  # a column of edges 1.5 mm long, within the thickness
])
def test_the_candidate_list_holds_exactly_the_layered_pairs_within_the_reach(columns, side, gap,
                                                                           jitter, squeezed):
    """Against a brute-force NumPy search over every vertex and triangle it is not a corner of
    and every two edges that share no particle, on a folded sheet, less the pairs whose patches
    hold no layers (``flat_patch_pairs``) and the pairs within the thickness of each other in the
    sheet's rest shape (around the squeezed column, whose jittered triangles are not flat):
    with pairs at every distance around the reach, and as densely as the thickness bound allows
    (every walk's and the list's capacity holds). The fold's layers are all listed; in the dense
    sheet, the flat layers' own neighbours within the reach are not."""
    model, forces, state, out, effect = folded_sheet_physics(columns, side, squeezed=squeezed)
    x = folded_positions(model, gap, jitter)
    state.x.from_numpy(x)
    state.v.fill(0.0)
    effect.pairs.ask_rebuild()
    forces.evaluate(state.x, state.v, 0.0, out)
    reach = effect.reach
    triangles, edges = model.garment.triangles, model.garment.edges
    patches = effect.pairs.patches
    triangle_patch = patches.triangle_patch
    culled = flat_patch_pairs(x, triangles, triangle_patch)
    home = np.full(len(x), -1)
    for t in range(len(triangles) - 1, -1, -1):
        home[triangles[t]] = triangle_patch[t]
    edge_patch = {}  # an edge's patch: its first triangle's
    for t in range(len(triangles) - 1, -1, -1):
        for k in range(3):
            edge_patch[tuple(sorted((int(triangles[t][k]), int(triangles[t][(k + 1) % 3]))))] = \
                int(triangle_patch[t])
    vertex, triangle = (index.ravel() for index in np.indices((len(x), len(triangles))))
    apart = (triangles[triangle] != vertex[:, None]).all(axis=1)  # not a corner of it
    vertex, triangle = vertex[apart], triangle[apart]
    corners = triangles[triangle]
    vertex_distance = closest_distance_point_triangle(x[vertex], *(x[corners[:, k]]
                                                                   for k in range(3)))
    first, second = np.triu_indices(len(edges), 1)
    apart = (edges[first][:, :, None] != edges[second][:, None, :]).all(axis=(1, 2))
    first, second = first[apart], second[apart]  # every two edges that share no particle
    edge_distance = closest_distance_segments(*(x[edges[first][:, k]] for k in range(2)),
                                              *(x[edges[second][:, k]] for k in range(2)))
    rest = model.garment.positions  # pairs this close at rest: left out for good
    vertex_at_rest = closest_distance_point_triangle(rest[vertex], *(rest[corners[:, k]]
                                                                     for k in range(3)))
    edge_at_rest = closest_distance_segments(*(rest[edges[first][:, k]] for k in range(2)),
                                             *(rest[edges[second][:, k]] for k in range(2)))
    borderline = sum(np.sum(np.abs(distance - limit) < 1e-9) for distance, limit in [
        (vertex_distance, reach), (edge_distance, reach), (vertex_at_rest, effect.thickness),
        (edge_at_rest, effect.thickness)])
    at_rest = np.sum(vertex_at_rest < effect.thickness) + np.sum(edge_at_rest < effect.thickness)
    assert (at_rest > 0) == squeezed
    hops = mesh_hops(edges, len(x))
    expected, left_out = set(), []
    near = (vertex_distance <= reach) & (vertex_at_rest >= effect.thickness)
    for p, t, corner_ids in zip(vertex[near], triangle[near], corners[near]):
        if culled(home[p], triangle_patch[t]):
            left_out.append(hops[p, corner_ids].min())
        else:
            expected.add((0, (int(p), *(int(c) for c in corner_ids))))
    near = (edge_distance <= reach) & (edge_at_rest >= effect.thickness)
    for e, f in zip(first[near], second[near]):
        ids = (*(int(i) for i in edges[e]), *(int(i) for i in edges[f]))
        if culled(edge_patch[ids[:2]], edge_patch[ids[2:]]):
            left_out.append(hops[np.ix_(ids[:2], ids[2:])].min())
        else:
            expected.add((1, ids))
    assert borderline == 0
    assert len(expected) > 100  # the fold brings the layers within reach all over
    # left out: pairs in flat stretches (the sheet's own neighbours, the fold's crease), each an
    # edge or two from its other primitive: neighbours along the cloth, never two layers
    assert len(left_out) > 0 and max(left_out) <= 2
    assert listed_pairs(effect.pairs) == expected
    assert len(expected) == effect.pairs.pair_count[None]  # each pair listed once
    assert effect.pairs.overflow[None] == 0


@ti.kernel
def culled_pairs_of_patches(patches: ti.template(), relation: ti.types.ndarray(),
                            out: ti.types.ndarray()):
    for p, q in ti.ndrange(patches.count, patches.count):
        out[p, q] = patches.culled(p, q, relation[p, q])


def patches_culled(patches) -> np.ndarray:
    """(count, count): ``MeshPatches.culled`` of every pair of patches, each pair's relation
    taken from ``cut_patches``' near lists."""
    relation = np.zeros((patches.count, patches.count), np.int32)  # NOT_NEAR
    start, near = patches.near_start.to_numpy(), patches.near.to_numpy()
    for p in range(patches.count):
        for q, how in near[start[p]:start[p + 1]]:
            relation[p, q] = how
    culled = np.zeros_like(relation)
    culled_pairs_of_patches(patches, relation, culled)
    return culled


def bent_positions(model, radius: float) -> np.ndarray:
    """The sheet rolled about the z axis onto a cylinder of ``radius`` [m] (its normals turning
    by the sheet's width over the radius), then jittered by 0.5 mm."""
    x = model.garment.positions.copy()
    across = x[:, 0] - x[:, 0].mean()
    x[:, 0] = radius * np.sin(across / radius)
    x[:, 1] += radius * (1 - np.cos(across / radius))
    return x + np.random.default_rng(3).uniform(-0.0005, 0.0005, x.shape)


@pytest.mark.parametrize("shape", ["folded", "bent 6 cm", "bent 3 cm", "bent 2 cm"])
def test_which_pairs_of_patches_are_left_out_agrees_with_the_cones_computed_apart(shape):
    """Every pair of patches, near or not, within the reach or not, on the dense sheet folded or
    rolled onto cylinders (every ring of neighbours then flat, some and none): ``culled`` against
    ``flat_patch_pairs``; pairs within 10⁻⁶° of the 60° bound are skipped, and each case has
    patches left out on both grounds (touching, and touching a common patch) and kept."""
    model, forces, state, out, effect = folded_sheet_physics(12, 0.0915)
    x = folded_positions(model, 0.004, 0.001) if shape == "folded" else \
        bent_positions(model, float(shape.split()[1]) / 100)
    state.x.from_numpy(x)
    state.v.fill(0.0)
    effect.pairs.ask_rebuild()
    forces.evaluate(state.x, state.v, 0.0, out)
    patches = effect.pairs.patches
    culled = patches_culled(patches)
    triangles, triangle_patch = model.garment.triangles, patches.triangle_patch
    narrower, wider = (flat_patch_pairs(x, triangles, triangle_patch, 60.0 + step)
                       for step in (-1e-6, 1e-6))
    particles = [set(triangles[triangle_patch == p].ravel()) for p in range(patches.count)]
    touching = [{q for q in range(patches.count) if particles[p] & particles[q]}
                for p in range(patches.count)]
    left_out = collections.Counter()  # (how near, left out): pairs of patches
    for p, q in np.ndindex(culled.shape):
        if narrower(p, q) == wider(p, q):
            assert culled[p, q] == narrower(p, q), (p, q)
            near = "itself" if p == q else "touching" if q in touching[p] else \
                "common" if touching[p] & touching[q] else "apart"
            left_out[(near, bool(culled[p, q]))] += 1
    assert sum(left_out.values()) > 0.99 * culled.size
    assert left_out[("apart", True)] == 0
    if shape == "bent 6 cm":  # every neighbourhood flat
        assert left_out[("touching", False)] == left_out[("common", False)] == 0
    else:  # both rings of neighbours left out and kept
        assert left_out[("common", True)] > 0 and left_out[("common", False)] > 0


def test_each_build_lists_every_pair_of_overlapping_patches_the_cones_keep_in_order():
    """Each patch's partners against every pair of patches' boxes tested in NumPy (each patch's
    triangles' corners, grown by half the reach), less the pairs ``culled`` leaves out (checked
    against the cones computed apart above), in ascending order; over builds of the folded
    sheet turned so that the widest axis, and so the sweep's, changes at each (each build sorts
    the patches from the last one's order along another axis), then waved along z by x, so
    that the patches' order along z is shuffled."""
    model, forces, state, out, effect = folded_sheet_physics(12, 0.0915)
    folded = folded_positions(model, 0.004, 0.001)
    waved = folded + np.outer(0.04 * np.sin(300.0 * folded[:, 0]), [0.0, 0.0, 1.0])
    patches = effect.pairs.patches
    turns = [np.eye(3), np.array([[0.0, 0, 1], [0, 1, 0], [-1, 0, 0]]),  # about y
             np.array([[1.0, 0, 0], [0, 0, -1], [0, 1, 0]])]  # about x
    triangles, triangle_patch = model.garment.triangles, patches.triangle_patch
    axes = []
    for x in [folded @ turn.T + np.array([0.3, -0.2, 0.1]) for turn in turns] + [waved]:
        kept = check_partners(model, forces, state, out, effect, x)
        assert kept.sum() > patches.count  # the fold's layers: partners beyond themselves
        axes.append(int(patches.sweep_axis[None]))
    assert axes == [2, 0, 1, 2]  # the sheet's widest spread along z, then x, then y, then z


def check_partners(model, forces, state, out, effect, x: np.ndarray) -> np.ndarray:
    """Build the list at x; assert each patch's partners are, in ascending order, the patches
    whose boxes (its triangles' corners grown by half the reach, in NumPy) overlap its own and
    that ``culled`` keeps; return that (count, count) matrix of kept pairs."""
    state.x.from_numpy(x)
    state.v.fill(0.0)
    effect.pairs.ask_rebuild()
    forces.evaluate(state.x, state.v, 0.0, out)
    patches = effect.pairs.patches
    triangle_patch = patches.triangle_patch
    corners = x[model.garment.triangles]
    grow = 0.5 * effect.reach
    lower = np.array([corners[triangle_patch == p].reshape(-1, 3).min(axis=0) - grow
                      for p in range(patches.count)])
    upper = np.array([corners[triangle_patch == p].reshape(-1, 3).max(axis=0) + grow
                      for p in range(patches.count)])
    overlap = ((lower[:, None] <= upper[None]) & (lower[None] <= upper[:, None])).all(axis=2)
    culled = patches_culled(patches)
    listed = patches.partner.to_numpy()
    counts = patches.partner_count.to_numpy()
    kept = overlap & (culled == 0)
    for p in range(patches.count):
        assert list(listed[p, :counts[p]]) == list(np.flatnonzero(kept[p])), p
    return kept


def test_a_sheet_rolled_round_more_than_once_lists_its_flat_wraps_as_partners():
    """The dense sheet rolled into a spiral of 1.2 cm radius, its second wrap 4 mm outside the
    first: patches a wrap apart lie over each other with their normals alike and their cones
    flat, but they are far apart along the cloth, so they are partners (``culled`` keeps every
    pair that is not near along the cloth, however flat), each patch's as listed against NumPy
    (``check_partners``)."""
    model, forces, state, out, effect = folded_sheet_physics(12, 0.0915)
    rest = model.garment.positions
    along = rest[:, 0] - rest[:, 0].min()  # arc length round the spiral [m]
    radius = 0.012 + 0.004 * along / (2 * np.pi * 0.012)
    angle = along / 0.012
    x = np.stack([radius * np.cos(angle), radius * np.sin(angle), rest[:, 2]], axis=1)
    kept = check_partners(model, forces, state, out, effect, x)
    patches = effect.pairs.patches
    triangles, triangle_patch = model.garment.triangles, patches.triangle_patch
    particles = [set(triangles[triangle_patch == p].ravel()) for p in range(patches.count)]
    touching = [{q for q in range(patches.count) if particles[p] & particles[q]}
                for p in range(patches.count)]
    wraps = [(p, q) for p, q in zip(*np.nonzero(kept)) if p != q and q not in touching[p]
             and not touching[p] & touching[q]]
    culled = flat_patch_pairs(x, triangles, triangle_patch)
    assert len(wraps) > 10 and all(culled(p, p) for p, _ in wraps)  # flat, a wrap apart


def test_a_fold_through_triangles_wound_the_other_way_is_listed_the_same():
    """The folded sheet whose turned-over half's triangles are wound the other way (their raw
    normals then agree with the layer under them): the same pairs listed as when wound alike
    (a triangle's corners compared as a set)."""
    lists = []
    for rewound in (False, True):
        model, forces, state, out, effect = folded_sheet_physics(12, 0.0915, rewound)
        state.x.from_numpy(folded_positions(model, 0.004, 0.001))
        state.v.fill(0.0)
        effect.pairs.ask_rebuild()
        forces.evaluate(state.x, state.v, 0.0, out)
        lists.append({(kind, ids[0], tuple(sorted(ids[1:]))) if kind == 0 else (kind, ids)
                      for kind, ids in listed_pairs(effect.pairs)})
    assert len(lists[0]) > 100
    assert lists[1] == lists[0]


def test_a_rigid_motion_keeps_the_list_and_turns_the_forces_a_deformation_rebuilds_it():
    """The list is rebuilt only when some particle is more than half the padding away from
    where the best-fitting rigid motion carries it: not after a turn of 40° and a shift of half
    a metre (the forces then turn with the cloth), not after one particle moves 0.4 of the
    padding, but after 0.6 of it."""
    model, forces, state, out, effect = folded_sheet_physics()
    x = folded_positions(model)
    state.v.fill(0.0)
    effect.pairs.ask_rebuild()
    state.x.from_numpy(x)
    forces.evaluate(state.x, state.v, 0.0, out)
    builds, force = effect.pairs.rebuilds[None], out.to_numpy()
    assert np.abs(force).max() > 0  # the layers are within the thickness somewhere
    angle = np.radians(40.0)
    turn = np.array([[np.cos(angle), 0, np.sin(angle)], [0, 1, 0],
                     [-np.sin(angle), 0, np.cos(angle)]])
    turned = x @ turn.T + [0.5, -0.2, 0.1]
    state.x.from_numpy(turned)
    forces.evaluate(state.x, state.v, 0.0, out)
    assert effect.pairs.rebuilds[None] == builds
    np.testing.assert_allclose(out.to_numpy(), force @ turn.T, atol=1e-9 * np.abs(force).max())
    pushed = turned.copy()
    far = int(np.argmax(np.linalg.norm(x - x.mean(axis=0), axis=1)))
    for fraction, rebuilt in ((0.4, False), (0.6, True)):
        pushed[far] = turned[far] + [0, fraction * effect.padding, 0]
        state.x.from_numpy(pushed)
        forces.evaluate(state.x, state.v, 0.0, out)
        assert effect.pairs.rebuilds[None] == builds + rebuilt
