"""Draw the garment library, ``docs/garments.png``: the A-line skirt (``skirt``), the half and
full circle skirts (``circle-skirt``), the pleated skirt (``pleated``), the dress (``dress``) and
a garment from a mesh file (``scenes/garments/hilo-skirt.obj``), each of cotton in one colour,
settled on the still dancer (two seconds after settling), in two rows (the full circle with
self-collision). Run

    .venv/bin/python tools/garment_gallery.py [OUT.png]
"""

import sys
import tempfile
from pathlib import Path

from matplotlib.figure import Figure

from taichi_cloth.cli import main
from taichi_cloth.output.files import atomic_path, read_png

GARMENTS = (
    ("A-line: skirt", ["cloth.shape='skirt'"]),
    ("half circle: circle-skirt, circle = 0.5", ["cloth.shape='circle-skirt'", "cloth.circle=0.5",
                                                 "cloth.length=0.5"]),
    # a whole annulus falling onto the body folds through itself without self-collision (2,266
    # pairs of triangles and a crumpled skirt at frame 60), as in the twirl scene
    ("full circle: circle-skirt, self-collision", ["cloth.shape='circle-skirt'", "cloth.length=0.45",
                                                   "effects.self_collision=true"]),
    ("pleated: 16 box pleats 3 cm deep", ["cloth.shape='pleated'", "cloth.pleats=16",
                                          "cloth.pleat_depth=0.03"]),
    ("dress", ["cloth.shape='dress'", "cloth.pin='shoulders'", "cloth.resolution=[64, 34]",
               "cloth.hem_radius=0.38", "cloth.length=0.5", "simulation.dt=0.008333333333333333",
               "render.camera_position=[0.9, 1.35, 2.1]", "render.camera_lookat=[0.0, 0.9, 0.0]"]),
    ("from a file: hilo-skirt.obj", ["cloth.shape='mesh'", "cloth.mesh='garments/hilo-skirt.obj'",
                                     "cloth.pin='group'", "cloth.pin_groups=['waistband']"]),
)
COMMON = ["cloth.resolution=[96, 24]", "body.motion='still'", "render.texture='none'",
          "render.cloth_color=[0.2, 0.35, 0.6]", "render.camera_position=[0.9, 1.15, 1.9]",
          "render.camera_lookat=[0.0, 0.72, 0.0]"]


def gallery(target: Path) -> None:
    columns = (len(GARMENTS) + 1) // 2
    figure = Figure(figsize=(4 * columns, 7.8))
    panels = figure.subplots(2, columns).ravel()
    with tempfile.TemporaryDirectory() as scratch:
        for index, (axes, (title, overrides)) in enumerate(zip(panels, GARMENTS)):
            out = Path(scratch) / str(index)
            sets = [item for key in COMMON + overrides for item in ("--set", key)]
            main(["render", "hula", *sets, "--frames", "60", "--width", "480", "--height",
                  "400", "--quiet", "--out", str(out)])
            axes.imshow(read_png(out / "frames" / "frame_00060.png"))
            axes.set_title(title, fontsize=10)
            axes.set_axis_off()
    figure.subplots_adjust(left=0.01, right=0.99, bottom=0.01, top=0.95, wspace=0.04,
                           hspace=0.1)
    with atomic_path(target, ".png") as temporary:
        figure.savefig(temporary, format="png", dpi=110)


if __name__ == "__main__":
    gallery(Path(sys.argv[1]) if len(sys.argv) > 1 else
            Path(__file__).resolve().parent.parent / "docs" / "garments.png")
