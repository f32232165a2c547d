"""Texture mapping on the cloth (the seed paper's future work): an image sampled at the cloth's UVs
into per-vertex colours, so that the print moves with the fabric.

Which image (``[render] texture``): ``""`` is the shipped pareo print (``scenes/textures/
pareo.png``) for a skirt and the plain ``cloth_color`` for a sheet; ``"none"`` is always the plain
colour; anything else is an image file, relative to the scene file. ``texture_repeat = [u, v]``
tiles the image that many times across the cloth.

UV convention: u runs along a row (around a skirt, wrapping at 1), v runs from the bottom edge
(v = 0, the hem) to the top (v = 1, the waist), so image row 0 is the top. The image wraps in
both directions. Each vertex gets the mean of a few bilinear samples spread over its footprint
(one render-grid cell), so a fine print does not alias.
"""

from pathlib import Path

import imageio.v3 as iio
import numpy as np

from taichi_cloth.errors import InputError
from taichi_cloth.config.scene import SCENES_DIR, Scene

DEFAULT_TEXTURE = SCENES_DIR / "textures" / "pareo.png"
FOOTPRINT_SAMPLES = 3  # per axis: 3 × 3 bilinear samples averaged per vertex


def texture_path(scene: Scene) -> Path | None:
    """The image a scene's cloth is printed with, or None for the plain ``cloth_color``."""
    name = scene.render.texture
    if name == "none" or (name == "" and not scene.cloth.is_skirt):
        return None
    if name == "":
        return DEFAULT_TEXTURE
    path = Path(scene.path).parent / name  # an absolute name stays as it is
    if not path.is_file():
        raise InputError(f"{scene.path}: render.texture: image {path} not found")
    return path


def load_texture(path: Path) -> np.ndarray:
    """An image file as (H, W, 3) float colours in [0, 1]."""
    try:
        image = iio.imread(path, mode="RGB")
    except (OSError, ValueError) as error:
        raise InputError(f"render.texture: cannot read image {path}: {error}") from None
    return image.astype(np.float64) / 255.0


def bilinear(image: np.ndarray, uv: np.ndarray) -> np.ndarray:
    """Colours (M, 3) at texture coordinates uv (M, 2), wrapping in both directions."""
    height, width = image.shape[:2]
    x = uv[:, 0] * width - 0.5
    y = (1.0 - uv[:, 1]) * height - 0.5
    x0, y0 = np.floor(x), np.floor(y)
    fx, fy = (x - x0)[:, None], (y - y0)[:, None]
    x0, y0 = x0.astype(int) % width, y0.astype(int) % height
    x1, y1 = (x0 + 1) % width, (y0 + 1) % height
    top = image[y0, x0] * (1 - fx) + image[y0, x1] * fx
    bottom = image[y1, x0] * (1 - fx) + image[y1, x1] * fx
    return top * (1 - fy) + bottom * fy


def sample_texture(image: np.ndarray, uv: np.ndarray, footprint: tuple[float, float],
                   repeat: tuple[float, float]) -> np.ndarray:
    """Per-vertex colours (M, 3): the image tiled ``repeat`` times, averaged over a
    ``footprint`` (du, dv) around each uv (M, 2)."""
    offsets = (np.arange(FOOTPRINT_SAMPLES) + 0.5) / FOOTPRINT_SAMPLES - 0.5
    scale = np.asarray(repeat, dtype=float)
    total = np.zeros((len(uv), 3))
    for du in offsets * footprint[0]:
        for dv in offsets * footprint[1]:
            total += bilinear(image, (uv + (du, dv)) * scale)
    return total / FOOTPRINT_SAMPLES ** 2
