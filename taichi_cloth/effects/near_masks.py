"""The broad phase of capsule contact (``effects/collision.py``, which mixes this class in): each
contact sample (a particle, an edge midpoint, a centroid) keeps a near-mask, the capsules within
r + margin + a slack s of it
(its distance to the axis segment), and only those are tested for it. The masks are made again
only when a particle or a capsule end has moved by more than s/2 since they were made (a sample,
a mean of particles, moves no farther than they do): until then a distance to a segment has
changed by less than s, so every capsule that a particle or a sample can touch is still in its
mask. A bit too many changes nothing (the sphere and the exact test decide): the forces are the
same, bit for bit, however old the masks and whatever their slack. On a dancing skirt most
samples hang clear of every capsule and skip the test, and a point walks only the set bits of
its mask (``_next_capsule``).

The slack follows the motion: a small one holds fewer capsules in fewer masks, a large one is
remade less often. At each remaking it is halved when the masks lasted more than
``REMADE_AFTER[1]`` evaluations, doubled when fewer than ``REMADE_AFTER[0]``, between
``MASK_SLACK`` of the longest rest edge: explicit substeps of ~40 µs settle at 1/16 of it (on
the dancing ``hula`` 63–279 samples with a capsule near instead of ~2,800), implicit steps of
1/60 s, where the hips move ~8 mm a step, stay at ½ (docs/performance.md).

A remaking makes each particle's mask twice, as it is and grown by ``sample_reach``, and each
other sample (an edge midpoint, a centroid) then tests only the capsules of its first
particle's grown mask, a superset of its own: the same masks as testing every capsule, in half
the time on ``hula`` (docs/performance.md).

A remaking also lists the samples whose mask holds a capsule (``near_sample``): an evaluation
looks at those alone.

A point near a capsule first tests its squared distance to the axes of its mask
(``_may_touch``, through ``_sample_mask``); each evaluation marks the particles of the samples
that touch a capsule (``touched_in``), and a particle with none reads none of its samples'
forces (all 0): on the dancing ``hula`` a few dozen of 1,792 particles (docs/performance.md).
The masks' remaking loops run no iteration while the masks are fresh.

The host class provides ``model``, ``capsule_count``, the posed capsules (``capsule_a``,
``capsule_b``, ``capsule_center``, ``capsule_reach_sq``, ``capsule_radius``), ``margin``,
``_axis_offset``, ``sample_count``, ``sample_corners``, ``sample_evaluation`` (each sample's
stamp: the evaluation that last stored its force) and ``_sample_point``.
"""

import numpy as np
import taichi as ti

MASK_BITS = 31  # capsules a sample's near-mask can hold (more: every sample tests them all)
# evaluations after which the marks and stamps start again from 0 (~11 simulated hours of 40 µs
# substeps), so that the i32 evaluation number never wraps (``_begin_marks``)
EVALUATION_RESTART = 1 << 30
MASK_SLACK = (1 / 16, 1 / 2)  # of the longest rest edge: the least and most slack of the masks
REMADE_AFTER = (16, 64)  # evaluations: masks lasting fewer double the slack, more halve it


