"""Batched 3-D geometry for the skeletons (``body.dancer``, ``body.mocap``): vectors, rotation
matrices and rigid turns over any leading axes (the dancer's sample times), built only from
complex-analytic operations, so the complex-step velocities pass through them."""

import numpy as np


def _filled(entries, shape: tuple) -> np.ndarray:
    """``entries`` (scalars, or arrays of one common shape B: the batch) laid out in order
    along trailing axes of ``shape``: an array of shape B + ``shape``."""
    leading = max((getattr(entry, "shape", ()) for entry in entries), key=len)
    out = np.empty(leading + shape, np.result_type(*entries))
    flat = out.reshape(leading + (len(entries),))
    for k, entry in enumerate(entries):
        flat[..., k] = entry
    return out


def vector(x, y, z):
    """(..., 3) vectors from three components of broadcastable shapes."""
    return _filled((x, y, z), (3,))


def matrix(rows):
    """(..., 3, 3) matrices from three rows of three broadcastable components."""
    return _filled([entry for row in rows for entry in row], (3, 3))


def rotation_x(angle):
    """Rotation matrices (..., 3, 3) about +x by ``angle`` (...) (rad)."""
    c, s = np.cos(angle), np.sin(angle)
    return matrix([(1.0, 0.0, 0.0), (0.0, c, -s), (0.0, s, c)])


def rotation_y(angle):
    """Rotation matrices (..., 3, 3) about +y by ``angle`` (...) (rad)."""
    c, s = np.cos(angle), np.sin(angle)
    return matrix([(c, 0.0, s), (0.0, 1.0, 0.0), (-s, 0.0, c)])


def rotation_z(angle):
    """Rotation matrices (..., 3, 3) about +z by ``angle`` (...) (rad)."""
    c, s = np.cos(angle), np.sin(angle)
    return matrix([(c, -s, 0.0), (s, c, 0.0), (0.0, 0.0, 1.0)])


def turned(points, rotation):
    """Points (..., P, 3) turned by rotations (..., 3, 3): R p for each (complex-step safe)."""
    return np.einsum("...pk,...jk->...pj", points, rotation)


def turned_vector(vectors, rotation):
    """Vectors (..., 3) turned by rotations (..., 3, 3): R v for each (complex-step safe)."""
    return np.einsum("...jk,...k->...j", rotation, vectors)


def row_dot(u, v):
    """Dot products over the last axis of broadcastable arrays, without conjugation
    (complex-step safe)."""
    return np.sum(u * v, axis=-1)


def angular_velocity(rotation: np.ndarray, rotation_rate: np.ndarray) -> np.ndarray:
    """ω [rad/s] (..., 3) (world frame) of frames turning as R(t) (..., 3, 3): the axial vector
    of the skew matrix dR/dt·Rᵀ = [ω]×."""
    spin = rotation_rate @ np.swapaxes(rotation, -1, -2)
    return 0.5 * vector(spin[..., 2, 1] - spin[..., 1, 2], spin[..., 0, 2] - spin[..., 2, 0],
                         spin[..., 1, 0] - spin[..., 0, 1])
