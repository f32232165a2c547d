"""The side records of self-collision's candidate pairs (``effects/crossing_history.py``), kept
beside the finds of ``candidate_pairs.CandidatePairs``, which mixes this class in: each
particle's and edge's row of finds has a row of records; a rebuild carries a record over to the
same pair found again, gives a new pair the record it had at the last finished step at which
the list was whole, or else at the step before (``reference_x``), and keeps a pair that has
crossed in the list, however far apart it has gone, until it is back on its side;
``commit_record`` brings a record to the end of every step and ``keep_positions`` the positions
they refer to; ``back_up`` and ``roll_back`` keep them with the state that a redone frame goes
back to (docs/physics.md, "Self-collision").

The host class provides ``model``, ``found``/``found_count`` (the rows), ``pair_count``,
``pair_kind``, ``pair_particles``, ``pair_slot`` (each pair's find), ``_find``,
``_measure_deformation`` (which sets ``stale``), ``rebuild_asked``, ``reach`` and ``thickness``.
"""

import taichi as ti

from taichi_cloth.effects import crossing_history
from taichi_cloth.effects.proximity import (VERTEX_TRIANGLE, closest_offset, edge_edge_geometry,
                                            inside_within, pair_side, vertex_triangle_geometry)


@ti.data_oriented
class PairRecords:
    """Side records of a candidate list (module docstring)."""

    def allocate_records(self) -> None:
        """The records beside the finds of ``found``, the rows before a rebuild (carried over)
        and at a redone frame's start (``back_up``), the positions [m] that new pairs take their
        records at and those of the last finished step (``keep_positions``), and whether there was
        one."""
        rows, row_count = self.found.shape, self.found_count.shape
        self.found_record = ti.field(ti.i32, rows)
        self.previous_found, self.kept_found = (ti.field(ti.i32, rows) for _ in range(2))
        self.previous_record, self.kept_record = (ti.field(ti.i32, rows) for _ in range(2))
        self.previous_count, self.kept_count = (ti.field(ti.i32, row_count) for _ in range(2))
        # (count, found, record) of the rows, as ``_copy_row`` takes them
        self.rows = (self.found_count, self.found, self.found_record)
        self.previous_rows = (self.previous_count, self.previous_found, self.previous_record)
        self.kept_rows = (self.kept_count, self.kept_found, self.kept_record)
        particles, real = self.model.particle_count, self.model.real
        self.reference_x, self.kept_reference_x, self.last_x, self.kept_last_x = (
            ti.Vector.field(3, real, particles) for _ in range(4))
        self.committed, self.kept_committed = ti.field(ti.i32, ()), ti.field(ti.i32, ())

    @ti.func
    def _copy_row(self, owner, source: ti.template(), target: ti.template()):
        """Row ``owner`` of the (count, found, record) fields ``source`` copied to ``target``."""
        count = source[0][owner]
        target[0][owner] = count
        for n in range(count):
            target[1][owner, n] = source[1][owner, n]
            target[2][owner, n] = source[2][owner, n]

    @ti.func
    def _start_row(self, owner):
        """Walk ``owner``'s row moved to ``previous_*`` (its records to carry over), emptied."""
        self._copy_row(owner, ti.static(self.rows), ti.static(self.previous_rows))
        self.found_count[owner] = 0

    @ti.func
    def _held_record(self, owner, other):
        """(the side record that row ``owner``'s item ``other`` held before this rebuild, or
        ``crossing_history.UNKNOWN``; whether it was held)."""
        record = crossing_history.UNKNOWN
        held = 0
        for n in range(self.previous_count[owner]):
            if self.previous_found[owner, n] == other:
                record = self.previous_record[owner, n]
                held = 1
        return record, held

    @ti.func
    def _consider(self, x, owner, other, ids, kind: ti.template()):
        """Walk ``owner``'s candidate ``other``, the pair of ``kind`` and particles ``ids``: into
        the row if within the reach at x, with its side record: the one it held before this
        rebuild, or for a new pair the one it would have had at the last finished step at which
        the list was whole (``reference_x``; ``crossing_history.UNKNOWN`` before the first
        step). Most candidates are beyond the reach: their closest points alone are computed
        (``closest_offset``), the side at ``reference_x`` only for a new pair."""
        real = self.model.real
        offset = closest_offset(kind, x[ids[0]], x[ids[1]], x[ids[2]], x[ids[3]], real)
        if offset.norm_sqr() <= real(self.reach * self.reach):
            record, held = self._held_record(owner, other)
            if not held and self.committed[None]:
                geometry = ti.static(vertex_triangle_geometry if kind == VERTEX_TRIANGLE
                                     else edge_edge_geometry)
                _share, _inside, normal, height, offset = geometry(
                    self.reference_x[ids[0]], self.reference_x[ids[1]],
                    self.reference_x[ids[2]], self.reference_x[ids[3]], real)
                record = crossing_history.record_from_here(
                    inside_within(normal, height, offset, real(self.thickness)),
                    height)
            self._find(owner, other, record)

    @ti.func
    def _keep_crossed(self, owner):
        """The pairs of row ``owner``'s previous finds that have crossed and that this build did
        not find again (gone beyond the reach), appended with their records."""
        for n in range(self.previous_count[owner]):
            if crossing_history.is_crossed(self.previous_record[owner, n]):
                other = self.previous_found[owner, n]
                again = 0
                for m in range(self.found_count[owner]):
                    if self.found[owner, m] == other:
                        again = 1
                if not again:
                    self._find(owner, other, self.previous_record[owner, n])

    @ti.func
    def _place(self, k):
        """Pair k's find: (row, place) in ``found``."""
        per_row = ti.static(self.found.shape[1])
        return self.pair_slot[k] // per_row, self.pair_slot[k] % per_row

    @ti.func
    def record(self, k):
        """Pair k's side record (``crossing_history``)."""
        row, place = self._place(k)
        return self.found_record[row, place]

    @ti.func
    def set_record(self, k, record):
        row, place = self._place(k)
        self.found_record[row, place] = record

    @ti.func
    def side(self, x, k):
        """Pair k at positions x: ``proximity.pair_side`` of its kind and particles."""
        return pair_side(x, self.pair_kind[k], self.pair_particles[k], self.model.real)

    @ti.func
    def commit_record(self, k, inside, height):
        """Pair k's side record brought to the end of a step at which its closest points are
        ``inside`` with signed ``height`` [m] (``crossing_history.commit``); the new record."""
        record = crossing_history.commit(self.record(k), inside, height)
        self.set_record(k, record)
        return record

    @ti.func
    def keep_positions(self, x):
        """The positions x [m] of a finished step, every record committed to them
        (``commit_record``): x becomes ``last_x``, and ``reference_x``, where the pairs that the
        next build adds take their records, if the list still holds every pair within the
        thickness there (``_measure_deformation``); if not, ``reference_x`` is the step's start
        (the last ``last_x``), so a pair that came from beyond the reach through a face within
        the step is seen to have crossed at the next step's end. On one thread.
        (The build itself runs only in ``update``: inlined twice per step it doubled the
        kernels' compile time.)"""
        ti.loop_config(serialize=True)
        for _ in range(1):
            self._measure_deformation(x, False)
        ti.loop_config(serialize=True)
        for i in range(self.model.particle_count):
            if self.stale[None] and self.committed[None]:
                self.reference_x[i] = self.last_x[i]
            else:
                self.reference_x[i] = x[i]
            self.last_x[i] = x[i]
        self.committed[None] = 1

    @ti.kernel
    def crossed_count(self) -> ti.i32:
        """Listed pairs whose record says they have crossed."""
        count = 0
        for k in range(self.pair_count[None]):
            if crossing_history.is_crossed(self.record(k)):
                count += 1
        return count

    @ti.kernel
    def back_up(self):
        """The rows with their records kept (the start of a frame that may be redone)."""
        for owner in self.found_count:
            self._copy_row(owner, ti.static(self.rows), ti.static(self.kept_rows))
        for i in self.last_x:
            self.kept_reference_x[i], self.kept_last_x[i] = self.reference_x[i], self.last_x[i]
        self.kept_committed[None] = self.committed[None]

    @ti.kernel
    def roll_back(self):
        """The rows of the last ``back_up`` put back, the list rebuilt from them at the next
        ``update``."""
        for owner in self.found_count:
            self._copy_row(owner, ti.static(self.kept_rows), ti.static(self.rows))
        for i in self.last_x:
            self.reference_x[i], self.last_x[i] = self.kept_reference_x[i], self.kept_last_x[i]
        self.committed[None] = self.kept_committed[None]
        self.rebuild_asked[None] = 1

    @ti.kernel
    def forget(self):
        """Every record dropped (the positions were set from outside), the list rebuilt at the
        next ``update``."""
        for owner in self.found_count:
            self.found_count[owner] = 0
        self.committed[None] = 0
        self.rebuild_asked[None] = 1
