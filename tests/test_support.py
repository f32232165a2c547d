"""The round support plate (effects/support.py): its signed distance against a brute-force one
on the plate's sampled outline, the force straight out of it and growing with depth, and its
Jacobians (exact and definite) against finite differences of the force round the plate's edge,
where the top face, the rim and the side meet."""

import numpy as np
import pytest
import taichi as ti
from systems import assemble

from taichi_cloth.cloth.garment import build_garment
from taichi_cloth.config.scene import load_scene
from taichi_cloth.effects.support import SupportContact, SupportSettings
from taichi_cloth.physics.model import Model

SETTINGS = SupportSettings(height=0.5, radius=0.09, centre=(0.02, -0.01), plate_thickness=0.003,
                           stiffness=1e4, damping=0.3, friction=0.4, thickness=0.002)


def brute_force_signed_distance(points: np.ndarray) -> np.ndarray:
    """Distance from each point to the plate's outline in its (r, y) half-plane, sampled every
    2 µm (top, side and bottom; every 1 mm on the faces more than 5 mm inside the rim, whose
    nearest points for the far test points are sample points themselves: the axis), negative
    inside the rectangle."""
    top, bottom, rim = SETTINGS.height, SETTINGS.height - SETTINGS.plate_thickness, SETTINGS.radius
    radii = np.concatenate([np.arange(0.0, rim - 0.005, 1e-3),
                            np.linspace(rim - 0.005, rim, int(0.005 / 2e-6) + 1)])
    heights = np.linspace(bottom, top, int(SETTINGS.plate_thickness / 2e-6) + 1)
    outline = np.concatenate([np.stack([radii, np.full_like(radii, top)], 1),
                              np.stack([radii, np.full_like(radii, bottom)], 1),
                              np.stack([np.full_like(heights, rim), heights], 1)])
    r = np.hypot(points[:, 0] - SETTINGS.centre[0], points[:, 2] - SETTINGS.centre[1])
    plane = np.stack([r, points[:, 1]], 1)
    distance = np.min(np.linalg.norm(plane[:, None] - outline[None], axis=2), axis=1)
    inside = (r <= rim) & (points[:, 1] >= bottom) & (points[:, 1] <= top)
    return np.where(inside, -distance, distance)


def points_round_the_edge(count: int, seed: int) -> np.ndarray:
    """Points within a few mm of the plate's rim: above the top, beside the side, round the
    edge and inside the plate."""
    rng = np.random.default_rng(seed)
    angle = rng.uniform(0, 2 * np.pi, count)
    r = SETTINGS.radius + rng.uniform(-0.003, 0.0025, count)
    y = SETTINGS.height + rng.uniform(-0.0045, 0.0025, count)
    return np.stack([SETTINGS.centre[0] + r * np.cos(angle), y,
                     SETTINGS.centre[1] + r * np.sin(angle)], 1)


def test_signed_distance_matches_the_sampled_outline():
    plate = SupportContact(SETTINGS)
    points = points_round_the_edge(400, 1)
    far = np.array([[0.02, 0.7, -0.01], [0.3, 0.4, 0.0], [0.02, 0.4985, -0.01]])
    points = np.concatenate([points, far])
    expected = brute_force_signed_distance(points)
    assert (expected < 0).sum() > 20 and (expected > 0).sum() > 200
    np.testing.assert_allclose(plate.signed_distances(points), expected, atol=3e-6)
    np.testing.assert_allclose(plate.penetration_depths(points), np.maximum(-expected, 0),
                               atol=3e-6)


class ParticlesRoundThePlate:
    """A 6 × 5 sheet (f64) with springs too soft to matter, its particles moved to points round
    the plate's edge, under the support's contact alone."""

    def __init__(self):
        scene = load_scene("sheet", ("cloth.resolution=[6, 5]", "cloth.pin='none'",
                                     "cloth.material.stretch_stiffness=1e-6",
                                     "cloth.material.shear_stiffness=1e-6",
                                     "cloth.material.bend_stiffness=1e-9"))
        garment = build_garment(scene.cloth, scene.material)
        self.model = Model(garment, "f64", None)
        physics = assemble(self.model, [(SupportContact, SETTINGS)])
        self.forces = physics.forces
        self.state = self.model.state()
        n = self.model.particle_count
        self.force, self.u, self.stiffness_product, self.damping_product = (
            ti.Vector.field(3, ti.f64, n) for _ in range(4))
        self.x = points_round_the_edge(n, 2)
        self.rng = np.random.default_rng(3)

    def force_at(self, x, v):
        self.state.x.from_numpy(x)
        self.state.v.from_numpy(v)
        self.forces.evaluate(self.state.x, self.state.v, 0.0, self.force)
        return self.force.to_numpy()

    def products(self, x, v, u, definite):
        self.state.x.from_numpy(x)
        self.state.v.from_numpy(v)
        self.u.from_numpy(u)
        self.forces.evaluate_jacobian_products(self.state.x, self.state.v, self.u, 0.0, definite,
                                               self.stiffness_product, self.damping_product)
        return self.stiffness_product.to_numpy(), self.damping_product.to_numpy()


@pytest.fixture(scope="module")
def plate():
    return ParticlesRoundThePlate()


