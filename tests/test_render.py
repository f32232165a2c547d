"""Headless rendering: hula frames, the texture on the skirt, the body, the video, imgui.ini, and
the Vulkan message; the surfaces the renderer draws. Rendering needs a Vulkan driver: without one
these tests skip, except in CI (CI=true), which installs it (scripts/ensure-system.sh)."""

import os
import subprocess
import sys
from pathlib import Path

import imageio
import imageio.v3 as iio
import numpy as np
import pytest

from taichi_cloth import cli
from taichi_cloth.body.dancer import Body
from taichi_cloth.errors import InputError
from taichi_cloth.cloth.garment import build_garment
from taichi_cloth.render.renderer import VULKAN_PACKAGES
from taichi_cloth.config.scene import load_scene
from taichi_cloth.render.surfaces import BodySurface, ClothSurface
from taichi_cloth.render.texture import DEFAULT_TEXTURE, sample_texture, texture_path

REPO = Path(__file__).resolve().parent.parent
SMALL = ["cloth.resolution=[16,8]", "body.ease_in=0.1"]  # the dance at full swing by frame 3
FRAMES, WIDTH, HEIGHT = 3, 160, 120
WRITTEN = FRAMES + 1  # frame 0 (the settled start) and the simulated frames


@pytest.fixture(scope="module")
def hula(tmp_path_factory):
    """3 frames of hula (and frame 0) at 160×120 with an mp4; the folder it wrote."""
    out = tmp_path_factory.mktemp("hula")
    had_imgui = (Path.cwd() / "imgui.ini").exists()
    try:
        cli.render("hula", SMALL, FRAMES, str(out), None, True, WIDTH, HEIGHT, "mp4")
    except InputError as error:
        if "Vulkan" in str(error) and not os.environ.get("CI"):
            pytest.skip(str(error))
        raise
    return out, had_imgui


def frames(out: Path) -> list[np.ndarray]:
    return [iio.imread(out / "frames" / f"frame_{k:05d}.png").astype(float) / 255
            for k in range(WRITTEN)]


def test_render_writes_one_png_per_frame_of_the_requested_size(hula):
    out, _ = hula
    assert sorted(p.name for p in (out / "frames").iterdir()) == \
        [f"frame_{k:05d}.png" for k in range(WRITTEN)]
    for image in frames(out):
        assert image.shape == (HEIGHT, WIDTH, 3)


def test_skirt_shows_the_texture_colours(hula):
    # The pareo's saturated ocean blue ground and its red/coral/yellow hibiscus: nothing else in
    # the scene (pale sky, sand, skin, white top, dark hair) has such hues.
    for image in frames(hula[0]):
        r, g, b = image[..., 0], image[..., 1], image[..., 2]
        ocean = (b > 1.8 * r) & (b > g) & (b > 0.12)
        flowers = (r > 2.5 * b) & (r > 0.35)
        assert ocean.sum() > 100, ocean.sum()
        assert flowers.sum() > 20, flowers.sum()


def test_consecutive_frames_differ(hula):
    images = frames(hula[0])
    for before, after in zip(images, images[1:]):
        assert np.abs(after - before).mean() > 1e-4


def test_body_is_visible(hula):
    # Skin (render.body_color, lit): r > g > b with r/b ≈ 1.8 and g/r ≈ 0.72, unlike the sand
    # floor (g/r ≈ 0.93) or the flowers (r/b ≥ 3); some of it above the skirt (head, arms).
    image = frames(hula[0])[-1]
    r, g, b = image[..., 0], image[..., 1], image[..., 2]
    skin = (r > 0.3) & (r / np.maximum(b, 1e-3) > 1.4) & (r / np.maximum(b, 1e-3) < 2.3) \
        & (g / np.maximum(r, 1e-3) < 0.82)
    rows = np.nonzero(skin.any(axis=1))[0]
    assert skin.sum() > 150, skin.sum()
    assert rows.min() < HEIGHT * 0.3 and rows.max() > HEIGHT * 0.6


def test_mp4_reads_back_with_every_frame_at_the_frame_size(hula):
    reader = imageio.v2.get_reader(hula[0] / "hula.mp4")
    assert reader.count_frames() == WRITTEN
    assert reader.get_meta_data()["size"] == (WIDTH, HEIGHT)
    assert reader.get_meta_data()["fps"] == load_scene("hula").scene.fps


