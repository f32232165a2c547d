"""Contact on the whole surface: edge midpoints and triangle centroids are contact samples whose
penalty energy ½·m_s·k̂·d² is shared by their particles. The force is −∇E by finite differences
of an energy written here from the geometry alone; the implicit solver's per-particle blocks are
the diagonal blocks of the true Jacobian; the metric's samples catch a capsule between particles."""

import numpy as np
import pytest
import taichi as ti
from systems import assemble, energy_gradient

from taichi_cloth.cloth.garment import build_garment
from taichi_cloth.cloth.topology import triangle_edges
from taichi_cloth.config.scene import load_scene
from taichi_cloth.effects.base import EffectContext
from taichi_cloth.effects.collision import CapsuleContact, CollisionSettings
from taichi_cloth.effects.near_masks import EVALUATION_RESTART
from taichi_cloth.effects.penalty import capsule_penetration_depths
from taichi_cloth.physics.metrics import surface_samples
from taichi_cloth.physics.model import Model

STIFFNESS, MARGIN, RADIUS = 1e4, 0.01, 0.03  # 1/s², m, m: a bar thinner than the spacing
BAR = np.array([[-0.6, 1.3, 0.0], [0.6, 1.3, 0.0]])
FAR = np.array([[-0.6, 9.0, 0.0], [0.6, 9.0, 0.0]])  # a capsule that touches nothing


class SheetOnThinBar:
    """A 5 × 4 sheet (f64, about 12 cm spacing) crossed by a bar of radius 3 cm between its
    particle rows; frictionless and undamped, so the contact force is conservative. The bar is
    the second of three capsules, the others far away: the near-masks hold its bit alone, and
    the contact passes over the first capsule's bit to find it."""

    def __init__(self):
        scene = load_scene("sheet", ("cloth.resolution=[5, 4]", "cloth.pin='none'"))
        self.garment = build_garment(scene.cloth, scene.material)
        self.model = Model(self.garment, "f64", None)
        physics = assemble(self.model, [(CapsuleContact, CollisionSettings(
            stiffness=STIFFNESS, damping=0.0, friction=0.0, thickness=MARGIN))],
            capsule_radius=[RADIUS] * 3)
        physics.control.capsule_track.hold(np.concatenate([FAR, BAR, FAR]))
        self.forces, self.contact = physics.forces, physics.effects[0]
        self.control = physics.control
        self.springs_only = assemble(self.model).forces
        n = self.model.particle_count
        self.state = self.model.state()
        self.out = ti.Vector.field(3, ti.f64, n)
        self.u = ti.Vector.field(3, ti.f64, n)
        self.damping_out = ti.Vector.field(3, ti.f64, n)
        rng = np.random.default_rng(7)
        x = self.garment.positions.copy()
        # lay the sheet across the bar: its rows at heights around the bar's, randomly moved
        x[:, 1] = 1.3 + 0.5 * (x[:, 1] - x[:, 1].mean())
        self.x = x + 0.01 * rng.standard_normal(x.shape)
        self.rng = rng
        self.edges = triangle_edges(self.garment.triangles)

    def energy(self, x):
        """Σ over particles and samples of ½·m·k̂·d², d the depth inside radius + margin."""
        mass = self.garment.mass
        triangles = self.garment.triangles
        points = surface_samples(x, self.edges, triangles)
        masses = np.concatenate([mass, mass[self.edges].mean(axis=1),
                                 mass[triangles].mean(axis=1)])
        depth = capsule_penetration_depths(points, BAR[:1], BAR[1:],
                                           np.array([RADIUS + MARGIN]))
        return 0.5 * STIFFNESS * float(np.sum(masses * depth ** 2))

    def force(self, x, forces=None):
        """Every particle's total force (springs and contact) at x, at rest."""
        self.state.x.from_numpy(x)
        self.state.v.fill(0.0)
        (forces or self.forces).evaluate(self.state.x, self.state.v, 0.0, self.out)
        return self.out.to_numpy()

    def contact_force(self, x):
        return self.force(x) - self.force(x, self.springs_only)

    def stiffness_product(self, x, u):
        self.state.x.from_numpy(x)
        self.state.v.fill(0.0)
        self.u.from_numpy(u)
        self.forces.evaluate_jacobian_products(self.state.x, self.state.v, self.u, 0.0, False,
                                               self.out, self.damping_out)
        return self.out.to_numpy()


@pytest.fixture(scope="module")
def sheet():
    return SheetOnThinBar()


def test_samples_between_particles_are_in_contact(sheet):
    particles = capsule_penetration_depths(sheet.x, BAR[:1], BAR[1:], np.array([RADIUS + MARGIN]))
    samples = capsule_penetration_depths(
        surface_samples(sheet.x, sheet.edges, sheet.garment.triangles)[len(sheet.x):],
        BAR[:1], BAR[1:], np.array([RADIUS + MARGIN]))
    assert np.count_nonzero(samples) >= 4 and np.count_nonzero(samples) > 2 * np.count_nonzero(particles)


