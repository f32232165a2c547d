"""Generate the shipped skirt print, ``scenes/textures/pareo.png``: a Hawaiian pareo of red, coral
and yellow hibiscus with white plumeria and green leaves on a deep ocean-blue ground, and a
tapa-pattern band along the bottom (the hem).

The image tiles horizontally (a skirt's u wraps around the seam): every shape is drawn at the
wrapped distance x − cx ∈ [−W/2, W/2). Its aspect (3.2 : 1) is a skirt's mean circumference over
its length, so the flowers come out round. Shapes are polar curves r(φ) around a centre, antialiased
by their coverage clamp(0.5 − (ρ − r(φ)) / pixel, 0, 1). Deterministic (fixed seed); run

    .venv/bin/python tools/make_texture.py [OUT.png]

to rewrite it. The palette is reduced to 96 colours to keep the file small.
"""

import sys
from pathlib import Path

import numpy as np
from PIL import Image

WIDTH, HEIGHT = 1024, 320  # pixels; u across, v down (row 0 = the waist)
BORDER = 34  # pixels of the hem band at the bottom
SEED = 7

OCEAN = np.array([0.04, 0.26, 0.42])
OCEAN_DEEP = np.array([0.02, 0.17, 0.30])
LEAF = np.array([0.10, 0.45, 0.28])
LEAF_DARK = np.array([0.05, 0.30, 0.20])
HIBISCUS = (np.array([0.86, 0.10, 0.14]), np.array([0.98, 0.45, 0.32]), np.array([0.99, 0.80, 0.22]))
HIBISCUS_THROAT = np.array([0.45, 0.02, 0.10])
POLLEN = np.array([1.0, 0.88, 0.30])
PLUMERIA = np.array([0.99, 0.97, 0.92])
PLUMERIA_HEART = np.array([1.0, 0.78, 0.25])
TAPA = np.array([0.93, 0.85, 0.68])


class Canvas:
    """An RGB float image with wrapped-x polar coordinates around any centre."""

    def __init__(self, width: int, height: int, background: np.ndarray):
        self.pixels = np.broadcast_to(background, (height, width, 3)).copy()
        self.y, self.x = np.mgrid[0:height, 0:width].astype(float) + 0.5

    def polar(self, cx: float, cy: float, angle: float):
        """(ρ, φ) of every pixel around (cx, cy) px, with x wrapped, φ measured from ``angle``."""
        width = self.pixels.shape[1]
        dx = (self.x - cx + width / 2) % width - width / 2
        dy = self.y - cy
        return np.hypot(dx, dy), np.arctan2(dy, dx) - angle

    def paint(self, coverage: np.ndarray, color) -> None:
        """Blend ``color`` (3,) or (H, W, 3) over the image with per-pixel ``coverage`` in [0, 1]."""
        alpha = np.clip(coverage, 0.0, 1.0)[..., None]
        self.pixels = self.pixels * (1 - alpha) + np.asarray(color) * alpha


def inside(rho: np.ndarray, radius: np.ndarray) -> np.ndarray:
    """Antialiased coverage of the polar shape ρ ≤ r(φ), one pixel wide edge."""
    return np.clip(0.5 + radius - rho, 0.0, 1.0)


def leaf(canvas: Canvas, cx, cy, length, angle, color) -> None:
    """A pointed leaf from (cx, cy) along ``angle``: half-width ∝ sin(π s)^0.8 with a midrib."""
    rho, phi = canvas.polar(cx, cy, angle)
    along = rho * np.cos(phi)
    across = rho * np.sin(phi)
    s = np.clip(along / length, 0.0, 1.0)
    half_width = 0.22 * length * np.sin(np.pi * s) ** 0.8
    canvas.paint(np.clip(0.5 + half_width - np.abs(across), 0, 1) * (along > 0) * (along < length),
                 color)
    canvas.paint(np.clip(1.2 - np.abs(across), 0, 1) * (along > 0.05 * length)
                 * (along < 0.9 * length) * 0.6, LEAF_DARK * 0.7)


def hibiscus(canvas: Canvas, cx, cy, radius, angle, color) -> None:
    """Five broad ruffled petals, r(φ) = R (0.72 + 0.28 |cos(5φ/2)|^0.4 + ruffle), a dark throat
    fading out along the petals, vein lines, and the long stamen with its pollen tip."""
    rho, phi = canvas.polar(cx, cy, angle)
    lobes = np.abs(np.cos(2.5 * phi)) ** 0.4
    edge = radius * (0.72 + 0.28 * lobes + 0.025 * np.sin(23 * phi))
    shade = np.clip(rho / edge, 0, 1)[..., None]
    petal = color * (0.78 + 0.22 * shade) + (1 - color) * 0.12 * shade ** 4
    canvas.paint(inside(rho, edge), petal)
    canvas.paint(inside(rho, edge) * np.clip(1.5 - np.abs(np.sin(2.5 * phi)) * rho * 0.6, 0, 1)
                 * 0.35, HIBISCUS_THROAT)
    canvas.paint(inside(rho, 0.34 * radius * (1 + 0.15 * lobes)) * (1 - rho / (0.5 * radius)) * 1.4,
                 HIBISCUS_THROAT)
    stamen_angle = 0.6
    stamen_rho, stamen_phi = canvas.polar(cx, cy, angle + stamen_angle)
    along = stamen_rho * np.cos(stamen_phi)
    across = stamen_rho * np.sin(stamen_phi)
    canvas.paint(np.clip(1.6 - np.abs(across), 0, 1) * (along > 0) * (along < 0.62 * radius),
                 POLLEN * 0.9)
    for k in range(5):
        dot_angle = angle + stamen_angle + 0.35 * (k - 2) / 2
        dot_x = cx + 0.66 * radius * np.cos(dot_angle)
        dot_y = cy + 0.66 * radius * np.sin(dot_angle)
        dot_rho, _ = canvas.polar(dot_x, dot_y, 0.0)
        canvas.paint(inside(dot_rho, 0.05 * radius), POLLEN)


