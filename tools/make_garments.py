"""Write the example garment meshes in ``scenes/garments/``, as a pattern tool would hand them
over: Wavefront OBJ, metres, y up, the garment as worn (its rest shape), UVs = where each vertex
lies on the flat pattern pieces (so the warp follows each piece's straight grain), the
waistband a group of its own to pin. Deterministic; run

    .venv/bin/python tools/make_garments.py [FOLDER]

- ``hilo-skirt.obj``: a four-gore A-line skirt with a high-low hem, knee length at the back
  (``BACK_LENGTH``) and above the knee at the front (``FRONT_LENGTH``). The skirt is a cone from
  the waist (radius ``WAIST_RADIUS`` at the dancer's waist height) flaring at ``FLARE`` rad;
  a cone is developable, so each gore (a quarter of it, from the centre front, side, back and
  side) unrolls flat into an annulus sector, and the gore's straight grain runs down its centre
  line: the warp hangs straight at the middle of each gore and turns ~20° off at the seams, as
  on a sewn gored skirt. The four gores are separate islands of the UV map, so the vertices on
  the seams carry two texture coordinates each. Quads: ``AROUND`` columns, ``DOWN`` rows, the
  first row a ``WAISTBAND`` wide band (group ``waistband``), the rest (group ``skirt``) spread
  evenly down to the hem. A garment no grid of the library can make (its rows are not level).
"""

import sys
from pathlib import Path

import numpy as np

WAIST_RADIUS = 0.17  # m
WAIST_HEIGHT = 0.99  # m, the dancer's waist in her rest pose
FLARE = 0.42  # rad, the cone's half-angle
FRONT_LENGTH, BACK_LENGTH = 0.40, 0.62  # m along the fabric, waist to hem
WAISTBAND = 0.006  # m, the first row's width
AROUND, DOWN = 64, 28  # columns (16 a gore), rows
GORES = 4


def hilo_skirt() -> tuple[np.ndarray, np.ndarray, np.ndarray, list, list]:
    """(positions (N, 3), texture coordinates (M, 2), corner texture index per (vertex, gore)
    (N, GORES), waistband quads, skirt quads): quads as 0-based ((vertex, gore) × 4), their
    normals outwards."""
    theta = 2 * np.pi * np.arange(AROUND) / AROUND  # from +x towards +z (the front)
    length = FRONT_LENGTH + (BACK_LENGTH - FRONT_LENGTH) * (1 - np.sin(theta)) / 2
    fraction = np.concatenate([[0.0], np.linspace(0.0, 1.0, DOWN - 1)])
    along = np.empty((DOWN, AROUND))  # m down the fabric from the waist
    along[0] = 0.0
    along[1:] = WAISTBAND + fraction[1:, None] * (length[None, :] - WAISTBAND)
    radius = WAIST_RADIUS + along * np.sin(FLARE)
    positions = np.stack([radius * np.cos(theta), WAIST_HEIGHT - along * np.cos(FLARE),
                          radius * np.sin(theta)], axis=-1).reshape(-1, 3)
    # Each gore unrolled: the cone's apex at the origin of the pattern, slant radius
    # R = WAIST_RADIUS/sin(FLARE) + along, and an angle ψ = sin(FLARE)·(θ − the gore's centre);
    # the gore's centre line runs down the pattern (−v), its islands side by side in u.
    gore_width = 2 * np.pi / GORES
    slant = WAIST_RADIUS / np.sin(FLARE) + along
    coordinates, corner = [], np.full((DOWN * AROUND, GORES), -1)
    for gore in range(GORES):
        centre = (gore + 0.5) * gore_width
        offset = (theta - centre + np.pi) % (2 * np.pi) - np.pi  # in (−π, π]
        member = np.abs(offset) <= gore_width / 2 + 1e-9
        psi = np.sin(FLARE) * offset[member]
        u = slant[:, member] * np.sin(psi)
        v = -slant[:, member] * np.cos(psi)
        island = np.stack([(u + 0.5) / GORES + gore / GORES, v + 1.1], axis=-1)
        rows, columns = np.meshgrid(np.arange(DOWN), np.flatnonzero(member), indexing="ij")
        corner[(rows * AROUND + columns).ravel(), gore] = len(coordinates) + np.arange(
            island.size // 2)
        coordinates.extend(island.reshape(-1, 2))
    index = np.arange(DOWN * AROUND).reshape(DOWN, AROUND)
    quads = []
    for row in range(DOWN - 1):
        for column in range(AROUND):
            gore = int((theta[column] + 1e-9) // gore_width) % GORES
            right = (column + 1) % AROUND
            quads.append([(index[row, column], gore), (index[row, right], gore),
                          (index[row + 1, right], gore), (index[row + 1, column], gore)])
    return positions, np.array(coordinates), corner, quads[:AROUND], quads[AROUND:]


def write_obj(path: Path, positions, coordinates, corner, groups: dict) -> None:
    lines = ["# taichi_cloth example garment (tools/make_garments.py): metres, y up"]
    lines += [f"v {x:.6f} {y:.6f} {z:.6f}" for x, y, z in positions]
    lines += [f"vt {u:.6f} {v:.6f}" for u, v in coordinates]
    for name, quads in groups.items():
        lines.append(f"g {name}")
        lines += ["f " + " ".join(f"{vertex + 1}/{corner[vertex, gore] + 1}"
                                  for vertex, gore in quad) for quad in quads]
    path.write_text("\n".join(lines) + "\n", encoding="utf-8")


def main(folder: Path) -> None:
    folder.mkdir(parents=True, exist_ok=True)
    positions, coordinates, corner, waistband, skirt = hilo_skirt()
    write_obj(folder / "hilo-skirt.obj", positions, coordinates, corner,
              {"waistband": waistband, "skirt": skirt})
    print(f"{folder / 'hilo-skirt.obj'}: {len(positions)} vertices, {len(coordinates)} texture "
          f"coordinates, {len(waistband) + len(skirt)} quads")


if __name__ == "__main__":
    main(Path(sys.argv[1]) if len(sys.argv) > 1 else
         Path(__file__).resolve().parent.parent / "scenes" / "garments")
