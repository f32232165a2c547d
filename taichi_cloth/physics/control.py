"""Prescribed motion of points (pinned particles, capsule endpoints) inside the kernels.

The body is posed on the host a few times per frame, not every substep: ``KinematicTrack``
holds positions and velocities of K points at S + 1 evenly spaced sample times covering one frame,
and ``at(i_k, t)`` interpolates them with cubic Hermite splines, so any substep or RK4 stage time
gets a C¹ position and its velocity without host work in the substep loop:

    p(s) = h00(s)·p0 + h10(s)·Δ·v0 + h01(s)·p1 + h11(s)·Δ·v1,   s = (t − t_k)/Δ ∈ [0, 1]
    h00 = 2s³ − 3s² + 1, h10 = s³ − 2s² + s, h01 = −2s³ + 3s², h11 = s³ − s²
    v(s) = (h00'·p0 + h10'·Δ·v0 + h01'·p1 + h11'·Δ·v1) / Δ

Times outside the sampled span clamp to its ends.
"""

import numpy as np
import taichi as ti

from taichi_cloth.uploads import UploadBatch, upload


@ti.data_oriented
class KinematicTrack:
    """Positions [m] and velocities [m/s] of ``point_count`` points at ``sample_count`` times."""

    def __init__(self, point_count: int, sample_count: int, real):
        self.point_count = point_count
        self.sample_count = sample_count
        self.real = real
        self.numpy_real = np.float64 if real == ti.f64 else np.float32
        self.position = ti.Vector.field(3, real, (sample_count, point_count))
        self.velocity = ti.Vector.field(3, real, (sample_count, point_count))
        self.timing = ti.field(ti.f64, 2)  # first sample time [s], interval between samples [s]

    def pairs(self, first_time: float, interval: float, positions: np.ndarray,
              velocities: np.ndarray) -> list:
        """(field, array) pairs for ``uploads.upload``: positions, velocities (sample_count,
        point_count, 3) at first_time + k·interval."""
        return [(self.position, np.ascontiguousarray(positions, dtype=self.numpy_real)),
                (self.velocity, np.ascontiguousarray(velocities, dtype=self.numpy_real)),
                (self.timing, np.array([first_time, interval]))]

    def upload(self, first_time: float, interval: float, positions: np.ndarray,
               velocities: np.ndarray) -> None:
        """positions, velocities: (sample_count, point_count, 3) at first_time + k·interval."""
        upload(self.pairs(first_time, interval, positions, velocities))

    def held(self, positions: np.ndarray) -> list:
        """``pairs`` of points that stay where they are: every sample at ``positions`` (K,3), at
        rest."""
        repeated = np.repeat(positions[None], self.sample_count, axis=0)
        return self.pairs(0.0, 1.0, repeated, np.zeros_like(repeated))

    def hold(self, positions: np.ndarray) -> None:
        """Upload ``held(positions)``."""
        upload(self.held(positions))

    @ti.func
    def at(self, i_k, t):
        """Position [m] and velocity [m/s] of point i_k at time t [s]."""
        k, weights, delta = self.basis(t)
        return self.blend(i_k, k, weights, delta)

    @ti.func
    def basis(self, t):
        """What ``at`` takes of time t [s], the same for every point: (the sample k before it,
        the weights (h00, h10, h01, h11, h00', h10', h01', h11') at s (module docstring), Δ [s])."""
        span = ti.cast(self.sample_count - 1, ti.f64)
        s_total = ti.min(ti.max((ti.cast(t, ti.f64) - self.timing[0]) / self.timing[1], 0.0),
                         span)
        k = ti.min(ti.cast(ti.floor(s_total), ti.i32), self.sample_count - 2)
        s = ti.cast(s_total - k, self.real)
        s2, s3 = s * s, s * s * s
        weights = ti.Vector([2 * s3 - 3 * s2 + 1, s3 - 2 * s2 + s, 3 * s2 - 2 * s3, s3 - s2,
                             6 * s2 - 6 * s, 3 * s2 - 4 * s + 1, 6 * s - 6 * s2, 3 * s2 - 2 * s])
        return k, weights, ti.cast(self.timing[1], self.real)

    @ti.func
    def blend(self, i_k, k, weights, delta):
        """Position [m] and velocity [m/s] of point i_k from the ``basis`` (k, weights, Δ) of a
        time (computed once for all the points a loop poses)."""
        p0, p1 = self.position[k, i_k], self.position[k + 1, i_k]
        v0, v1 = delta * self.velocity[k, i_k], delta * self.velocity[k + 1, i_k]
        position = weights[0] * p0 + weights[1] * v0 + weights[2] * p1 + weights[3] * v1
        slope = weights[4] * p0 + weights[5] * v0 + weights[6] * p1 + weights[7] * v1
        return position, slope / delta