def test_render_leaves_no_imgui_ini_and_no_temporary_file(hula):
    out, had_imgui = hula
    assert had_imgui or not (Path.cwd() / "imgui.ini").exists()
    assert not [p for p in out.rglob(".*")]
    assert "render" in __import__("json").loads((out / "stats.json").read_text())["wall_seconds"]


def test_render_from_the_cache_draws_the_same_frames_without_simulating(hula, tmp_path,
                                                                         monkeypatch):
    """`render --from-cache` on the run's folder: every PNG byte for byte the run's own, and the
    video with every frame, while no Simulation is built."""
    from taichi_cloth.physics import simulation
    monkeypatch.setattr(simulation.Simulation, "__init__", None)  # building one would fail
    out = tmp_path / "again"
    assert cli.main(["render", "--from-cache", str(hula[0]), "--out", str(out), "--width",
                     str(WIDTH), "--height", str(HEIGHT), "--video", "mp4", "--quiet"]) == 0
    for k in range(WRITTEN):
        name = f"frame_{k:05d}.png"
        assert (out / "frames" / name).read_bytes() == (hula[0] / "frames" / name).read_bytes()
    assert imageio.v2.get_reader(out / "hula.mp4").count_frames() == WRITTEN


@pytest.mark.parametrize("argv, words", [
    (["render", "--from-cache", "DIR", "hula"], "SCENE"),
    (["render", "--from-cache", "DIR", "--set", "cloth.material=silk"], "--set"),
    (["render", "--from-cache", "/nonexistent/run"], "no simulation cache"),
    (["render"], "--from-cache"),
])
def test_from_cache_misuse_is_one_line_exit_2(argv, words, hula, capsys):
    argv = [str(hula[0]) if word == "DIR" else word for word in argv]
    assert cli.main(argv) == 2
    error = capsys.readouterr().err.strip()
    assert words in error and "\n" not in error


def test_missing_vulkan_exits_2_naming_the_packages(tmp_path):
    environment = dict(os.environ, VK_ICD_FILENAMES=str(tmp_path / "none.json"),
                       VK_DRIVER_FILES=str(tmp_path / "none.json"))
    result = subprocess.run(
        [sys.executable, "-m", "taichi_cloth", "render", "skirt", "--frames", "1", "--quiet",
         "--out", str(tmp_path / "out"), "--set", "cloth.resolution=[8,4]"],
        cwd=REPO, env=environment, capture_output=True, text=True, timeout=300)
    assert result.returncode == 2, result.stderr
    message = result.stderr.strip().splitlines()[-1]
    assert VULKAN_PACKAGES in message and message.startswith("error: render")
    assert not (tmp_path / "out" / "frames").exists()


def test_render_rejects_a_bad_size_naming_the_flag(tmp_path):
    with pytest.raises(InputError, match="--width 8"):
        cli.render("skirt", [], 1, str(tmp_path), None, True, width=8)


# --- what the renderer draws, without a window ---------------------------------------------


def skirt_garment(resolution=(12, 6)):
    scene = load_scene("skirt", (f"cloth.resolution={list(resolution)}",))
    return build_garment(scene.cloth, scene.material, None, scene.path)


def upload(positions: np.ndarray):
    import taichi as ti
    field = ti.Vector.field(3, ti.f32, len(positions))
    field.from_numpy(positions.astype(np.float32))
    return field


def test_cloth_surface_passes_through_the_particles_with_smooth_unit_normals():
    garment = skirt_garment()
    surface = ClothSurface(garment, subdivision=3)
    surface.update(upload(garment.positions))
    points = surface.points().reshape(surface.rows, surface.columns, 3)
    grid = garment.positions.reshape(garment.rows, garment.columns, 3)
    np.testing.assert_allclose(points[::3, ::3], grid, atol=1e-6)
    normals = surface.normals.to_numpy().reshape(surface.rows, surface.columns, 3)
    np.testing.assert_allclose(np.linalg.norm(normals, axis=-1), 1.0, atol=1e-5)
    radial = points[..., [0, 2]] / np.linalg.norm(points[..., [0, 2]], axis=-1, keepdims=True)
    facing = np.sum(normals[..., [0, 2]] * radial, axis=-1)  # the cone's normals are ±radial
    assert (np.abs(facing) > 0.8).all() and len(np.unique(np.sign(facing))) == 1
    assert surface.columns == 3 * garment.columns  # periodic: no duplicate seam column


