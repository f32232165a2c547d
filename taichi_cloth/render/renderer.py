"""Headless frames of a scene through Taichi's GGUI (Vulkan; lavapipe where there is no GPU).

A ``Renderer`` owns one hidden ``ti.ui.Window`` of the frame size, a camera from ``[render]``
(position, look-at point, vertical field of view), an ambient light plus a key light above the
camera's right shoulder and a fill light at its left, the floor, the cloth as a lit two-sided mesh
with smooth per-vertex normals and its texture as per-vertex colours, and the body's capsules.
GGUI's lighting is Lambertian without falloff: colour × (ambient + Σ light |n · l|).

GGUI writes ``imgui.ini`` into the working directory when its window is destroyed; ``close``
destroys it from inside a temporary folder, so the file never lands where the user ran us.
"""

import contextlib
import os
import tempfile

import numpy as np
import taichi as ti

from taichi_cloth.errors import InputError
from taichi_cloth.config.scene import Scene
from taichi_cloth.render.surfaces import (BodySurface, ClothEdges, ClothSurface, GroundSurface,
                                          PlateSurface)
from taichi_cloth.render.texture import load_texture, sample_texture, texture_path
from taichi_cloth.uploads import UploadBatch

VULKAN_PACKAGES = "libvulkan1 mesa-vulkan-drivers"
FILL_FRACTION = 1.0 / 3.0  # fill light intensity relative to the key light
WIRE_COLOR = (0.08, 0.08, 0.1)  # the wireframe's lines


def open_window(width: int, height: int, visible: bool = False,
                title: str = "taichi_cloth") -> ti.ui.Window:
    """A GGUI window, hidden unless ``visible`` (the interactive viewer); a missing Vulkan
    driver is bad input (exit 2) that names the fix."""
    try:
        return ti.ui.Window(title, (width, height), show_window=visible, vsync=visible)
    except RuntimeError as error:
        what = "view: cannot open a window" if visible else \
            "render: no Vulkan device for headless rendering"
        raise InputError(f"{what} ({error}); it needs a Vulkan driver: install the Debian "
                         f"packages {VULKAN_PACKAGES} (make setup does it as root)") from None


@contextlib.contextmanager
def working_directory(path: str):
    """Run the block with ``path`` as the current directory, then go back."""
    previous = os.getcwd()
    os.chdir(path)
    try:
        yield
    finally:
        os.chdir(previous)