def test_the_force_is_minus_the_gradient_of_the_sampled_energy(sheet):
    force = sheet.contact_force(sheet.x)
    gradient = energy_gradient(sheet.energy, sheet.x, 1e-7)
    assert np.abs(force).max() > 1e-3
    np.testing.assert_allclose(force, -gradient, atol=1e-6 * np.abs(force).max())


def test_the_implicit_blocks_are_the_diagonal_blocks_of_the_jacobian(sheet):
    """Column (i, c) of the product with e_(i,c): its row i is ∂f_i/∂x_i (w_a² of each sample's
    block plus the particle's own); central differences of f_i in x_i give the same."""
    n = sheet.model.particle_count
    eps = 1e-6
    checked = 0
    for i in range(n):
        block = np.empty((3, 3))
        numeric = np.empty((3, 3))
        for c in range(3):
            u = np.zeros((n, 3))
            u[i, c] = 1.0
            block[:, c] = sheet.stiffness_product(sheet.x, u)[i]
            numeric[:, c] = (sheet.force(sheet.x + eps * u)[i]
                             - sheet.force(sheet.x - eps * u)[i]) / (2 * eps)
        if np.abs(numeric).max() > 0:
            checked += 1
        np.testing.assert_allclose(block, numeric, atol=1e-5 * max(np.abs(numeric).max(), 1.0))
    assert checked >= 4


def test_each_particle_is_its_own_first_sample_and_blocks_are_kept_only_when_asked(sheet):
    """The particles are the first samples (their own corner, weight 1, their own mass), each
    first in its particle's list, then its edges (w = ½) and triangles (w = ⅓); an effect built
    for an explicit integrator (``needs_jacobian`` false) has no block fields at all."""
    contact, n = sheet.contact, sheet.model.particle_count
    start = contact.particle_sample_start.to_numpy()
    sample = contact.particle_sample.to_numpy()
    weight = contact.particle_sample_weight.to_numpy()
    np.testing.assert_array_equal(sample[start[:-1]], np.arange(n))
    np.testing.assert_array_equal(weight[start[:-1]], 1.0)
    np.testing.assert_array_equal(contact.sample_mass.to_numpy()[:n], sheet.garment.mass)
    edges, triangles = len(sheet.edges), len(sheet.garment.triangles)
    assert contact.sample_count == n + edges + triangles
    assert sorted(np.unique(np.round(weight, 12))) == pytest.approx([1 / 3, 0.5, 1.0])
    assert np.count_nonzero(np.isclose(weight, 0.5)) == 2 * edges
    assert np.count_nonzero(np.isclose(weight, 1 / 3)) == 3 * triangles
    assert contact.keeps_blocks and hasattr(contact, "sample_stiffness")
    explicit = CapsuleContact(CollisionSettings(stiffness=STIFFNESS, thickness=MARGIN),
                              EffectContext(sheet.model, sheet.control, needs_jacobian=False))
    assert not explicit.keeps_blocks
    assert not any(hasattr(explicit, name) for name in
                   ("sample_stiffness", "sample_curvature", "sample_damping"))


def test_auto_step_sees_the_samples_stiffness(sheet):
    """A particle and its shares of its samples are that many contacts on it: their springs,
    dashpots and friction dampers add up (``ContactMode``)."""
    (stiffness, _, contacts), = sheet.contact.stability_modes()
    assert stiffness == STIFFNESS
    # an interior particle of a grid: itself, 6 edges (w = ½), 6 triangles (w = ⅓) of equal mass
    assert 2.5 < contacts <= 6.0 + 1e-9


def test_masks_kept_while_the_sheet_slides_across_the_bar_never_miss_a_contact(sheet):
    """The near-masks are made again only when something has moved by half their slack
    (``CapsuleContact``): sliding the sheet across the bar in steps of 0.3 of the slack, some
    evaluations keep the masks and some make them again, and at every one the force is still
    −∇ of the sampled energy, with the contacts coming and going along the way. Only the
    particles of samples that may touch the bar read their samples' forces (``touched_in``),
    and only the forces stored at this evaluation (``sample_evaluation``): every sample pushing
    on the sheet has its particles among them, and not every particle is."""
    slack = sheet.contact.mask_slack[None]
    corners = sheet.contact.sample_corners.to_numpy()
    kept = remade = 0
    touching, marked_counts = [], []
    for step in range(12):
        x = sheet.x + [0.0, 0.3 * slack * step - 0.1, 0.0]
        force = sheet.contact_force(x)
        evaluation = sheet.contact.evaluation[None]
        marked = sheet.contact.touched_in.to_numpy() == evaluation
        stored_now = sheet.contact.sample_evaluation.to_numpy() == evaluation
        pushing = stored_now & (np.abs(sheet.contact.sample_force.to_numpy()).sum(axis=1) > 0)
        assert marked[corners[pushing]].all()
        marked_counts.append(int(marked.sum()))
        if sheet.contact.mask_stale[None]:
            remade += 1
        else:
            kept += 1
        gradient = energy_gradient(sheet.energy, x, 1e-7)
        np.testing.assert_allclose(force, -gradient, atol=1e-6 * max(np.abs(force).max(), 1e-3))
        touching.append(int(np.count_nonzero(np.abs(force).sum(axis=1))))
    assert kept >= 3 and remade >= 3
    assert max(touching) > 0 and min(touching) < max(touching)
    assert min(marked_counts) < max(marked_counts) and min(marked_counts) < len(sheet.x)