def plumeria(canvas: Canvas, cx, cy, radius, angle) -> None:
    """Five overlapping oval petals, r(φ) = R (0.45 + 0.55 |cos(5φ/2)|), with a yellow heart."""
    rho, phi = canvas.polar(cx, cy, angle)
    edge = radius * (0.45 + 0.55 * np.abs(np.cos(2.5 * phi + 0.3 * np.sin(2.5 * phi))))
    canvas.paint(inside(rho, edge + 1.2), OCEAN_DEEP)
    canvas.paint(inside(rho, edge), PLUMERIA)
    canvas.paint(inside(rho, 0.45 * radius) * (1 - rho / (0.45 * radius)) * 1.6, PLUMERIA_HEART)


def hem_band(canvas: Canvas) -> None:
    """The bottom ``BORDER`` rows: a dark band with a row of tapa triangles and dots, periodic
    in x with a whole number of motifs."""
    top = HEIGHT - BORDER
    band = canvas.y > top
    canvas.paint(band.astype(float), OCEAN_DEEP)
    motif = WIDTH / 32
    phase = (canvas.x % motif) / motif
    rise = (canvas.y - top - 6) / (BORDER - 14)
    triangle = (rise > 0) & (rise < 1) & (np.abs(phase - 0.5) < 0.5 * rise)
    canvas.paint(triangle.astype(float), TAPA)
    line = np.abs(canvas.y - (top + 3)) < 1.2
    canvas.paint(line.astype(float), TAPA)
    dots_rho = np.hypot((canvas.x % motif) - 0.0, canvas.y - (HEIGHT - 6))
    canvas.paint(inside(dots_rho, 2.5), TAPA)


def make_pareo() -> np.ndarray:
    """The print as an (HEIGHT, WIDTH, 3) uint8 array."""
    random = np.random.default_rng(SEED)
    canvas = Canvas(WIDTH, HEIGHT, OCEAN)
    field_height = HEIGHT - BORDER
    shade = 0.5 + 0.5 * np.cos(2 * np.pi * canvas.y / field_height)
    canvas.paint(0.35 * shade, OCEAN_DEEP)

    columns = 7
    spacing = WIDTH / columns
    flowers = []
    for row, row_y in enumerate((0.27 * field_height, 0.73 * field_height)):
        for column in range(columns):
            x = (column + 0.5 * row) * spacing + random.uniform(-0.12, 0.12) * spacing
            y = row_y + random.uniform(-0.06, 0.06) * field_height
            flowers.append((x, y))
    for x, y in flowers:
        for _ in range(3):
            angle = random.uniform(0, 2 * np.pi)
            color = LEAF if random.uniform() < 0.6 else LEAF_DARK
            leaf(canvas, x, y, random.uniform(0.55, 0.75) * spacing, angle, color)
    for column in range(columns):
        x = (column + 0.25) * spacing + random.uniform(-0.05, 0.05) * spacing
        y = (0.5 + random.uniform(-0.08, 0.08)) * field_height
        plumeria(canvas, x, y, 0.16 * spacing, random.uniform(0, 2 * np.pi))
        plumeria(canvas, x + 0.5 * spacing, (y + 0.5 * field_height) % field_height,
                 0.13 * spacing, random.uniform(0, 2 * np.pi))
    for index, (x, y) in enumerate(flowers):
        color = HIBISCUS[index % len(HIBISCUS)]
        hibiscus(canvas, x, y, random.uniform(0.36, 0.42) * spacing,
                 random.uniform(0, 2 * np.pi), color)
    hem_band(canvas)
    return np.round(np.clip(canvas.pixels, 0, 1) * 255).astype(np.uint8)


def main(argv: list[str]) -> int:
    target = Path(argv[1]) if len(argv) > 1 else \
        Path(__file__).resolve().parent.parent / "scenes" / "textures" / "pareo.png"
    target.parent.mkdir(parents=True, exist_ok=True)
    image = Image.fromarray(make_pareo()).quantize(96, dither=Image.Dither.NONE)
    image.save(target, optimize=True)
    print(f"{target}: {WIDTH}×{HEIGHT}, {target.stat().st_size // 1024} KB")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv))
