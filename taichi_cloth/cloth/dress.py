"""The dress of the garment library (``cloth.shape = "dress"``): a bodice, a skirt and two
shoulder straps, one mesh built in its worn shape and then made into a garment as any mesh is
(``mesh_garment.garment_from_mesh``). Sizes in metres, for the default dancer (scale 1).

- Bodice and skirt are one tube of ``resolution`` = [around, down] particles, periodic around
  (θ from +x towards +z, her front), its rows spread evenly along the fabric from the top edge,
  ``bodice_height`` above the waist, down to the hem: a cylinder of ``bodice_radius`` (the torso's
  capsules are 11–12 cm thick, the bodice a little wider) to the waist, then the skirt's cone,
  flaring to ``hem_radius`` over ``length`` along the fabric (as ``skirt``).
- A strap on each side rises from the bodice's top edge at her front, where the bodice's columns
  are ``STRAP_OFFSET`` from the body's middle plane, over the shoulder to the same columns at her
  back: a half ellipse in the plane x = const of each column it spans, ``STRAP_RISE`` above the top
  edge at its apex (3 cm over the body's shoulder capsule, whose top is 9 cm above the
  bodice's edge: at 1–2 cm, the strap pressed on the capsule jerked its pinned ends to 3–5 %
  strain in single frames), as many columns wide as ``strap_width`` needs and with rows about as
  far apart as the tube's. The straps share their end rows with the bodice's top edge, so the
  mesh is one manifold piece.
- Pins (``pin = "shoulders"``): the part of each strap that lies over the shoulder (its faces
  where sin φ > ``SHOULDER_SINE``, the middle 60 % of the arc, down to 7 cm over the bodice's
  edge), carried by the chest frame: a dancer's shoulders hold a dress up by their sloping shape
  and friction, which the straight shoulder capsule (x-aligned, from joint to joint) does not
  have, so the pins stand for them. (With only the apex pinned, the free strap beside it fell
  onto the torso's capsule, and the stiff strap pressed between pins and capsule stretched
  10–16 %. Pinned from sin φ > 0.75, the free strap met its pins at 45° to the vertical and
  wool's stiffer, heavier strap sheared there by 27 % as the dance began, 16 % with the earlier
  straps; from 0.6, 2.1 %.)
- UVs: the tube as a skirt's (u = θ/2π, its seam at u = 1; v from 1 at the top edge down, in
  proportion to the fabric's length), so its warp runs down the dress; each strap an island of
  its own along its length, cut on the straight grain.
"""

import numpy as np

from taichi_cloth.cloth.obj_mesh import ObjMesh
from taichi_cloth.config.tables import ClothConfig
from taichi_cloth.errors import InputError

STRAP_OFFSET = 0.085  # m, from her middle plane (x = 0) to a strap's middle
STRAP_RISE = 0.12  # m, from the bodice's top edge to a strap's apex
SHOULDER_SINE = 0.6  # the strap's faces with sin φ above this lie on the shoulder: pinned