@ti.data_oriented
class Control:
    """Everything prescribed rather than simulated, in one place that the body rig writes once per
    frame (``physics.rig``) and the kernels read at every substep and stage:

    - the pinned particles: ``pin_slot[i]`` is particle i's point in ``pin_track`` (−1 for a free
      particle); a static pin holds its rest position, a worn skirt's waist follows the pelvis;
    - the body's capsules: ``capsule_radius`` [m] (constant) and ``capsule_track``, whose points
      2c and 2c + 1 are capsule c's endpoints a and b; ``capsule_ends_at_frame_end`` are host
      copies (a, b) of their positions at the end of the frame last written, for the metrics.

    The model (``physics.model``) holds only constants.
    """

    def __init__(self, pinned: np.ndarray, rest_positions: np.ndarray, real,
                 capsule_radius: np.ndarray = np.zeros(0), sample_count: int = 2):
        """pinned (N,) bool; rest_positions (N, 3) [m]; sample_count: times per frame at which
        the rig samples the motion (2 when nothing moves)."""
        self.pinned_particles = np.flatnonzero(pinned)
        self.capsule_radius = np.asarray(capsule_radius, dtype=np.float64)
        self.capsule_count = len(self.capsule_radius)
        self.capsule_ends_at_frame_end = (np.zeros((0, 3)), np.zeros((0, 3)))
        self.pin_slot = ti.field(ti.i32, len(pinned))
        self.pin_track = KinematicTrack(max(1, len(self.pinned_particles)), sample_count, real)
        self.capsule_track = KinematicTrack(2 * self.capsule_count, sample_count, real) \
            if self.capsule_count else None
        self._rest_positions = rest_positions

    def upload(self, batch: UploadBatch | None = None) -> None:
        """Fill the fields, pins held at their rest positions: now, or with ``batch`` (the
        model's ``uploads``, sent once every field is allocated: one SNode tree)."""
        slot = np.full(len(self._rest_positions), -1, dtype=np.int32)
        slot[self.pinned_particles] = np.arange(len(self.pinned_particles), dtype=np.int32)
        held = self.pin_track.held(self._rest_positions[self.pinned_particles]) \
            if len(self.pinned_particles) else []
        pairs = [(self.pin_slot, slot), *held]
        if batch is None:
            upload(pairs)
        else:
            batch.add(pairs)

    @ti.func
    def pin_target(self, i_p, t):
        """Position [m] and velocity [m/s] of pinned particle i_p at time t [s]."""
        return self.pin_track.at(self.pin_slot[i_p], t)

    @ti.func
    def pin_basis(self, t):
        """The pins' track's ``KinematicTrack.basis`` at time t [s], for ``pin_target_from``."""
        return self.pin_track.basis(t)

    @ti.func
    def pin_target_from(self, i_p, k, weights, delta):
        """``pin_target`` of pinned particle i_p at the time of ``pin_basis`` (k, weights, Δ):
        a loop over the pins takes the time's weights once."""
        return self.pin_track.blend(self.pin_slot[i_p], k, weights, delta)
