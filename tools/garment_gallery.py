"""Draw the garment library, ``docs/garments.png``: the A-line skirt (``skirt``), the half and
full circle skirts (``circle-skirt``) and the pleated skirt (``pleated``), each of cotton in
one colour, settled on the still dancer (two seconds after settling), side by side. Run

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
    ("full circle: circle-skirt", ["cloth.shape='circle-skirt'", "cloth.length=0.45"]),
    ("pleated: 16 box pleats 3 cm deep", ["cloth.shape='pleated'", "cloth.pleats=16",
                                          "cloth.pleat_depth=0.03"]),
)
COMMON = ["cloth.resolution=[96, 24]", "body.motion='still'", "render.texture='none'",
          "render.cloth_color=[0.2, 0.35, 0.6]", "render.camera_position=[0.9, 1.15, 1.9]",
          "render.camera_lookat=[0.0, 0.72, 0.0]"]


def gallery(target: Path) -> None:
    figure = Figure(figsize=(4 * len(GARMENTS), 3.9))
    panels = figure.subplots(1, len(GARMENTS))
    with tempfile.TemporaryDirectory() as scratch:
        for axes, (title, overrides) in zip(panels, GARMENTS):
            out = Path(scratch) / str(len(title))
            sets = [item for key in COMMON + overrides for item in ("--set", key)]
            main(["render", "hula", *sets, "--frames", "60", "--width", "480", "--height",
                  "400", "--quiet", "--out", str(out)])
            axes.imshow(read_png(out / "frames" / "frame_00060.png"))
            axes.set_title(title, fontsize=10)
            axes.set_axis_off()
    figure.subplots_adjust(left=0.01, right=0.99, bottom=0.01, top=0.92, wspace=0.04)
    with atomic_path(target, ".png") as temporary:
        figure.savefig(temporary, format="png", dpi=110)


if __name__ == "__main__":
    gallery(Path(sys.argv[1]) if len(sys.argv) > 1 else
            Path(__file__).resolve().parent.parent / "docs" / "garments.png")