def test_the_masks_slack_follows_the_motion_and_the_force_does_not(sheet):
    """Moved far at every evaluation, the masks are remade at each and their slack goes to its
    most; moved a little at each, they last long and the slack is halved at the next
    remaking. The force at the end is −∇E, and bit for bit the force with masks made afresh at
    the most slack."""
    contact = sheet.contact
    largest = contact.slack_range[1]
    for step in range(6):  # 0.6 of the most slack each time: remade at every evaluation
        sheet.contact_force(sheet.x + [0.0, 0.6 * largest * (step % 2), 0.0])
    assert contact.mask_slack[None] == pytest.approx(largest)
    remade = 0
    for step in range(200):  # 1/250 of it each time: the first remaking comes after > 64
        x = sheet.x + [0.0, 0.004 * largest * step, 0.0]
        force = sheet.contact_force(x)
        remade += contact.mask_stale[None]
    assert remade >= 2 and contact.mask_slack[None] == pytest.approx(largest / 2)
    gradient = energy_gradient(sheet.energy, x, 1e-7)
    np.testing.assert_allclose(force, -gradient, atol=1e-6 * max(np.abs(force).max(), 1e-3))
    assert np.abs(force).max() > 0
    contact.mask_x.fill(np.inf)  # remade at the next evaluation, doubling the slack again
    np.testing.assert_array_equal(sheet.contact_force(x), force)
    assert contact.mask_stale[None] and contact.mask_slack[None] == pytest.approx(largest)


def test_a_remaking_finds_every_capsule_near_each_sample(sheet):
    """A remaking tests each edge midpoint and centroid only against its first particle's mask
    grown by ``sample_reach`` (``NearMasks``), or against every capsule where the sample lies
    farther from that particle (a stretched edge): the masks are those of testing every capsule
    at every sample, here computed in NumPy, with one particle pulled out of the sheet so far
    that a sample of its lies past the reach and still near the bar, which its particle's grown
    mask does not hold."""
    contact = sheet.contact
    # a remaking now keeps the most slack (masks kept fewer than 16 evaluations double it)
    contact.mask_slack[None] = contact.slack_range[1]
    contact.evaluations_kept[None] = 0
    reach = RADIUS + MARGIN + contact.slack_range[1]
    corners, weights = contact.sample_corners.to_numpy(), contact.sample_weights.to_numpy()

    def bar_distance(points):
        return np.hypot(points[:, 1] - BAR[0, 1], points[:, 2] - BAR[0, 2])

    def pulled(i, distance):
        x = sheet.x.copy()
        x[i] += [0.0, 0.0, distance]
        points = np.einsum("sa,sak->sk", weights, x[corners])
        first = x[corners[:, 0]]
        only_by_all = (np.linalg.norm(points - first, axis=1) > contact.sample_reach) \
            & (bar_distance(points) < reach) \
            & (bar_distance(first) > reach + contact.sample_reach)
        return x, points, only_by_all.any()

    x, points = next((x, points) for i in range(len(sheet.x))
                     for distance in np.arange(0.3, 1.0, 0.02)
                     for x, points, found in [pulled(i, distance)] if found)
    contact.mask_x.fill(np.inf)  # remade at this evaluation
    sheet.contact_force(x)
    assert contact.mask_stale[None] and contact.mask_slack[None] == contact.slack_range[1]
    expected = np.zeros(len(points), np.int64)
    for bit, (a, b) in enumerate([FAR, BAR, FAR]):
        inside = capsule_penetration_depths(points, a[None], b[None], np.array([reach])) > 0
        expected |= inside.astype(np.int64) << bit
    assert 0 < np.count_nonzero(expected) < len(points)
    np.testing.assert_array_equal(contact.sample_near.to_numpy(), expected)


def test_the_evaluation_numbers_start_again_and_the_contact_stays(sheet):
    """After ``EVALUATION_RESTART`` evaluations the particles' marks and the samples' stamps go
    back to 0 and the numbers start again (an i32 that wrapped would never be the larger of the
    marks' atomic max): the force is the same bit for bit before, at and after the restart,
    and each particle a sample of which touches the bar is listed once."""
    contact = sheet.contact
    expected = sheet.contact_force(sheet.x)
    contact.evaluation[None] = EVALUATION_RESTART - 1
    for _ in range(3):  # the last number before the restart, the restart, the next one
        np.testing.assert_array_equal(sheet.contact_force(sheet.x), expected)
    assert contact.evaluation[None] == 2
    listed = contact.touched_list.to_numpy()[:contact.touched_count[None]]
    assert len(set(listed.tolist())) == len(listed) > 0
    assert set(np.flatnonzero(np.abs(expected).sum(axis=1) > 0).tolist()) <= set(listed.tolist())
