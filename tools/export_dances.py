"""Write the procedural dances as BVH clips, ``scenes/motions/<dance>.bvh``: one whole loop of
each (hula, sway, twirl and walk at 90 beats a minute, no ease-in, 30 frames a second), so that the
clip's last frame is its first and a reader loops it. The ``mocap`` scene plays ``hula.bvh``;
any BVH tool (Blender, a motion library) can play them too. Deterministic; run

    .venv/bin/python tools/export_dances.py [FOLDER]

to rewrite them (``taichi_cloth/body/bvh_export.py`` says how the skeleton is made).
"""

import sys
from pathlib import Path

from taichi_cloth.body.bvh_export import write_dance_bvh
from taichi_cloth.body.dancer import Body

FPS = 30
TEMPO = 90.0  # beats per minute


def main(folder: Path) -> None:
    for motion in ("hula", "sway", "twirl", "walk"):
        body = Body(motion, TEMPO, 1.0, "split", 1.0, ease_in=0.0)
        loop = body.loop_period  # 8 beats: every dance repeats after it
        write_dance_bvh(body, folder / f"{motion}.bvh", loop, FPS)
        print(f"{folder / f'{motion}.bvh'}: {loop:.3f} s, {round(loop * FPS) + 1} frames")


if __name__ == "__main__":
    main(Path(sys.argv[1]) if len(sys.argv) > 1 else Path(__file__).resolve().parent.parent
         / "scenes" / "motions")
