"""The side records of self-collision's candidate pairs (``effects/crossing_history.py``), kept
beside the finds of ``candidate_pairs.CandidatePairs``, which mixes this class in: each walk's
row of finds has a row of records; a rebuild carries a record over to the same pair found
again, gives a new pair the record it had at the last finished step (``committed_x``), and keeps
a pair that has crossed in the list, however far apart it has gone, until it is back on its
side; ``commit`` brings the list and the records to the end of every step; ``back_up`` and
``roll_back`` keep them with the state that a redone frame goes back to (docs/physics.md,
"Self-collision").

The host class provides ``model``, ``found``/``found_count`` (the walks' rows), ``pair_count``,
``pair_kind``, ``pair_particles``, ``pair_slot`` (each pair's find), ``_find``, ``_pair_of``,
``update`` and ``rebuild_asked``.
"""

import taichi as ti

from taichi_cloth.effects import crossing_history
from taichi_cloth.effects.proximity import pair_side


@ti.data_oriented
class PairRecords:
    """Side records of a candidate list (module docstring)."""

    def allocate_records(self) -> None:
        """The records beside the finds of ``found``, the rows before a rebuild (carried over)
        and at a redone frame's start (``back_up``), and the positions of the last finished
        step [m] (``commit``) with whether there was one."""
        rows, row_count = self.found.shape, self.found_count.shape
        self.found_record = ti.field(ti.i32, rows)
        self.previous_found, self.kept_found = (ti.field(ti.i32, rows) for _ in range(2))
        self.previous_record, self.kept_record = (ti.field(ti.i32, rows) for _ in range(2))
        self.previous_count, self.kept_count = (ti.field(ti.i32, row_count) for _ in range(2))
        particles, real = self.model.particle_count, self.model.real
        self.committed_x, self.kept_committed_x = (ti.Vector.field(3, real, particles)
                                                   for _ in range(2))
        self.committed, self.kept_committed = ti.field(ti.i32, ()), ti.field(ti.i32, ())

    @ti.func
    def _start_row(self, owner):
        """Walk ``owner``'s row moved to ``previous_*`` (its records to carry over), emptied."""
        self.previous_count[owner] = self.found_count[owner]
        for n in range(self.found_count[owner]):
            self.previous_found[owner, n] = self.found[owner, n]
            self.previous_record[owner, n] = self.found_record[owner, n]
        self.found_count[owner] = 0

    @ti.func
    def _carried_record(self, owner, other):
        """The side record of the pair that walk ``owner`` finds as item ``other``: the one it
        held before this rebuild, or for a new pair the one it would have had at the last
        finished step (``committed_x``; ``crossing_history.UNKNOWN`` before the first)."""
        record = crossing_history.UNKNOWN
        held = 0
        for n in range(self.previous_count[owner]):
            if self.previous_found[owner, n] == other:
                record = self.previous_record[owner, n]
                held = 1
        if not held and self.committed[None]:
            kind, ids = self._pair_of(owner, other)
            _share, inside, _normal, height, _offset = pair_side(self.committed_x, kind, ids,
                                                                   self.model.real)
            record = crossing_history.commit(crossing_history.UNKNOWN, inside, height)
        return record

    @ti.func
    def _keep_crossed(self, owner):
        """The pairs of walk ``owner``'s previous row that have crossed and that the walk did not
        find again (gone beyond the reach), appended with their records."""
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
    def record(self, k):
        """Pair k's side record (``crossing_history``)."""
        slot = self.pair_slot[k]
        return self.found_record[slot // ti.static(self.found.shape[1]), slot % ti.static(self.found.shape[1])]

    @ti.func
    def set_record(self, k, record):
        slot = self.pair_slot[k]
        self.found_record[slot // ti.static(self.found.shape[1]), slot % ti.static(self.found.shape[1])] = record

    @ti.func
    def side(self, x, k):
        """Pair k at positions x: ``proximity.pair_side`` of its kind and particles."""
        return pair_side(x, self.pair_kind[k], self.pair_particles[k], self.model.real)

    @ti.func
    def commit(self, x, serial: ti.template()):
        """The positions x [m] of a finished step: the list brought up to date there
        (``update``: a pair near at the step's end is listed, a new one with its record at the
        step's start), every listed pair's side record brought to x
        (``crossing_history.commit``), and x kept as ``committed_x``; on one thread when
        ``serial``."""
        self.update(x)
        if ti.static(serial):
            ti.loop_config(serialize=True)
        for k in range(self.pair_count[None]):
            _share, inside, _normal, height, _offset = self.side(x, k)
            self.set_record(k, crossing_history.commit(self.record(k), inside, height))
        if ti.static(serial):
            ti.loop_config(serialize=True)
        for i in range(self.model.particle_count):
            self.committed_x[i] = x[i]
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
            self.kept_count[owner] = self.found_count[owner]
            for n in range(self.found_count[owner]):
                self.kept_found[owner, n] = self.found[owner, n]
                self.kept_record[owner, n] = self.found_record[owner, n]
        for i in self.committed_x:
            self.kept_committed_x[i] = self.committed_x[i]
        self.kept_committed[None] = self.committed[None]

    @ti.kernel
    def roll_back(self):
        """The rows of the last ``back_up`` put back, the list rebuilt from them at the next
        ``update``."""
        for owner in self.found_count:
            self.found_count[owner] = self.kept_count[owner]
            for n in range(self.kept_count[owner]):
                self.found[owner, n] = self.kept_found[owner, n]
                self.found_record[owner, n] = self.kept_record[owner, n]
        for i in self.committed_x:
            self.committed_x[i] = self.kept_committed_x[i]
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