def light_positions(position: np.ndarray, lookat: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Key and fill light positions [m]: the key up and to the right of the camera, the fill
    low on its left, both at about the camera's distance from what it looks at."""
    forward = lookat - position
    distance = np.linalg.norm(forward)
    forward /= distance
    right = np.cross(forward, [0.0, 1.0, 0.0])
    right /= max(np.linalg.norm(right), 1e-9)
    key = position + distance * (0.9 * right + 0.9 * np.array([0.0, 1.0, 0.0]) - 0.2 * forward)
    fill = position + distance * (-1.0 * right + 0.1 * np.array([0.0, 1.0, 0.0]))
    return key, fill


def illumination(normals: np.ndarray, points: np.ndarray, lights: list, ambient: float):
    """GGUI's lighting factor (V,) for unit normals and points (V, 3): ambient + Σ I |n · l|."""
    total = np.full(len(points), ambient)
    for position, intensity in lights:
        direction = position - points
        direction /= np.linalg.norm(direction, axis=1, keepdims=True)
        total += intensity * np.abs(np.sum(direction * normals, axis=1))
    return total


class Renderer:
    """Draws one frame at a time of a scene's cloth and body into an RGB image."""

    def __init__(self, scene: Scene, garment, body, width: int, height: int,
                 visible: bool = False):
        """garment: the simulation's ``Garment``; body: a ``body.Body`` or None; visible: an
        on-screen window (``render/viewer.py``) instead of a hidden one."""
        config = scene.render
        self.config = config
        position, lookat = np.array(config.camera_position), np.array(config.camera_lookat)
        key, fill = light_positions(position, lookat)
        self.lights = [(key, config.light), (fill, config.light * FILL_FRACTION)]
        uploads = UploadBatch()  # every surface's fields filled in one launch, once all are built
        self.cloth = ClothSurface(garment, config.subdivision, uploads)
        self.garment = garment
        self.edges = None  # the wireframe's lines, made when first asked for
        image_path = texture_path(scene)
        if image_path is None:
            self.cloth.set_colors(np.broadcast_to(config.cloth_color, (self.cloth.vertex_count, 3)))
        else:
            self.cloth.set_colors(sample_texture(load_texture(image_path), self.cloth.uvs,
                                                 self.cloth.uv_footprint, config.texture_repeat))
        self.body = BodySurface(body, config.body_color, uploads) if body is not None else None
        self.ground = None
        if config.ground:
            ground = scene.effects.get("ground")
            self.ground = GroundSurface(ground.height if ground is not None else 0.0, uploads)
            self.ground.shade(key, lambda normals, points: illumination(
                normals, points, self.lights, config.ambient), config.background)

        support = scene.effects.get("support")
        self.plate = None if support is None else PlateSurface(
            support.height, support.radius, support.plate_thickness, support.centre, uploads)
        uploads.send()

        # last: nothing after it can fail unclosed
        self.window = open_window(width, height, visible, f"taichi_cloth: {scene.name}")
        self.canvas = self.window.get_canvas()
        self.scene_3d = self.window.get_scene()
        self.camera = ti.ui.Camera()
        self.camera.position(*position)
        self.camera.lookat(*lookat)
        self.camera.up(0.0, 1.0, 0.0)
        self.camera.fov(config.fov)
        self.drawn = False  # whether a frame was read back yet (``draw``)

    def draw(self, positions, t: float) -> np.ndarray:
        """The frame with the cloth at ``positions`` (the simulation's x field) and the body at
        time ``t`` [s], as an (height, width, 3) uint8 image. The first call draws the frame
        twice and keeps the second: GGUI builds its pipelines on the first draw, and once (of
        six fresh ``render hula`` runs on lavapipe) that first image showed the body without
        the cloth."""
        if not self.drawn:
            self.compose(positions, t)
            self.window.get_image_buffer_as_numpy()
            self.drawn = True
        self.compose(positions, t)
        image = self.window.get_image_buffer_as_numpy()
        return np.round(np.clip(image[:, ::-1, :3].transpose(1, 0, 2), 0, 1) * 255).astype(np.uint8)

    def compose(self, positions, t: float, show_body: bool = True,
                wireframe: bool = False) -> None:
        """Draw the scene into the window's canvas (``draw`` reads it back, the viewer shows
        it): the cloth at ``positions``, the body at ``t`` [s] unless not ``show_body``, the
        cloth's triangle edges over it when ``wireframe``."""
        self.cloth.update(positions)
        self.canvas.set_background_color(tuple(self.config.background))
        self.scene_3d.set_camera(self.camera)
        self.scene_3d.ambient_light((self.config.ambient,) * 3)
        for position, intensity in self.lights:
            self.scene_3d.point_light(tuple(position), (intensity,) * 3)
        if self.body is not None and show_body:
            self.body.update(t)
            self._mesh(self.body, two_sided=False)
            if self.ground is not None:
                self.ground.cast_shadows(self.body)
        if self.ground is not None:
            self._mesh(self.ground, two_sided=False)
        if self.plate is not None:
            self._mesh(self.plate, two_sided=False)
        self._mesh(self.cloth, two_sided=True)
        if wireframe:
            if self.edges is None:
                self.edges = ClothEdges(self.garment)
            self.edges.update(positions)
            self.scene_3d.lines(self.edges.vertices, width=1.0, indices=self.edges.indices,
                                color=WIRE_COLOR)
        self.canvas.scene(self.scene_3d)

    def _mesh(self, surface, two_sided: bool) -> None:
        self.scene_3d.mesh(surface.vertices, indices=surface.indices, normals=surface.normals,
                           per_vertex_color=surface.colors, two_sided=two_sided)

    def close(self) -> None:
        """Destroy the window (GGUI's imgui.ini goes to a temporary folder)."""
        with tempfile.TemporaryDirectory() as scratch, working_directory(scratch):
            self.window.destroy()

    def __enter__(self):
        return self

    def __exit__(self, *_):
        self.close()
