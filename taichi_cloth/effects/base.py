"""The protocol every effect follows: one class per effect, one file per class.

An effect is everything a scene may declare under ``[effects.<name>]``: gravity, the springs'
dashpots, air drag, wind, contact with the body or the ground. The scene turns its declared
tables into a list of effect objects once (``build_effects``); the force evaluation, the implicit
solver, the time-step choice and the per-frame metrics then iterate that list, the kernels under
``ti.static``, so an effect the scene does not declare emits no code at all (the pattern of
Genesis' ``force_fields.py``). What an effect declares:

- ``name`` and ``Settings``: its scene table and that table's keys (a frozen dataclass of
  ``settings.setting`` fields; defaults, kinds, bounds, units).
- ``__init__(settings, context)``: what it allocates (Taichi fields), given the ``EffectContext``.
- ``force(model, x, v, i_p, t)``: a ``@ti.func`` returning its force on particle i_p [N], gathered
  per particle (no atomics); ``has_force = False`` when it acts elsewhere (the dashpots act
  inside the spring pass, ``model_options``).
- ``prepare(x, v, t)``: a ``@ti.func`` run once per force evaluation before the particle loops
  (posing the capsules; the contact of the surface samples, which particles then gather);
  nothing by default. A serial integrator may run it inside one serial loop (no thread-pool
  hand-offs), unless ``arranges_own_passes`` (its passes keep the serial and parallel loops it
  gives them: self-collision's rebuild, whose walks inlined into one serial loop compile 13 s
  longer). ``prepares_on_one_thread``: its passes run on one thread in any launch, so a launch
  made parallel for the particle loops pays the thread pool's hand-offs around them and gains
  nothing there (the integrator then stays on one thread up to ``SERIAL_PARTICLE_LIMIT``).
- ``has_jacobian`` and ``local_jacobian(model, x, v, i_p, t, definite)``: its per-particle blocks
  (∂f_i/∂x_i, ∂f_i/∂v_i) for the implicit solver, or ``has_jacobian = False`` when it has none
  (a constant force). An effect that couples particles (bending) sets ``has_coupled_jacobian``
  and gives ``coupled_products(model, u, i_p)`` (the rows i of (∂f/∂x)·u and (∂f/∂v)·u),
  ``coupled_diagonal(model, i_p)`` (their diagonals, for the preconditioner),
  ``coupled_rows()`` (host: the off-diagonal entries, constant for the run, as scalar blocks,
  (start, neighbour, H_ij, β) with ∂f_i/∂x_j = −H_ij·I and ∂f_i/∂v_j = −β·H_ij·I for j ≠ i,
  which the Gauss–Seidel sweeps fold into the springs' blocks: ``gather.sweep_rows``), and for
  ``dt = "auto"`` ``rest_stiffness_product(u)`` and ``stiffness_row_sums(n)`` (host NumPy).
- ``uniform_acceleration``: (a_x, a_y, a_z) [m/s²] when its force is m·a for every free particle
  (gravity), which a grid cloth's SIMD lanes add without gathering it per particle; None
  otherwise.
- ``touched_particles``: (a field of particle indices, a 0-d field of their count) that each
  ``prepare`` fills with every particle its force may be non-zero on (contact: the particles of
  the samples touching a capsule), or None when it may act on any; a grid cloth's SIMD lanes
  then take its force on the listed particles only (``EulerStep``), and its ``prepare`` and
  ``force`` get v as a view of the lanes that can only be read by particle, ``v[i]``
  (``packed_grid.PackedParticles``).
- ``allocate_lanes(grid)``: on a packed grid cloth (``physics.packed_grid``) an effect whose
  force is a linear stencil on the grid, f_i = −Σ_j C_ij·[(x_j − x_i) + β·(v_j − v_i)] (bending),
  may act inside the SIMD spring pass instead of being gathered per particle: it says whether
  it does (False by default) and sets ``lane_column_runs``, ``lane_row_step`` (a field per
  slot), ``lane_coefficient`` (C per lane and slot: ``GridStencil.lane_slots``,
  ``packed_table``) and ``lane_damping`` (β [s]).
- ``lane_faces``: True when its force is the air pressure on each face of the cloth
  (``aerodynamics.plate_pressure``, a third to each corner) with the air velocity relative to a
  face given by ``face_air(face_velocity)`` (on components) and the factor ``face_factor``
  (½·ρ·C_d [kg/m³]): on a packed grid cloth the SIMD pass then computes each face once, in
  lanes, and each particle reads back its six (drag).
- ``stability_modes()``: the ``penalty.ContactMode`` (k̂ [1/s²], ζ, how many add up) of each
  stiff mode it adds, for ``dt = "auto"``, and with ``bounds_given_step`` for a step in seconds
  too (an explicit one split until they are stable: self-collision's penalty, whose
  instability stays within its band, unseen by the frame guard);
  ``fit_time_step(time_step, integrator)``: the step then chosen (self-collision's default
  stiffness); ``follow_redo(halvings)``: a frame redone by the tunnelling guard at dt/2^halvings
  (0: the run's step again), which a penalty whose stopping speed the step allows may stiffen
  for (self-collision).
- ``potential_energy(x, mass)`` [J], ``penetration_depths(points)`` [m] and
  ``frame_metrics(x, potential)`` (more per-frame values for ``stats.json``, by name, given the
  potential energy already taken): its metrics.
- ``upload()``: add the copies into its fields to the model's ``uploads`` (sent in one launch
  once every field of the simulation is allocated: one SNode tree).
- ``post_step``: an object with a ``@ti.func apply(state, t)`` to run after every substep (the
  contact projection; self-collision's side records), or None.
- ``back_up()``, ``roll_back()`` and ``forget_history()``: what it carries from step to step
  besides the state (self-collision's side records), kept at the start of a frame, put back
  when the frame is redone, and dropped when the positions are set from outside; nothing by
  default. ``memory()`` and ``restore_memory(memory)``: the same as host arrays, for a
  checkpoint. ``repair(state)``: mend a frame's end that crossed itself (self-collision).

Every value an effect reads that is fixed for the run is baked in at compile time, as
``model.real(value)`` so that it keeps the model's precision; the time t is a kernel argument.
To add an effect: write ``effects/<name>.py`` with its ``Settings`` and its class, and list the
class in ``EFFECTS`` (``effects/__init__.py``).
"""

