"""Self-collision: the cloth repels itself where two of its parts come closer than ``thickness``
(docs/physics.md, "Self-collision").

Proximity, as in Bridson, Fedkiw & Anderson (2002, "Robust treatment of collisions, contact and
friction for cloth animation"), between every vertex and every triangle it is not a corner of,
and between every two edges that share no vertex. A pair at distance d < thickness along the unit
normal n between its closest points gets the penalty force of ``penalty`` (the law of body
contact: m·(k̂·(thickness − d) − 2ζ·√k̂·(u·n)), never pulling, and regularised Coulomb friction
on the relative slip u):

- vertex p and triangle t with closest point c = Σ w_k·x_k (barycentric, clamped to the
  triangle; Ericson 2005, "Real-Time Collision Detection", §5.1.5): F on p with p's mass, −w_k·F
  on each corner k;
- edges (a, b) and (c, d) with closest points P = a + s·(b − a), Q = c + u·(d − c) (Ericson
  §5.1.9): F on the first with the mean mass of the four particles, (1 − s)·F on a and s·F on b;
  −F shared the same way by the second.

The elastic part is −∇ of the energy ½·m·k̂·(thickness − d)² (the closest points move
tangentially to first order), so momentum is conserved and the energy balance holds.

A pair remembers which side of each other its primitives belong on (``crossing_history``): while
its closest points stay inside (over the face; within both edges) d is signed, so a pair that
has passed through itself is pushed back, not further through; and after every step
(``apply``, the post step) a pair that crossed within it is put back on its side, without
stretching the springs past their length before (``unstretch``), only where edges pierce faces
around it (a record that no crossing witnesses gives way, also after the step's other
put-backs) and the move leaves fewer. For the records, inside is within a thickness of it.

Candidate pairs (``effects/candidate_pairs.py``): every pair within the reach, thickness +
padding, in one list, less those in flat stretches, which hold no layers (``mesh_patches.py``),
rebuilt when the cloth has deformed (its best rigid motion taken out) by half the padding.

Gathered, no atomics on forces: each pair's force (and blocks) is computed once per evaluation,
with each of its four particles' share weight; a particle sums its entries' shares in list
order, so a run is bit-reproducible. The CPU only (``config.scene`` refuses a GPU arch: on CUDA
these kernels did not finish compiling in 7 minutes); its loops run on one thread (a second
costs more than it gains at these sizes). Implicit integrator: per-particle blocks of each pair
(w²-weighted), the couplings between a pair's particles left out; tunnelling, the thickness
bound, the stable step and the cost: docs/physics.md. The default stiffness and the stiffest
mode's contacts: ``effects/self_collision_stiffness.py``.
"""

from dataclasses import dataclass

import numpy as np
import taichi as ti

from taichi_cloth.effects import crossing_history
from taichi_cloth.effects.base import Effect, EffectContext
from taichi_cloth.effects.candidate_pairs import CandidatePairs
from taichi_cloth.effects.penalty import ContactMode, normal_force_magnitude, penalty_terms
from taichi_cloth.effects.piercing import intersections_around
from taichi_cloth.effects.proximity import VERTEX_TRIANGLE, inside_within, pair_geometry
from taichi_cloth.effects.self_collision_stiffness import (
    default_stiffness, fitted_stiffness, redo_stiffness, vertex_on_vertex_contacts)
from taichi_cloth.effects.unstretch import unstretch
from taichi_cloth.errors import InputError
from taichi_cloth.settings import setting

PADDING = 1.0  # the list's padding in thicknesses: rebuilt after half of it is deformed
SEPARATION = 0.25  # a crossed pair is put back this fraction of the thickness apart
SEPARATION_SWEEPS = 4  # sweeps of the list that put crossed pairs back, at most, each step
PATH_POINTS = 4  # points of a step's straight path where each pair's side record is brought up
# to date (``_sweep_pair``): 1/4, 1/2, 3/4 and the end (the others only for a pair inside at it)


@dataclass(frozen=True)
class SelfCollisionSettings:
    thickness: float = setting(0.004, "float", low=0.0, low_inclusive=False,
                               doc="distance the cloth keeps from itself, m")
    stiffness: float | None = setting(None, "float", low=0.0, low_inclusive=False,
                                      doc="penalty stiffness per unit particle mass, 1/s²: "
                                          "layers meeting faster than thickness·√stiffness pass "
                                          "through; unset, (4 m/s / thickness)²: 4 m/s "
                                          "(less where the step is too long for it: "
                                          "``effects.self_collision_stiffness``)")
    damping: float = setting(0.5, "float", low=0.0, doc="normal damping ratio ζ")
    friction: float = setting(0.3, "float", low=0.0, doc="Coulomb coefficient μ")


