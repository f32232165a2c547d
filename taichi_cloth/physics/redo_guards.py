"""The redo guards: a frame redone from its start at half the step while it tunnelled, stretched
or sank in past the scene's limits, and the best of its tries kept (docs/physics.md,
"Self-collision": "Tunnelling", the strain and penetration guards, "The best try kept")."""

import math

from taichi_cloth.physics.integrators.conjugate_gradient import SolverBreakdown
from taichi_cloth.physics.metrics import RunRecord

REDO_HALVINGS = 3  # a frame that overstretched or sank in is redone at dt/2, dt/4, then dt/8
TUNNELLING_HALVINGS = 6  # a frame that tunnelled: down to dt/64 while it still does (a layer
# must not cross the band in a step: 0.5 mm at 4 m/s is 1/8,000 s, `twirl`'s 1/240 s over 33)
REDO_GAIN = 0.9  # a halving that leaves the strain (or depth) within this factor of the try
# before, either way, shows one the step does not make (a tight garment): not halved again
RUBBER_STRAIN = 0.10  # a frame stretched past it looks like rubber, not cloth (Provot 1995):
# the strain guard halves it on to dt/64 (``TUNNELLING_HALVINGS``), not only to dt/8


class RedoGuards:
    """``Simulation``'s frames refined by its guards (mixed in: it keeps the simulation's
    ``_crossings`` and ``_measured``, reads its ``guards_crossings``, ``redo_limits``,
    ``effects``, ``intersections`` and ``time_step``, and calls its ``advance_frame``,
    ``_end_state``, ``_roll_back``, ``set_time_step``, ``_follow_redo``, ``surface_depth``,
    ``snapshot`` and ``restore``)."""

    def _advance_refining(self, frame: int, record: RunRecord, still: bool):
        """``frame`` from the backed-up state, refined: (problem or None, x, v, crossing pairs
        or None, the halvings of each guard, x's largest stretch strain or None, its surface
        samples' depths or None) of the try kept. A frame is redone at half the step while it
        ends
        - with more pairs of triangles through each other than it began with, even after the
          effects' ``repair`` (self-collision declared): down to dt/64
          (``TUNNELLING_HALVINGS``: a layer that crosses the band in one step tunnels), each
          such halving also stiffening the effects for the redo (``follow_redo``: a penalty
          too weak for the closing speed tunnels at any step);
        - with a larger max strain than ``simulation.redo_strain``, or a surface sample deeper
          inside a collider than ``simulation.redo_penetration`` (each when set), unless it is
          the garment's, not the step's (``_held_by_garment``: a frame that began past the
          limit, a halving that left it within ``REDO_GAIN`` of the try before, either way,
          and no further than 1/``REDO_GAIN`` of the frame's start): down to dt/8
          (``REDO_HALVINGS``; a frame still stretched past ``RUBBER_STRAIN`` down to dt/64),
          or as many halvings past the tunnelling guard's in a frame that tunnelled (at most
          dt/64: a fold that crossing-free smaller steps pushed apart hard, stretching the
          cloth 15 %, is redone smaller still).
        The try kept is the best (``_shortfall``): the last, unless an earlier one was better
        (a smaller step made the frame worse: a fold that met at another moment, harder) or the
        last broke down or blew up, whose end, kept as a snapshot with what the integrator and
        the effects carry, is put back exactly (``Simulation.restore``): only a frame whose
        first try fails is the frame guard's to redo at half the run's step. The step goes back
        to the run's afterwards: a frame that a smaller step cannot mend costs that frame, not
        the run."""
        dt, substeps = self.time_step.dt, self.time_step.substeps_per_frame
        depth = None
        refines = self.guards_crossings or bool(self.redo_limits)
        before = dict.fromkeys(self.redo_limits, math.inf)
        halved = dict.fromkeys(["tunnelling", *self.redo_limits], 0)
        kept = halved  # each guard's halvings at the try kept
        best = None  # (shortfall, snapshot, what was measured) of the best try before the last
        for halvings in range(max(TUNNELLING_HALVINGS, REDO_HALVINGS) + 1 if refines else 1):
            if halvings:
                self._roll_back()
                self.set_time_step(dt / 2 ** halvings, substeps * 2 ** halvings)
                self._follow_redo(halved["tunnelling"])
            problem, x, v, strain, crossings = self._try_frame(frame, record, still)
            if problem is not None or not refines:
                break
            measured, depth = self._guard_measures(x, strain)
            shortfall = self._shortfall(crossings, measured)
            kept = dict(halved)
            tunnelled = self.guards_crossings and crossings > self._crossings \
                and halvings < TUNNELLING_HALVINGS
            deepest = min(halved["tunnelling"] + REDO_HALVINGS, TUNNELLING_HALVINGS)
            exceeded = [name for name, limit in self.redo_limits.items()
                        if limit < measured[name] and not self._held_by_garment(
                            name, limit, measured[name], before[name])
                        and halvings < (TUNNELLING_HALVINGS if name == "strain"
                                        and measured[name] > RUBBER_STRAIN else deepest)]
            before = {name: measured[name] for name in self.redo_limits}
            if not (tunnelled or exceeded):
                break
            if best is None or shortfall < best[0]:  # (a later try may do worse)
                best = (shortfall, self.snapshot(effects=True),
                        (x, v, strain, crossings, depth, kept, measured))
            halved["tunnelling"] += tunnelled
            for name in exceeded:
                halved[name] += 1
        if best is not None and (problem is not None or best[0] < shortfall):
            self.restore(best[1])  # (a smaller step that broke down or blew up: the best before)
            problem, (x, v, strain, crossings, depth, kept, measured) = None, best[2]
        if problem is None:  # what the next frame's tries are compared with
            self._crossings = crossings
            if refines:
                self._measured = measured
        self.set_time_step(dt, substeps)
        if halved["tunnelling"]:
            self._follow_redo(0)
        return problem, x, v, crossings, kept, strain, depth

    def _try_frame(self, frame: int, record: RunRecord, still: bool):
        """One try at ``frame`` at the step set: (problem or None, x [m], v [m/s], x's largest
        stretch strain or None, crossing pairs or None: counted when self-collision is
        declared), the effects' own mend (``repair``) made first when it ends with more
        crossing pairs than the frame began with."""
        try:
            self.advance_frame(frame, record, still)
        except SolverBreakdown as breakdown:
            return f"could not be solved for ({breakdown})", None, None, None, None
        x, v, strain, problem = self._end_state()
        crossings = None
        if problem is None and self.guards_crossings:
            crossings = self.intersections.count(x)
            if crossings > self._crossings:
                for effect in self.effects:
                    effect.repair(self.state_in)
                x, v, strain, problem = self._end_state()
                if problem is None:  # (else unusable: ``guarded_frame`` retries)
                    crossings = self.intersections.count(x)
        return problem, x, v, strain, crossings

    def _guard_measures(self, x, strain: float) -> tuple[dict, object]:
        """(the redo guards' measures of positions x [m] with largest stretch strain
        ``strain``: the strain and, with the penetration guard, the surface's deepest point in
        a collider [m]; the surface samples' depths, or None without that guard)."""
        measured, depth = {"strain": strain}, None
        if "penetration" in self.redo_limits:
            depth = self.surface_depth(x)
            measured["penetration"] = float(depth.max(initial=0.0))
        return measured, depth

    def _measure_start(self) -> None:
        """What the guards compare a frame's tries with, of the state it starts from, when not
        known (the first frame, a restored snapshot; else the kept try's, from the frame
        before): its crossing pairs (``_shortfall``) and the guards' measures
        (``_held_by_garment``)."""
        crossings_unknown = self.guards_crossings and self._crossings is None
        measures_unknown = self.redo_limits and self._measured is None
        if crossings_unknown or measures_unknown:  # (one host copy of the state)
            x, _, strain, _ = self._end_state()
            if crossings_unknown:
                self._crossings = self.intersections.count(x)
            if measures_unknown:
                self._measured = self._guard_measures(x, strain)[0]

    def _held_by_garment(self, name: str, limit: float, measure: float, before: float) -> bool:
        """Whether a try's ``measure`` past the guard's ``limit`` (``before``: the try's before
        it, inf for the first) is one the garment holds (a tight waist), which no smaller step
        mends: the frame began past the limit, and the try is within ``REDO_GAIN`` of the one
        before, either way, and no further than that past the frame's start. A frame that began
        within the limit and ends past it met something within the frame, as does one that ends
        far past its start (`twirl` at tempo 360, frame 22: 3.9 % at its start, 13 % at dt and
        at dt/2); a smaller step may meet it more gently."""
        start = self._measured[name]
        return (limit < start and REDO_GAIN * before <= measure <= before / REDO_GAIN
                and measure <= start / REDO_GAIN)

    def _shortfall(self, crossings: int | None, measured: dict) -> tuple[int, float]:
        """How far a try falls short of its guards, the smaller the better: (its crossing pairs
        beyond the frame's start, 0 when not counted; the largest ratio of a measure to its
        limit, 1 for a try within all of them)."""
        excess = 0 if crossings is None else max(crossings - self._crossings, 0)
        worst = max([measured[name] / limit for name, limit in self.redo_limits.items()],
                    default=1.0)
        return excess, max(worst, 1.0)