def dress_mesh(cloth: ClothConfig, waist_height: float, source: str) -> tuple[ObjMesh, np.ndarray]:
    """The dress's mesh (quads with per-corner UVs, the group "shoulders") and its positions
    (module docstring); ``waist_height`` [m] places the waist."""
    around, down = cloth.resolution
    bodice, skirt_length = cloth.bodice_height, cloth.length
    radius, flare = cloth.bodice_radius, cloth.hem_radius - cloth.bodice_radius
    if not 0 <= flare < skirt_length or not STRAP_OFFSET < radius:
        raise InputError(f"{source}: cloth.hem_radius: a dress's hem must lie between "
                         f"bodice_radius {radius:g} m and bodice_radius + length "
                         f"{radius + skirt_length:g} m, and bodice_radius beyond "
                         f"{STRAP_OFFSET} m")
    theta = 2 * np.pi * np.arange(around) / around
    along = np.linspace(0.0, bodice + skirt_length, down)  # m down the fabric from the top
    below_waist = np.maximum(along - bodice, 0.0)
    ring_radius = radius + below_waist * flare / skirt_length
    drop = np.where(along < bodice, along,
                    bodice + below_waist * np.sqrt(1 - (flare / skirt_length) ** 2))
    top = waist_height + bodice
    tube = np.stack([ring_radius[:, None] * np.cos(theta), np.repeat((top - drop)[:, None],
                                                                     around, axis=1),
                     ring_radius[:, None] * np.sin(theta)], axis=-1).reshape(-1, 3)
    tube_index = np.arange(down * around).reshape(down, around)
    spacing = (bodice + skirt_length) / (down - 1)
    width = max(1, round(cloth.strap_width / (2 * np.pi * radius / around)))
    positions, strap_faces, strap_uvs, pinned_faces = [tube], [], [], []
    count = len(tube)
    if around % 2:
        raise InputError(f"{source}: cloth.resolution: a dress needs an even number of "
                         f"particles around (its straps mirror each other), got {around}")
    left_front = int(np.argmin(np.abs(radius * np.cos(theta) - STRAP_OFFSET)
                               + 10.0 * (np.sin(theta) <= 0)))  # her left: +x, front: +z
    left_columns = left_front - width // 2 + np.arange(width + 1)
    for columns in (left_columns, np.sort(around // 2 - left_columns)):  # x → −x: θ → π − θ
        back_columns = (-columns) % around  # the mirror image through the x–y plane, z → −z
        x, z = radius * np.cos(theta[columns]), radius * np.sin(theta[columns])
        arc_length = np.pi * np.sqrt((z.mean() ** 2 + STRAP_RISE ** 2) / 2)
        steps = max(4, 2 * round(arc_length / spacing / 2))
        phi = np.linspace(0.0, np.pi, steps + 1)[1:-1]
        shape = (len(phi), len(x))
        inner = np.stack([np.broadcast_to(x, shape),
                          np.broadcast_to(top + STRAP_RISE * np.sin(phi)[:, None], shape),
                          np.cos(phi)[:, None] * z], axis=-1)
        rows = np.concatenate([tube_index[0, columns][None, :],
                               count + np.arange(inner[..., 0].size).reshape(inner.shape[:2]),
                               tube_index[0, back_columns][None, :]])
        positions.append(inner.reshape(-1, 3))
        count += inner[..., 0].size
        for j in range(steps):
            for a in range(width):
                strap_faces.append([rows[j, a], rows[j + 1, a], rows[j + 1, a + 1],
                                    rows[j, a + 1]])  # outwards, as the tube's
                corner_uv = [(a, j), (a, j + 1), (a + 1, j + 1), (a + 1, j)]
                strap_uvs.append([(0.9 + (0.05 if columns[0] > around // 4 else 0.0)
                                   + 0.04 * u / width,
                                   1.0 - v / steps) for u, v in corner_uv])
                if np.sin(np.pi * (j + 0.5) / steps) > SHOULDER_SINE:
                    pinned_faces.append(len(strap_faces) - 1)
    tube_faces, tube_uvs = tube_quads(tube_index, along / along[-1])
    faces = np.array(tube_faces + strap_faces, np.int64)
    corner_uvs = np.array(tube_uvs + strap_uvs, float)
    uvs = corner_uvs.reshape(-1, 2)
    shoulders = np.unique(np.array(strap_faces)[pinned_faces])
    mesh = ObjMesh(np.concatenate(positions), faces,
                   np.arange(faces.size).reshape(faces.shape), uvs, {"shoulders": shoulders})
    return mesh, mesh.positions


def tube_quads(index: np.ndarray, fraction: np.ndarray) -> tuple[list, list]:
    """The tube's quads (rows × around, periodic), wound outwards, and their corner UVs (u =
    column/around, u = 1 on the seam's far side; v = 1 − 0.95·fraction down the fabric)."""
    rows, around = index.shape
    faces, uvs = [], []
    for r in range(rows - 1):
        for c in range(around):
            right = (c + 1) % around
            faces.append([index[r, c], index[r, right], index[r + 1, right], index[r + 1, c]])
            u0, u1 = c / around, (c + 1) / around
            v0, v1 = 1.0 - 0.95 * fraction[r], 1.0 - 0.95 * fraction[r + 1]
            uvs.append([(0.85 * u0, v0), (0.85 * u1, v0), (0.85 * u1, v1), (0.85 * u0, v1)])
    return faces, uvs