from dataclasses import dataclass
from typing import Any

import numpy as np
import taichi as ti

from taichi_cloth.effects.penalty import ContactMode


@dataclass(frozen=True)
class EffectContext:
    """What an effect may build on: the cloth's constant ``physics.model.Model``, the
    prescribed motion ``physics.control.Control`` (pinned particles, the body's capsules), and
    whether the integrator solves with Jacobians (an effect may then skip preparing them)."""

    model: Any
    control: Any = None
    needs_jacobian: bool = True  # whether the integrator asks for ``local_jacobian`` blocks


@ti.data_oriented
class Effect:
    """Base of the effects: no force, no Jacobian, no metrics; subclasses declare what they add
    (module docstring)."""

    name = ""
    Settings = None
    has_force = True
    has_jacobian = False
    has_coupled_jacobian = False
    needs_body = False  # the scene must have a [body] section
    arranges_own_passes = False  # ``prepare``'s loops stay as it configures them
    prepares_on_one_thread = False  # ``prepare``'s loops are all serial (module docstring)
    bounds_given_step = False  # its ``stability_modes`` split a step in seconds too
    uniform_acceleration = None
    touched_particles = None
    lane_faces = False
    post_step = None

    def __init__(self, settings, context: EffectContext):
        self.settings = settings

    def back_up(self) -> None:
        """Keep what the effect carries from step to step (module docstring): nothing here."""

    def roll_back(self) -> None:
        """Put back what ``back_up`` kept: nothing here."""

    def forget_history(self) -> None:
        """Drop what the effect carries from step to step: nothing here."""

    def memory(self) -> dict:
        """Host copies of what the effect carries from step to step (NumPy arrays by name),
        for a checkpoint: none here."""
        return {}

    def restore_memory(self, memory: dict) -> None:
        """Put back what ``memory`` returned (a resumed run takes the very same steps)."""

    def repair(self, state) -> None:
        """Mend a frame's end ``state`` that the cloth crossed itself in: nothing here."""

    def fit_time_step(self, time_step, integrator: str) -> bool:
        """The run's ``timestep.TimeStep`` with ``integrator``, once chosen and before any kernel
        compiles (a default that depends on it); whether that changed its ``stability_modes``:
        nothing here."""
        return False

    def follow_redo(self, halvings: int) -> None:
        """The frame is redone by the tunnelling guard at the run's step over 2^``halvings``
        (0: the run's step again): nothing here."""

    @staticmethod
    def model_options(settings) -> dict:
        """Keyword arguments this effect adds to ``Model`` (before it exists): none here."""
        return {}

    def upload(self) -> None:
        """Add the copies into the fields allocated in ``__init__`` to the model's
        ``uploads``: none here."""

    @ti.func
    def prepare(self, x, v, t):
        """Per-evaluation work at positions x, velocities v and time t [s], before the
        particle loops: nothing here."""

    def allocate_lanes(self, grid) -> bool:
        """Allocate what acting inside the SIMD pass of the grid cloth ``grid`` (a
        ``GridStencil``) needs, and say whether the effect does (module docstring): it does not
        here."""
        return False

    def stability_modes(self) -> list[ContactMode]:
        """The ``penalty.ContactMode`` of each stiff mode this effect adds: none here."""
        return []

    def potential_energy(self, x: np.ndarray, mass: np.ndarray) -> float:
        """Potential energy [J] of positions x [m] (N, 3) with masses [kg]: none here."""
        return 0.0

    def penetration_depths(self, points: np.ndarray) -> np.ndarray | None:
        """How deep [m] each of the points (P, 3) [m] lies inside the effect's collider at the
        end of the frame (0 outside; the margin does not count), or None without a collider."""
        return None

    def frame_metrics(self, x: np.ndarray, potential: float) -> dict:
        """Further per-frame metrics of positions x, by name (``potential``: this effect's
        ``potential_energy`` at x [J], already taken): none here."""
        return {}