def test_cloth_surface_uvs_follow_the_garment_and_wrap_once_around_a_skirt():
    garment = skirt_garment()
    surface = ClothSurface(garment, subdivision=2)
    uv = surface.uvs.reshape(surface.rows, surface.columns, 2)
    np.testing.assert_allclose(uv[::2, ::2].reshape(-1, 2), garment.uvs, atol=1e-12)
    assert uv[..., 0].max() < 1.0 and np.allclose(uv[0, :, 1], 1.0) and np.allclose(uv[-1, :, 1], 0)


def test_body_surface_puts_every_vertex_on_its_capsule():
    body = Body("hula")
    surface = BodySurface(body)
    surface.update(1.3)
    pose = body.pose(1.3)
    a = np.concatenate([pose.capsule_a, pose.display_capsule_a])
    b = np.concatenate([pose.capsule_b, pose.display_capsule_b])
    radius = np.concatenate([body.capsule_radius, body.display_capsule_radius])
    points = surface.points().reshape(len(a), -1, 3)
    axis = (b - a)[:, None, :]
    s = np.clip(np.sum((points - a[:, None]) * axis, -1) / np.sum(axis * axis, -1), 0, 1)
    distance = np.linalg.norm(points - (a[:, None] + s[..., None] * axis), axis=-1)
    np.testing.assert_allclose(distance, radius[:, None] * np.ones_like(distance), atol=1e-5)
    corners = surface.points()[surface.triangles]
    area = np.linalg.norm(np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0]), axis=1)
    assert (area > 1e-10).all()


# --- texture -------------------------------------------------------------------------------


def test_texture_choice_per_scene():
    assert texture_path(load_scene("skirt")) == DEFAULT_TEXTURE
    assert texture_path(load_scene("sheet")) is None
    assert texture_path(load_scene("skirt", ("render.texture=none",))) is None
    custom = load_scene("sheet", ("render.texture=\"textures/pareo.png\"",))
    assert texture_path(custom) == DEFAULT_TEXTURE.resolve() or \
        texture_path(custom).resolve() == DEFAULT_TEXTURE


def test_texture_sampling_wraps_and_averages_its_footprint():
    image = np.zeros((4, 8, 3))
    image[:, ::2] = 1.0  # 1-pixel stripes
    uv = np.array([[0.5 / 8, 0.5], [1 - 0.5 / 8, 0.5]])
    sharp = sample_texture(image, uv, (0.0, 0.0), (1.0, 1.0))
    np.testing.assert_allclose(sharp[:, 0], [1.0, 0.0])  # pixel centres, both ends of the wrap
    blurred = sample_texture(image, uv, (2 / 8, 0.0), (1.0, 1.0))
    assert (np.abs(blurred - 0.5) < 0.2).all()  # a footprint of two stripes averages them
    tiled = sample_texture(image, uv / 2, (0.0, 0.0), (2.0, 1.0))
    np.testing.assert_allclose(tiled, sharp)


def test_shipped_print_is_small_and_tiles_around_the_skirt():
    assert DEFAULT_TEXTURE.stat().st_size < 300_000
    image = iio.imread(DEFAULT_TEXTURE, mode="RGB").astype(float)
    seam = np.abs(image[:, 0] - image[:, -1]).mean()
    inside = np.abs(image[:, 1:] - image[:, :-1]).mean()
    assert seam < 3 * inside


def test_a_mesh_garment_is_drawn_as_it_is_split_at_its_uv_seams():
    scene = load_scene("hilo")
    garment = build_garment(scene.cloth, scene.material, None, scene.path)
    surface = ClothSurface(garment, subdivision=3)  # a mesh is not refined
    source, uvs, triangles = garment.uv_layout()
    assert surface.vertex_count == len(source) > garment.particle_count  # four gores' seams
    surface.update(upload(garment.positions))
    np.testing.assert_allclose(surface.points(), garment.positions[source], atol=1e-6)
    normals = surface.normals.to_numpy()
    np.testing.assert_allclose(np.linalg.norm(normals, axis=-1), 1.0, atol=1e-5)
    outward = np.sum(normals[:, [0, 2]] * surface.points()[:, [0, 2]], axis=-1)
    assert (outward > 0).all()  # the cone's quads are wound outwards
    np.testing.assert_array_equal(surface.uvs, uvs)