@ti.data_oriented
class SelfCollision(Effect):
    """Penalty repulsion between the cloth's own vertices and triangles and between its edges
    (module docstring)."""

    name = "self_collision"
    Settings = SelfCollisionSettings
    has_jacobian = True
    arranges_own_passes = prepares_on_one_thread = True  # its build and sweeps on one thread
    bounds_given_step = True  # a given explicit step split for the penalty (docs/physics.md)

    def __init__(self, settings: SelfCollisionSettings, context: EffectContext):
        super().__init__(settings, context)
        model = self.model = context.model
        garment = model.garment
        self.blocks = context.needs_jacobian  # the implicit solver's blocks, else none
        real = model.real
        rest = np.linalg.norm(np.diff(garment.positions[garment.edges], axis=1), axis=2)
        median = float(np.median(rest)) if rest.size else np.inf  # (closer pairs: left out)
        if settings.thickness >= 0.5 * median:
            raise InputError(f"effects.self_collision.thickness: {settings.thickness:g} m must be "
                             f"below {0.5 * median:g} m, half the cloth's median edge "
                             f"({median:g} m)")
        self.thickness, self.stiffness = settings.thickness, settings.stiffness  # m, 1/s²
        self.stiffness_given = self.stiffness is not None
        if not self.stiffness_given:
            self.stiffness = default_stiffness(self.thickness)
        self.damping_ratio, self.friction = settings.damping, settings.friction
        self.stiffness_now = ti.field(real, ())  # 1/s², the run's or a redone frame's
        self.padding = PADDING * settings.thickness  # m: the list holds pairs within reach
        self.pairs = CandidatePairs(model, settings.thickness, self.padding)
        self.reach = self.pairs.reach  # m: thickness + padding
        self.post_step = self  # ``apply``: the side records after every step
        self.moved = ti.field(ti.i32, ())  # pairs a sweep of ``apply`` put back
        self.separations = ti.field(ti.i32, ())  # pairs put back since the start
        self.refusals = ti.field(ti.i32, ())  # put-backs not made since the start (``_sweep_pair``)
        # put back with a redone frame: a run counts what its kept steps did (``back_up``)
        self._counts = (self.separations, self.refusals, self.pairs.rebuilds, self.pairs.overflow)
        # per post step: the positions before its sweeps [m], whether a sweep moved a particle
        self.unswept_x = ti.Vector.field(3, real, model.particle_count)
        self.lifted = ti.field(ti.i32, model.particle_count)
        capacity = self.pairs.capacity
        # per evaluation: each pair's force on its first point, its blocks, its particles' shares
        self.pair_force = ti.Vector.field(3, real, capacity)
        self.pair_share = ti.Vector.field(4, real, capacity)
        if self.blocks:
            self.pair_stiffness = ti.Matrix.field(3, 3, real, capacity)
            self.pair_damping = ti.Matrix.field(3, 3, real, capacity)

    def upload(self) -> None:
        self.model.uploads.add([(self.stiffness_now, np.array(self.stiffness))])
        self.pairs.upload()

    def follow_redo(self, halvings: int) -> None:
        """A frame the tunnelling guard redoes at the run's step over 2^``halvings``: 4^halvings
        × the run's stiffness (``redo_stiffness``: thickness·√k̂ stopped doubles); 0: the run's."""
        self.stiffness_now[None] = redo_stiffness(self.stiffness, halvings)

    @ti.func
    def prepare(self, x, v, t):
        """The candidate list brought up to date (``CandidatePairs.update``), then every listed
        pair's force and blocks."""
        self.pairs.update(x)
        ti.loop_config(serialize=True)
        for k in range(self.pairs.pair_count[None]):
            self._evaluate(x, v, k)

    @ti.func
    def _evaluate(self, x, v, k):
        """Pair k's force on its first point, its blocks and its particles' shares (the share
        of a corner or end: its weight, negative on the second primitive), with the pair's side
        record (``crossing_history.oriented``)."""
        real = self.model.real
        ids = self.pairs.pair_particles[k]
        share, inside, normal, height, offset = self.pairs.side(x, k)
        direction, distance = crossing_history.oriented(self.pairs.record(k), inside, normal,
                                                        height, offset, real)
        relative_velocity = ti.Vector.zero(real, 3)
        for slot in ti.static(range(4)):
            relative_velocity += share[slot] * v[ids[slot]]
        mass = ti.static(self.model.particle_mass)
        pair_mass = mass[ids[0]]  # a vertex's own; two edges: their four particles' mean
        if self.pairs.pair_kind[k] != VERTEX_TRIANGLE:
            pair_mass = 0.25 * (mass[ids[0]] + mass[ids[1]] + mass[ids[2]] + mass[ids[3]])
        force, stiffness, damping = self._pair(pair_mass, direction, distance, relative_velocity)
        self.pair_force[k] = force
        self.pair_share[k] = share
        if ti.static(self.blocks):
            self.pair_stiffness[k] = stiffness
            self.pair_damping[k] = damping

    @ti.func
    def _pair(self, mass, normal, distance, relative_velocity):
        """The penalty between two points ``distance`` apart [m] along the unit ``normal`` (from
        the second to the first; negative: the first has crossed to the second's other side,
        ``crossing_history.oriented``) with that relative velocity, for ``mass`` [kg]: (force
        on the first [N], its stiffness block −m·k̂·n·nᵀ and damping block), all zero beyond the
        thickness, for a zero normal, or when the normal force is clamped to 0 (leaving fast:
        its blocks would make release sticky)."""
        real = self.model.real
        depth = real(self.thickness) - distance
        k_hat, zeta, mu = self.stiffness_now[None], real(self.damping_ratio), real(self.friction)
        active = normal.norm_sqr() > 0 and depth > 0 and normal_force_magnitude(
            mass, depth, relative_velocity.dot(normal), k_hat, zeta) > 0
        force = ti.Vector.zero(real, 3)
        stiffness = ti.Matrix.zero(real, 3, 3)
        damping = ti.Matrix.zero(real, 3, 3)
        if active:
            pushed, normal_magnitude, damped = penalty_terms(mass, depth, normal,
                                                             relative_velocity, k_hat, zeta, mu,
                                                             real)
            force = pushed
            if ti.static(self.blocks):
                stiffness = -mass * k_hat * normal.outer_product(normal)
                damping = damped
        return force, stiffness, damping

    @ti.func
    def apply(self, state, t):
        """After every step (``post_step``): one sweep over the list that brings each pair's
        side record to the step's end and puts back the pairs that crossed within it, then up
        to ``SEPARATION_SWEEPS`` − 1 more of the pairs inside and on the wrong side of their
        records while the sweep before moved any (putting one pair back can push a neighbour
        through: two diagonals of a tight fold take turns otherwise), each pair in turn
        (``_sweep_pair``); then a last pass that moves nothing: a pair still crossed whose
        crossing nothing witnesses any more (the sweep found edges through faces around it and
        left it, and other pairs' moves took them out) takes the side it is on, so that its
        penalty does not push it through a face it is clear of; then the positions kept as the
        records' (``keep_positions``). On one thread in list order (Gauss–Seidel,
        bit-reproducible). Before each sweep after the first, the stretch springs that the
        sweeps have stretched are shortened again (``unstretch``), so the last word is the
        sides'."""
        ti.loop_config(serialize=True)
        for i in range(self.model.particle_count):
            self.unswept_x[i] = state.x[i]
            self.lifted[i] = 0
        ti.loop_config(serialize=True)
        for sweep in range(SEPARATION_SWEEPS + 1):
            releasing = sweep == SEPARATION_SWEEPS
            if sweep == 0 or releasing or self.moved[None] > 0:
                if sweep > 0 and not releasing:
                    unstretch(self.model, state, self.unswept_x, self.lifted)
                self.moved[None] = 0
                for k in range(self.pairs.pair_count[None]):
                    self._sweep_pair(state, k, sweep == 0, releasing)
        self.pairs.keep_positions(state.x)

    @ti.func
    def _sweep_pair(self, state, k, first, releasing):
        """Pair k in a sweep of ``apply``: in the ``first``, its record committed
        (``commit_record``) at ``PATH_POINTS`` points of the step's straight path from the last
        step's end (``last_x``; the particles of an Euler or backward Euler step move on straight
        lines, RK4's nearly) to the positions, the last point exactly them: a pair that crossed
        on the way stays crossed if it is inside on the wrong side at the end (not if it went on
        past the edge: there the face's neighbour sees the crossing, or the edge is the cloth's
        border or a crease, round which it may go); then, if it has crossed (its record says so,
        or it is inside with the other sign of height than its record's, σ·h < 0), moved back
        onto its side (``SEPARATION`` of the thickness: the penalty, oriented by the record, does
        the rest over the next steps without a jump that stretches the cloth), and its approach
        along the normal stopped: the inelastic projection of Bridson, Fedkiw & Anderson (2002,
        §7.1) on the constraint C = σ·n·Σ_i b_i·x_i − SEPARATION·thickness (b the pair's shares,
        σ·n the normal of its side): x_i += λ·b_i·w_i·σn with λ = −C / Σ_i b_i²·w_i (w the
        inverse masses; pinned particles do not move), and the same for the velocities when
        Σ_i b_i·v_i·σn < 0. Momentum is kept (Σ b_i = 0); the pair's record is back on its side;
        ``moved`` counts it. Only where edges pierce faces around the pair
        (``piercing.intersections_around``): with none, no crossing witnesses the record (a hem
        gone round another layer's border between two points of the path, or past its edge
        within a thickness) and it takes the side the pair is on, nothing moved; and not where
        the move leaves as many or more (it mends nothing there, only trades one piercing for
        another): the particles then stay where they were and the record stays, the penalty
        pushing the pair its way (``refusals`` counts both). Inside, for the records, is
        within a thickness of it (``proximity.inside_within``: a vertex passing a face's corner
        or edge closer than that, where every pair around it is at its border, is seen by
        one). In the last pass (``releasing``) only a crossed pair is looked at, and nothing
        moves: with no edges through faces around it, its record takes the side it is on."""
        real = self.model.real
        inverse_mass = ti.static(self.model.particle_inv_mass)
        record = self.pairs.record(k)
        if (first or ti.abs(record) == crossing_history.INSIDE) and not releasing or (
                releasing and crossing_history.is_crossed(record)):
            ids = self.pairs.pair_particles[k]
            kind = self.pairs.pair_kind[k]
            share, inside, normal = ti.Vector.zero(real, 4), 0, ti.Vector.zero(real, 3)
            height = real(0.0)
            # The step's end, then (first sweep, a pair inside at the end: outside, the path
            # cannot change the record) the points on its path from the last commit
            # (``last_x``) in order; one inlined copy of the geometry serves all.
            rounds = 1
            if first and self.pairs.committed[None]:
                rounds = PATH_POINTS
            for round_ in range(rounds):
                if round_ == 0 or inside:
                    along = ti.cast(round_, real) * real(1.0 / PATH_POINTS)
                    last = [self.pairs.last_x[ids[slot]] for slot in ti.static(range(4))]
                    at = [ti.select(round_ > 0,
                                    last[slot] + along * (state.x[ids[slot]] - last[slot]),
                                    state.x[ids[slot]]) for slot in ti.static(range(4))]
                    on_share, _inside, on_normal, on_height, on_offset = pair_geometry(
                        kind, at[0], at[1], at[2], at[3], real)
                    on_inside = inside_within(on_normal, on_height, on_offset,
                                              real(self.thickness))
                    if round_ == 0:
                        share, inside, normal, height = on_share, on_inside, on_normal, on_height
                    elif not crossing_history.is_crossed(record):
                        record = self.pairs.commit_record(k, on_inside, on_height)
            if first:
                record = self.pairs.commit_record(k, inside, height)
            side = real(1.0) if record > 0 else real(-1.0)
            if crossing_history.is_crossed(record) or (
                    ti.abs(record) == crossing_history.INSIDE and inside and side * height < 0):
                weight = real(0.0)
                approach = real(0.0)
                for slot in ti.static(range(4)):
                    weight += share[slot] ** 2 * inverse_mass[ids[slot]]
                    approach += share[slot] * state.v[ids[slot]].dot(side * normal)
                if weight > 0 and normal.norm_sqr() > 0:
                    lift = (real(SEPARATION * self.thickness) - side * height) / weight
                    stop = ti.max(-approach, 0.0) / weight
                    unmoved = [state.x[ids[slot]] for slot in ti.static(range(4))]
                    moves = [share[slot] * inverse_mass[ids[slot]] * side * normal
                             for slot in ti.static(range(4))]
                    first_slots = 1 if kind == VERTEX_TRIANGLE else 2
                    # the edges through faces around the pair before and after the move (one
                    # inlined piercing test for both; before only, in the last pass)
                    meeting = 0
                    refused = 0
                    for round_ in range(2):
                        if round_ == 0 or (meeting > 0 and not releasing):
                            count = intersections_around(self.model, state.x, ids, first_slots)
                            if round_ == 0:
                                meeting = count
                                if meeting > 0 and not releasing:
                                    for slot in ti.static(range(4)):
                                        state.x[ids[slot]] += lift * moves[slot]
                            elif count >= meeting:
                                refused = 1
                    if refused:
                        for slot in ti.static(range(4)):
                            state.x[ids[slot]] = unmoved[slot]
                    if releasing or refused or meeting == 0:
                        self.refusals[None] += int(not releasing)
                        if meeting == 0:  # nothing witnesses the record: it gives way
                            self.pairs.set_record(k, crossing_history.record_from_here(
                                inside, height))
                    else:
                        for slot in ti.static(range(4)):
                            state.v[ids[slot]] += stop * moves[slot]
                            self.lifted[ids[slot]] = 1
                        self.pairs.set_record(k, int(side) * crossing_history.INSIDE)
                        self.moved[None] += 1
                        self.separations[None] += 1

    @ti.func
    def force(self, model, x, v, i_p, t):
        """The particle's shares of its pairs' forces, gathered in list order."""
        f = ti.Vector.zero(model.real, 3)
        entries = self.pairs
        for k in range(entries.entry_start[i_p], entries.entry_start[i_p + 1]):
            pair, slot = entries.entry[k] // 4, entries.entry[k] % 4
            f += self.pair_share[pair][slot] * self.pair_force[pair]
        return f

    @ti.func
    def local_jacobian(self, model, x, v, i_p, t, definite: ti.template()):
        """(∂f/∂x, ∂f/∂v) of particle i_p: its shares² of its pairs' blocks from the last
        ``prepare`` (the couplings between a pair's particles left out: module docstring)."""
        stiffness = ti.Matrix.zero(model.real, 3, 3)
        damping = ti.Matrix.zero(model.real, 3, 3)
        if ti.static(self.blocks):
            entries = self.pairs
            for k in range(entries.entry_start[i_p], entries.entry_start[i_p + 1]):
                pair, slot = entries.entry[k] // 4, entries.entry[k] % 4
                weight = self.pair_share[pair][slot] ** 2
                stiffness += weight * self.pair_stiffness[pair]
                damping += weight * self.pair_damping[pair]
        return stiffness, damping

    def back_up(self) -> None:
        self.pairs.back_up()
        self._kept_counts = [count[None] for count in self._counts]

    def roll_back(self) -> None:
        self.pairs.roll_back()
        for count, kept in zip(self._counts, self._kept_counts):
            count[None] = kept

    def forget_history(self) -> None:
        self.pairs.forget()

    def memory(self) -> dict:
        return {**self.pairs.memory(), "separations": self.separations.to_numpy(),
                "refusals": self.refusals.to_numpy()}

    def restore_memory(self, memory: dict) -> None:
        self.pairs.restore_memory(memory)
        self.separations.from_numpy(memory["separations"])
        self.refusals[None] = int(memory.get("refusals", 0))  # (older checkpoints: none)

    def repair(self, state) -> None:
        """A frame's end with pairs of triangles through each other: the list brought up to
        date there (a build if the cloth has deformed past it, its new pairs with their records
        at ``reference_x``), then the post step again (``apply``): a pair that came from beyond
        the reach through a face in the frame's last step is put back."""
        self._repair(state)

    @ti.kernel
    def _repair(self, state: ti.template()):
        self.pairs.update(state.x)
        self.apply(state, 0.0)

    def frame_metrics(self, x: np.ndarray, potential: float) -> dict:
        """Candidate pairs dropped since the start (0 unless the capacities of
        ``candidate_pairs`` are too small for the scene: then contacts can be missed), the list's
        builds since the start, its pairs at the last build, the pairs put back onto their sides
        since the start (``_sweep_pair``), the put-backs not made since the start (no crossing
        witnessed them, or they would not have mended it), and the listed pairs whose records say
        they are crossed at the frame's end (0 unless a witnessed crossing could not be put
        back: the move would mend nothing, or every particle of the pair is pinned)."""
        return {"self_collision_overflow": int(self.pairs.overflow[None]),
                "self_collision_builds": int(self.pairs.rebuilds[None]),
                "self_collision_pairs": int(self.pairs.pair_count[None]),
                "self_collision_separations": int(self.separations[None]),
                "self_collision_refusals": int(self.refusals[None]),
                "self_collision_crossed": self.pairs.crossed_count()}

    def fit_time_step(self, time_step, integrator: str) -> bool:
        """The default stiffness (none given) fitted to the run's ``TimeStep`` once chosen
        (``fitted_stiffness``); whether it changed."""
        chosen = self.stiffness
        if not self.stiffness_given:
            self.stiffness = fitted_stiffness(chosen, time_step.dt, integrator,
                                              time_step.requested)
        return self.stiffness != chosen

    def stability_modes(self) -> list[ContactMode]:
        """Two vertices resting on each other, every pair around them pushing their relative
        coordinate (``vertex_on_vertex_contacts``; docs/physics.md, "Self-collision")."""
        garment = self.model.garment
        return [ContactMode(self.stiffness, self.damping_ratio, contacts=vertex_on_vertex_contacts(
            garment.triangles, garment.edges, garment.mass, garment.pinned))]