def regions(points: np.ndarray) -> list[str]:
    """Which part of the plate each point is nearest: its top or bottom face, its side, the
    edge round the top or the bottom, or (inside) the plate."""
    r = np.hypot(points[:, 0] - SETTINGS.centre[0], points[:, 2] - SETTINGS.centre[1])
    beyond_rim = r - SETTINGS.radius
    above = points[:, 1] - SETTINGS.height
    below = SETTINGS.height - SETTINGS.plate_thickness - points[:, 1]
    face = np.where(above >= below, "top", "bottom")
    beyond_face = np.maximum(above, below)
    return [("inside" if rim <= 0 and depth <= 0 else f"{side} edge" if rim > 0 and depth > 0
             else "side" if rim > depth else f"{side} face")
            for rim, depth, side in zip(beyond_rim, beyond_face, face)]


def test_the_particles_meet_every_part_of_the_plate(plate):
    touching = SETTINGS.thickness - SupportContact(SETTINGS).signed_distances(plate.x) > 0
    met = {region for region, inside in zip(regions(plate.x), touching) if inside}
    assert met >= {"top face", "bottom face", "side", "top edge", "bottom edge", "inside"}


def test_the_force_points_straight_out_and_is_the_penalty_of_the_depth(plate):
    x, zero = plate.x, np.zeros_like(plate.x)
    depth = SETTINGS.thickness - SupportContact(SETTINGS).signed_distances(x)
    force = plate.force_at(x, zero)
    touching = depth > 0
    assert touching.sum() > 10 and (~touching).sum() > 3
    magnitude = np.linalg.norm(force, axis=1)
    mass = plate.model.host_mass
    np.testing.assert_allclose(magnitude[touching], mass[touching] * SETTINGS.stiffness
                               * depth[touching], atol=1e-5 * magnitude.max())  # springs' 1e-6
    np.testing.assert_allclose(magnitude[~touching], 0.0, atol=1e-5 * magnitude.max())
    eps = 1e-7  # the force is −∇(½·m·k̂·depth²): along the gradient of the signed distance
    plate_alone = SupportContact(SETTINGS)
    for axis in range(3):
        step = np.zeros(3)
        step[axis] = eps
        gradient = (plate_alone.signed_distances(x + step)
                    - plate_alone.signed_distances(x - step)) / (2 * eps)
        np.testing.assert_allclose(force[touching, axis], magnitude[touching]
                                   * gradient[touching], atol=1e-5 * magnitude.max())


def test_jacobians_equal_central_differences_of_the_force(plate):
    """At rest: there the damping and friction forces vanish (their dependence on x, which
    the stiffness blocks leave out, with them) and friction is in its viscous regime (2·m·√k̂
    per unit slip), linear in v (away from rest its coefficient is frozen at the current slip:
    ``penalty_terms``)."""
    x, zero = plate.x, np.zeros_like(plate.x)
    for _ in range(3):
        u = plate.rng.standard_normal(x.shape)
        stiffness_u, _ = plate.products(x, zero, u, definite=False)
        eps = 1e-8
        numeric = (plate.force_at(x + eps * u, zero) - plate.force_at(x - eps * u, zero)) / (2 * eps)
        assert np.abs(stiffness_u).max() > 1.0
        np.testing.assert_allclose(stiffness_u, numeric, atol=1e-5 * np.abs(stiffness_u).max())
        definite_u, _ = plate.products(x, zero, u, definite=True)
        curvature = stiffness_u - definite_u  # the dropped term: positive semi-definite
        # (per particle, up to the soft springs' own definite clamp, ~1e-5)
        assert np.all(np.einsum("pk,pk->p", curvature, u) >= -1e-4)
        assert np.abs(curvature).max() > 0
        _, damping_u = plate.products(x, zero, u, definite=False)
        numeric = (plate.force_at(x, 1e-9 * u) - plate.force_at(x, -1e-9 * u)) / 2e-9
        assert np.abs(damping_u).max() > 1e-3
        np.testing.assert_allclose(damping_u, numeric, atol=1e-6 * np.abs(damping_u).max())


def test_the_drawn_plate_is_the_collider_with_outward_faces():
    """The renderer's plate (render/surfaces.py): its vertices on the collider's top, side and
    bottom, and every triangle wound so that its normal points out, as its vertices' normals do
    (GGUI draws it one-sided)."""
    from taichi_cloth.render.surfaces import PlateSurface
    surface = PlateSurface(SETTINGS.height, SETTINGS.radius, SETTINGS.plate_thickness,
                           SETTINGS.centre)
    points, normals = surface.points(), surface.normals.to_numpy()
    np.testing.assert_allclose(SupportContact(SETTINGS).signed_distances(points), 0.0, atol=1e-6)
    a, b, c = (points[surface.triangles[:, k]] for k in range(3))
    face = np.cross(b - a, c - a)
    assert np.all(np.einsum("tk,tk->t", face, normals[surface.triangles].mean(axis=1)) > 0)
    centroid = (a + b + c) / 3
    outward = centroid - np.array([SETTINGS.centre[0], SETTINGS.height
                                   - SETTINGS.plate_thickness / 2, SETTINGS.centre[1]])
    assert np.all(np.einsum("tk,tk->t", face, outward) > 0)
