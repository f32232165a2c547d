"""Explicit Euler and symplectic ("FB") Euler (seed §2.5.1 and §2.5.2).

Both take one force evaluation per step, a = M⁻¹ F(x_n, v_n, t_n), and differ only in which
velocity moves the positions:

    explicit Euler:   x_{n+1} = x_n + h·v_n,       v_{n+1} = v_n + h·a
    symplectic Euler: v_{n+1} = v_n + h·a,         x_{n+1} = x_n + h·v_{n+1}

(the seed's §2.5.2 listing prints v(t) in the position update, but its text says the position
uses the *future* velocity: that is the symplectic method implemented here; cf. PositionBasedDynamics
``TimeIntegration.h``). A step reads only ``state_in`` and writes only ``state_out``, so the
force gather and the update fuse into one loop over the particles. Pinned particles (inverse mass
0) take their pin target at t + h.

A substep takes one of three paths, chosen at compile time:

- gather: ``Forces.prepare`` then one loop over the particles, each gathering its springs through
  the CSR lists (any cloth);
- packed (with a projection after each substep, ``post_step``, which moves particles in the
  unpacked state): on a packed grid (``forces.packed``, ``physics.packed_grid``) the state
  packed and the damped stencils' x + β·v, then row by row in blocks of rows the forward pass
  (each spring's force once, the faces of its face effects: ``PackedGrid.each_group``) and for
  each group the SIMD group pass (``physics.packed_pass``), then the update of its particles
  (any effects);
- lanes (a packed grid without a projection): the update too runs in the SIMD lanes
  (``lane_step_function``): the packed state is stepped as whole vectors, pins are set
  afterwards, and x, v are unpacked once at the end of the launch (``end_launch``). The forces
  of the effects that act in the packed pass (bending: ``Effect.allocate_lanes``; drag:
  ``Effect.lane_faces``) are in the pass; gravity is a uniform acceleration of every free lane;
  where any other effect is declared (contact, wind: ``gathers_for_lanes``) each substep first
  unpacks its input state, runs the effects' passes and packs every particle's force of those
  effects into lanes that the update adds. Where each of them lists the particles it acts on
  (``Effect.touched_particles``: contact, ``gathers_listed``) only the positions are unpacked,
  the effects read velocities from the lanes (``PackedParticles``), and only the listed
  particles' lanes are written, then cleared after the step (on `hula` a few dozen of 1,792
  particles: ~7 µs less a substep).
docs/performance.md has what each path costs.
"""

import taichi as ti

from taichi_cloth.physics.integrators.base import Integrator
from taichi_cloth.physics.grid_stencil import SIMD_LANES
from taichi_cloth.physics.packed_grid import PackedParticles
from taichi_cloth.physics.packed_pass import forward_pass_function, group_pass_function


def lane_step_function(forces, uses_new_velocity: bool, gathered_force=None):
    """A ``ti.func`` finishing ``packed_pass.group_pass_function``: step one packed group of lanes
    from packed copy ``buffer`` into the other with its spring forces f: a = M⁻¹·(f + g) + Σ
    uniform accelerations (free lanes only), g the forces of the effects that are not
    (``gathered_force``: (x, y, z) fields of SIMD_LANES-vectors [row, group], made before the
    pass; None where there are none); then v' = v + h·a, x' = x + h·v' (symplectic) or x + h·v
    (explicit), and the damped stencils' y' = x' + β·v' that the next substep's pass reads
    (``PackedGrid.store_damped``: no pass of its own over the state, ~3 µs a substep on
    `hula`). Pinned and halo lanes have inverse mass 0 and coast (``EulerStep`` sets the pins
    afterwards; halo lanes are masked out of the spring pass, or refreshed on a periodic
    grid, or not read at all where the reads wrap round its whole groups)."""
    model = forces.model
    real = model.real
    acceleration = forces.uniform_acceleration
    packed = forces.packed
    packed_x, packed_v, packed_inv_mass = packed.packed_x, packed.packed_v, packed.packed_inv_mass
    gathers = gathered_force is not None

    @ti.func
    def lane_step(buffer, row, group, h, f_x, f_y, f_z):
        inv_mass = packed_inv_mass[row, group]
        free = ti.cast(inv_mass > 0, real)
        force = (f_x, f_y, f_z)
        for c in ti.static(range(3)):
            lane_acceleration = inv_mass * force[c]
            if ti.static(gathers):
                lane_acceleration += inv_mass * gathered_force[c][row, group]
            if ti.static(acceleration[c] != 0.0):
                lane_acceleration += model.real(acceleration[c]) * free
            v = packed_v[c][buffer, row, group]
            v_new = v + h * lane_acceleration
            moving = v
            if ti.static(uses_new_velocity):
                moving = v_new
            x_new = packed_x[c][buffer, row, group] + h * moving
            packed_v[c][1 - buffer, row, group] = v_new
            packed_x[c][1 - buffer, row, group] = x_new
            packed.store_damped(1 - buffer, row, group, c, x_new, v_new)

    return lane_step