@ti.data_oriented
class NearMasks:
    """Near-masks of a cloth's contact samples against posed capsules, and the particles whose
    samples touch one (module docstring)."""

    def allocate_masks(self, longest_rest_edge: float) -> None:
        """The masks (when there are at most ``MASK_BITS`` capsules: ``masked``), their slack
        between ``MASK_SLACK`` times the longest rest edge [m], and the evaluations' marks."""
        model, real = self.model, self.model.real
        self.masked = self.capsule_count <= MASK_BITS
        self.slack_range = tuple(bound * longest_rest_edge for bound in MASK_SLACK)  # m
        self.mask_slack = ti.field(real, ())  # m: the masks' slack now
        self.evaluations_kept = ti.field(ti.i32, ())  # since the masks were last made
        self.sample_near = ti.field(ti.i32, self.sample_count)
        # a particle's mask grown by ``sample_reach`` [m]: the samples it is the first particle
        # of within that distance of it test only its capsules, others every capsule. A
        # midpoint is half an edge away, a centroid at most ⅔ of the longest edge: 0.7 times
        # the longest rest edge holds them up to 5 % of stretch (any edge on a grid cloth)
        self.sample_reach = 0.7 * longest_rest_edge
        self.grown_near = ti.field(ti.i32, model.particle_count)
        # the samples whose mask holds a capsule, ascending, made with the masks: the only
        # ones an evaluation looks at (on the dancing ``hula`` 63-279 of 8,704)
        self.near_sample = ti.field(ti.i32, self.sample_count)
        self.near_count = ti.field(ti.i32, ())
        # where the particles and the capsules' ends were when the masks were made [m]; stale:
        # the masks are made again at this evaluation
        self.mask_x = ti.Vector.field(3, real, model.particle_count)
        self.mask_a = ti.Vector.field(3, real, self.capsule_count)
        self.mask_b = ti.Vector.field(3, real, self.capsule_count)
        self.mask_stale = ti.field(ti.i32, ())
        # bounding sphere's radius + the slack [m], made with the masks
        self.mask_sphere = ti.field(real, self.capsule_count)
        # each evaluation's number, and per particle the last one in which a sample of its
        # passed ``_may_touch``
        self.evaluation = ti.field(ti.i32, ())
        self.touched_in = ti.field(ti.i32, model.particle_count)
        # the particles marked in this evaluation, each once (in a parallel launch in any
        # order): every particle the contact force may be non-zero on (``touched_particles``)
        self.touched_list = ti.field(ti.i32, model.particle_count)
        self.touched_count = ti.field(ti.i32, ())
        self.touched_particles = (self.touched_list, self.touched_count)

    def mask_uploads(self) -> list:
        """(field, values) for the model's ``uploads``: positions far away, so that the first
        evaluation makes the masks, with the most slack."""
        far = np.full((self.model.particle_count, 3), np.inf)
        return [(self.mask_x, far.astype(self.model.numpy_real)),
                (self.mask_slack, np.array(self.slack_range[1], self.model.numpy_real))]

    @ti.func
    def _refresh_masks(self, x):
        """Every sample's near-mask made again at x [m] when a particle or a
        capsule end has moved by more than half the slack since the last time, the slack first
        fitted to how long the masks lasted (module docstring)."""
        half_slack_sq = 0.25 * self.mask_slack[None] ** 2
        ti.loop_config(serialize=True)
        for _ in range(1):
            self.mask_stale[None] = 0
        # an atomic max at every particle, not under a branch: a reduction that Taichi keeps per
        # thread and LLVM vectorises (the loop alone on ``hula``: 0.7-0.9 µs against 2.1-3.4 µs
        # branching; in the whole pass, within its noise)
        for i_p in range(self.model.particle_count):
            ti.atomic_max(self.mask_stale[None], ti.cast(
                (x[i_p] - self.mask_x[i_p]).norm_sqr() > half_slack_sq, ti.i32))
        for i_c in range(self.capsule_count):
            ti.atomic_max(self.mask_stale[None], ti.cast(
                (self.capsule_a[i_c] - self.mask_a[i_c]).norm_sqr() > half_slack_sq
                or (self.capsule_b[i_c] - self.mask_b[i_c]).norm_sqr() > half_slack_sq, ti.i32))
        ti.loop_config(serialize=True)
        for _ in range(1):
            self._fit_slack()
        # each loop's count times ``mask_stale``: no iteration while the masks are fresh (most
        # evaluations), and still a loop of its own, parallel in a parallel launch (a loop
        # under an ``if`` would run on one thread)
        for i_c in range(self.capsule_count * self.mask_stale[None]):
            self.mask_sphere[i_c] = ti.sqrt(self.capsule_reach_sq[i_c]) + self.mask_slack[None]
        for i_p in range(self.model.particle_count * self.mask_stale[None]):
            self.mask_x[i_p] = x[i_p]
        # the particles first (each its own sample), with their masks grown by the reach of
        # their samples; then every other sample tests only its first particle's grown mask
        for i_p in range(self.model.particle_count * self.mask_stale[None]):
            self.sample_near[i_p], self.grown_near[i_p] = self._near_masks(
                x[i_p], self.sample_reach, -1)
        for k in range((self.sample_count - self.model.particle_count) * self.mask_stale[None]):
            i_s = self.model.particle_count + k
            position = self._sample_point(x, i_s)
            first = self.sample_corners[i_s][0]
            candidates = self.grown_near[first]
            if (position - x[first]).norm_sqr() > self.sample_reach ** 2:
                candidates = -1  # a sample farther than the bound from its particle: all
            self.sample_near[i_s], _ = self._near_masks(position, 0.0, candidates)
        for i_c in range(self.capsule_count * self.mask_stale[None]):
            self.mask_a[i_c], self.mask_b[i_c] = self.capsule_a[i_c], self.capsule_b[i_c]
        ti.loop_config(serialize=True)
        for _ in range(self.mask_stale[None]):  # the samples with a capsule near, in order
            listed = 0
            for i_s in range(self.sample_count):
                if self.sample_near[i_s] != 0:
                    self.near_sample[listed] = i_s
                    listed += 1
            self.near_count[None] = listed

    @ti.func
    def _fit_slack(self):
        """At a remaking, the slack doubled if the masks lasted fewer than ``REMADE_AFTER[0]``
        evaluations, halved if more than ``REMADE_AFTER[1]``, within ``slack_range``; else one
        more evaluation kept."""
        real = self.model.real
        if self.mask_stale[None]:
            kept = self.evaluations_kept[None]
            if kept < REMADE_AFTER[0]:
                self.mask_slack[None] = ti.min(2 * self.mask_slack[None],
                                               real(self.slack_range[1]))
            elif kept > REMADE_AFTER[1]:
                self.mask_slack[None] = ti.max(0.5 * self.mask_slack[None],
                                               real(self.slack_range[0]))
            self.evaluations_kept[None] = 0
        else:
            self.evaluations_kept[None] += 1

    @ti.func
    def _near_masks(self, position, growth, candidates):
        """(the near-mask of ``position`` [m]: bit c set when it is within r_c + margin + the
        slack of capsule c's axis segment, the same grown by ``growth`` [m]) over the capsules
        whose bit is set in ``candidates`` (-1: all), each first culled by its bounding sphere
        grown by the slack and ``growth``."""
        mask, grown = 0, 0
        i_c = self._next_capsule(0, candidates)
        while i_c < self.capsule_count:
            sphere = self.mask_sphere[i_c] + growth
            if (position - self.capsule_center[i_c]).norm_sqr() < sphere * sphere:
                reach = self.capsule_radius[i_c] + self.model.real(self.margin) \
                    + self.mask_slack[None]
                distance = self._axis_offset(i_c, position)[1].norm()
                if distance < reach:
                    mask |= 1 << i_c
                if distance < reach + growth:
                    grown |= 1 << i_c
            i_c = self._next_capsule(i_c + 1, candidates)
        return mask, grown

    @ti.func
    def _next_capsule(self, i_c, mask):
        """The first capsule from i_c on whose bit is set in ``mask`` (with the masks off:
        i_c), or ``capsule_count`` when there is none: a point whose mask is 0 tests no
        capsule, one with a few bits only those. The lowest set bit of mask >> i_c found with
        a count of leading zeros, no loop over the bits (whose branches the processor guessed
        wrong: contact's pass on the dancing ``hula`` ~1 µs a substep shorter,
        docs/performance.md)."""
        found = i_c
        if ti.static(self.masked):
            rest = 0  # (no capsule from bit 31 on: ``MASK_BITS``)
            if i_c < MASK_BITS:
                rest = mask >> i_c
            found = self.capsule_count
            if rest != 0:
                found = i_c + 31 - ti.math.clz(rest & -rest)
        return found

    @ti.func
    def _may_touch(self, position, mask):
        """Whether ``position`` [m] is within (1 + 10⁻⁴)·(r + margin) of the axis of a capsule
        in ``mask`` (a squared distance, no root). Where not, ``_sample_contact`` finds depth ≤ 0
        at every capsule: a sample skips it (and its velocity) to the same result.
        On a dancing skirt ~1 in 200 samples near a capsule touches one (docs/performance.md)."""
        real = self.model.real
        touches = False
        i_c = self._next_capsule(0, mask)
        while i_c < self.capsule_count:
            offset = self._axis_offset(i_c, position)[1]
            reach = real(1.0 + 1e-4) * (self.capsule_radius[i_c] + real(self.margin))
            if offset.norm_sqr() < reach * reach:
                touches = True
                i_c = self.capsule_count
            else:
                i_c = self._next_capsule(i_c + 1, mask)
        return touches

    @ti.func
    def _sample_mask(self, x, i_s):
        """(sample i_s's point at x [m], its near-mask, or 0 where the point fails
        ``_may_touch``): the point is formed only for a sample with a capsule near (0 else).
        Every capsule where there are no masks (more than ``MASK_BITS`` capsules)."""
        mask = -1
        if ti.static(self.masked):
            mask = self.sample_near[i_s]
        position = ti.Vector.zero(self.model.real, 3)
        if mask != 0:
            position = self._sample_point(x, i_s)
            if not self._may_touch(position, mask):
                mask = 0
        return position, mask

    @ti.func
    def _sample_may_touch(self, i_p):
        """Whether a sample of particle i_p touched a capsule at the evaluation that ``prepare``
        made last (on a dancing skirt a few dozen of its particles)."""
        return self.touched_in[i_p] == self.evaluation[None]

    @ti.func
    def _begin_marks(self):
        """A new evaluation: no particle marked in it yet. Every ``EVALUATION_RESTART``
        evaluations the marks and the samples' stamps go back to 0 and the numbers start again:
        a wrapped (negative) number would never be the larger of an atomic max, and an old
        stamp equal to a number used again would read a stale force."""
        restart = ti.cast(self.evaluation[None] >= EVALUATION_RESTART, ti.i32)
        for i_p in range(self.model.particle_count * restart):
            self.touched_in[i_p] = 0
        for i_s in range(self.sample_count * restart):
            self.sample_evaluation[i_s] = 0
        self.evaluation[None] = self.evaluation[None] * (1 - restart) + 1
        self.touched_count[None] = 0

    @ti.func
    def _mark_touched(self, i_s):
        """Sample i_s touches a capsule at this evaluation: its particles are marked, so that
        they read their samples' forces, and listed in ``touched_list`` when first marked (the
        atomic max returns the older mark to one thread only)."""
        for a in ti.static(range(3)):
            i_p = self.sample_corners[i_s][a]
            if ti.atomic_max(self.touched_in[i_p], self.evaluation[None]) \
                    != self.evaluation[None]:
                self.touched_list[ti.atomic_add(self.touched_count[None], 1)] = i_p