@ti.data_oriented
class EulerStep(Integrator):
    """One force evaluation, then one update; ``uses_new_velocity`` picks the variant."""

    uses_new_velocity = False
    packs_springs = True
    substep_batch = 8  # fewer Python launches against longer compiles (docs/performance.md)

    def __init__(self, forces, control, post_step=None):
        super().__init__(forces, control, post_step)
        self.packed = forces.packed
        self.has_packed = forces.has_packed
        # The whole step in SIMD lanes: a packed grid and no projection (which moves particles
        # in the unpacked state). Where a gathered force effect is not a uniform acceleration
        # (contact, wind), the particles gather those effects' forces into packed vectors first
        # (``gathers_for_lanes``).
        self.steps_in_lanes = self.has_packed and not self.has_post_step
        self.gathers_for_lanes = self.steps_in_lanes and bool(forces.pointwise_effects)
        # each of those effects lists the particles it acts on: only theirs are gathered
        self.gathers_listed = self.gathers_for_lanes and forces.pointwise_listed
        self.substeps_write_states = not self.steps_in_lanes
        # 20-40 % faster lanes (runtime.without_taichi_passes); not with face effects, whose
        # real function the force evaluations' kernels share, nor with gathered effects
        # (contact's pass is ~40 % faster with Taichi's passes: docs/performance.md)
        self.compiles_without_passes = self.steps_in_lanes and not self.packed.face_effects \
            and not self.gathers_for_lanes
        if self.steps_in_lanes:
            # [N]: the gathered effects' forces of a substep, per lane
            self.gathered_force = self.model.grid.lane_fields(self.model.real) \
                if self.gathers_for_lanes else None
            # its own real functions: kernels compiled apart share none (``runtime``)
            self.forward_pass = forward_pass_function(self.packed)
            self.group_step = group_pass_function(self.packed, lane_step_function(
                forces, self.uses_new_velocity, self.gathered_force))

    @ti.func
    def begin_launch(self, state):
        if ti.static(self.steps_in_lanes):  # (the packed path packs at every substep)
            self.packed.pack(state.x, state.v, 0, True)
            self.packed.make_damped(0)

    @ti.func
    def end_launch(self, state, buffer):
        if ti.static(self.steps_in_lanes):
            self.packed.unpack(buffer, state, True)

    @ti.func
    def substep(self, state_in, state_out, t, dt, buffer):
        """One step from state_in (packed copy ``buffer`` on a grid) at t [s] into state_out
        (into packed copy 1 − buffer only, when ``steps_in_lanes``: unpacked at the launch's
        end; with ``gathers_for_lanes`` state_in is overwritten with the substep's input
        positions, and velocities unless ``gathers_listed``, so after a launch the other state
        holds parts of a substep within it, not the launch's input)."""
        if ti.static(self.steps_in_lanes):
            self._lanes_substep(state_in, t, dt, buffer)
        elif ti.static(self.has_packed):
            self._packed_substep(state_in, state_out, t, dt, buffer)
        else:
            self._gather_substep(state_in, state_out, t, dt)

    @ti.func
    def _gather_substep(self, state_in, state_out, t, dt):
        """``Forces.prepare``, then every particle's update (its springs gathered)."""
        self.forces.prepare(state_in.x, state_in.v, t)
        for i_p in range(self.model.particle_count):
            self._update(state_in, state_out, i_p, t, dt)

    @ti.func
    def _lanes_substep(self, state_in, t, dt, buffer):
        """Row by row in blocks of rows (``PackedGrid.each_group``: in parallel, or all rows in
        one block in a serial launch, ``serial``: the kernel ``_advance_serial``), each row's
        forward pass and halo (``PackedGrid.forward_row``), then ``group_step`` for each of its
        groups and the pins set to their targets at t + h (``_step_group``; a group's sum reads
        the forward forces of its own row and the ``rows_back`` rows before: ~1.5 µs a substep
        less on ``hula`` than two loops over the rows, the same bits). With
        ``gathers_for_lanes``, first packed copy ``buffer`` unpacked into state_in, the
        effects' passes (``Forces.prepare_effects``) and the pointwise effects' forces into
        ``gathered_force``: of every particle, or with ``gathers_listed`` only of the particles
        the effects list (their lanes cleared again after the step), whose velocities are then
        read from the lanes (``PackedParticles``) and only the positions unpacked (every
        particle's, for contact's masks: 1.7 µs on ``hula``, where reading them from the lanes
        made contact's pass ~7 µs longer, docs/performance.md)."""
        packed = self.packed
        if ti.static(self.gathers_for_lanes):
            packed.unpack(buffer, state_in, not self.gathers_listed)
            x, v = ti.static(self._effects_state(state_in, buffer))
            self.forces.prepare_effects(x, v, t)
            if ti.static(self.gathers_listed):
                self._gather_listed(x, v, t)
            else:
                self._gather_lanes(x, v, t)
        packed.each_group(buffer, self.serial, self.forward_pass, self._step_group, (), t, dt)
        packed.refresh_halo(1 - buffer)
        if ti.static(self.gathers_listed):
            self._clear_listed()

    @ti.func
    def _step_group(self, buffer, row, block, group, states: ti.template(), t, dt):
        """``group_step`` of group ``group`` of row ``row`` (in block ``block``) from packed
        copy ``buffer`` at t [s] by dt [s], then its pinned lanes set to their targets at
        t + dt (``PackedGrid.each_group``'s work; no ``states``: the lanes are the state)."""
        model, packed = self.model, self.packed
        self.group_step(buffer, row, block, group, ti.cast(dt, model.real))
        if packed.group_has_pin[row, group]:
            first, end = packed.group_particles(row, group)
            # the pins' targets at t + h: the time's weights once for the group's pins (in the
            # loop, so that serial and parallel launches compute them alike)
            k, weights, delta = self.control.pin_basis(t + dt)
            for i_p in range(first, end):
                if model.particle_inv_mass[i_p] == 0:
                    x_pin, v_pin = self.control.pin_target_from(i_p, k, weights, delta)
                    packed.store_lane(1 - buffer, i_p, x_pin, v_pin)

    def _effects_state(self, state_in, buffer) -> list:
        """(x, v) that the effects read in a lanes substep (at compile time): state_in's fields
        (unpacked from packed copy ``buffer``), but with ``gathers_listed`` the velocities
        read from that copy's lanes."""
        velocities = PackedParticles(self.packed, self.packed.packed_v, buffer) \
            if self.gathers_listed else state_in.v
        return [state_in.x, velocities]

    @ti.func
    def _gather_lanes(self, x, v, t):
        """Every particle's pointwise force (``Forces.pointwise_force`` at x, v, time t [s]) into
        its lane of ``gathered_force``, a group at a time: its lanes filled in registers, then
        stored as whole vectors (stored lane by lane into the field, each store waited on the
        last: ~3x slower). Halo lanes hold 0."""
        model, packed = self.model, self.packed
        for row, group in ti.ndrange(model.grid.rows, ti.static(packed.filled_groups)):
            first, end = packed.group_particles(row, group)
            lanes = [ti.Vector.zero(model.real, SIMD_LANES) for _ in ti.static(range(3))]
            for i_p in range(first, end):
                force = self.forces.pointwise_force(x, v, i_p, ti.cast(t, model.real))
                for c in ti.static(range(3)):
                    lanes[c][i_p - first] = force[c]
            for c in ti.static(range(3)):
                self.gathered_force[c][row, group] = lanes[c]

    @ti.func
    def _gather_listed(self, x, v, t):
        """The pointwise force (``Forces.pointwise_force`` at x, v, time t [s]) of each particle
        that a pointwise effect lists (``Effect.touched_particles``) into its lane of
        ``gathered_force`` (the lanes of every other particle hold 0). A particle that two
        effects list is written twice, the same value."""
        model = self.model
        for e in ti.static(self.forces.pointwise_effects):
            listed, count = ti.static(e.touched_particles)
            for k in range(count[None]):
                i_p = listed[k]
                force = self.forces.pointwise_force(x, v, i_p, ti.cast(t, model.real))
                self.packed.store_lane_value(self.gathered_force, i_p, force)

    @ti.func
    def _clear_listed(self):
        """The lanes ``_gather_listed`` wrote set to 0 again (the lists are those it read)."""
        for e in ti.static(self.forces.pointwise_effects):
            listed, count = ti.static(e.touched_particles)
            for k in range(count[None]):
                self.packed.store_lane_value(self.gathered_force, listed[k],
                                             ti.Vector.zero(self.model.real, 3))

    @ti.func
    def _packed_substep(self, state_in, state_out, t, dt, buffer):
        """The state packed (a projection moved particles since the last substep), the SIMD
        spring pass and the per-particle update (any effects), group by group."""
        packed = self.packed
        self.forces.prepare_effects(state_in.x, state_in.v, t)
        packed.pack(state_in.x, state_in.v, buffer, packed.needs_velocity)
        packed.make_damped(buffer)
        packed.each_group(buffer, self.serial, packed.forward_pass, self._update_group,
                          (state_in, state_out), t, dt)

    @ti.func
    def _update_group(self, buffer, row, block, group, states: ti.template(), t, dt):
        """The SIMD pass's sum for group ``group`` of row ``row`` (in block ``block``), then
        the update of its particles from states[0] into states[1] (``PackedGrid.each_group``'s
        work in ``_packed_substep``)."""
        packed = self.packed
        packed.group_springs(buffer, row, block, group, 0.0)
        first, end = packed.group_particles(row, group)
        for i_p in range(first, end):
            self._update(states[0], states[1], i_p, t, dt)

    @ti.func
    def _update(self, state_in, state_out, i_p, t, dt):
        """Particle i_p's new (x, v) from its force at (state_in, t), after ``prepare``."""
        model = self.model
        x, v, x_out, v_out = ti.static(state_in.x, state_in.v, state_out.x, state_out.v)
        h = ti.cast(dt, model.real)
        inv_mass = model.particle_inv_mass[i_p]
        if inv_mass == 0:
            x_out[i_p], v_out[i_p] = self.control.pin_target(i_p, t + dt)
        else:
            acceleration = inv_mass * self.forces.particle_force(x, v, i_p, ti.cast(t, model.real))
            v_new = v[i_p] + h * acceleration
            if ti.static(self.uses_new_velocity):
                x_out[i_p] = x[i_p] + h * v_new
            else:
                x_out[i_p] = x[i_p] + h * v[i_p]
            v_out[i_p] = v_new


class ExplicitEuler(EulerStep):
    """x and v both from the old state: energy of an undamped oscillator grows by 1 + (ωh)²."""

    name = "euler"
    uses_new_velocity = False


class SymplecticEuler(EulerStep):
    """v first, then x with the new v: stable for ωh < 2 on an undamped oscillator."""

    name = "symplectic"
    uses_new_velocity = True
