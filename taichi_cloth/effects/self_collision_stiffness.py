"""The stiffness k̂ [1/s²] of self-collision's penalty (``effects/self_collision.py``), when the
scene gives none: chosen for the speed at which layers close, fitted to the run's step, and
stiffened in a frame that the tunnelling guard redoes (docs/physics.md, "Tunnelling").

Layers closing at v are stopped within the thickness h when the penalty's energy over it,
½·m·k̂·h², is at least their kinetic energy ½·m·v²: k̂ = (v / h)², with v = ``REFERENCE_SPEED``
(10⁶ at 4 mm). Faster folds (a skirt spun three turns a second and more) tunnel through it at
any step: the tunnelling guard, which redoes such a frame at a half, a quarter, ... of the step,
stiffens the penalty 4× a halving (``redo_stiffness``), k̂·dt² staying what the run's step was
chosen for.

Also how many contacts push two vertices resting on each other apart, at most
(``vertex_on_vertex_contacts``), which sets the penalty's stiffest mode for an explicit step
(``SelfCollision.stability_modes``).
"""

import numpy as np

REFERENCE_SPEED = 4.0  # m/s: layers closing up to this fast are stopped (a hem twirled once a second)
FIXED_STEP_STIFFNESS = 1e6  # 1/s²: the most for an explicit step given in seconds (not chosen
# for more; 4 m/s at 4 mm)
STEP_STIFFNESS = 300.0  # k̂·dt² at most for backward Euler (its blocks leave out the couplings
# between a pair's particles: with k̂·dt² ≫ 1 each side moves as if the other held still)
REDO_STIFFENING = 4.0  # a frame the tunnelling guard redoes at half the step: 4 × the stiffness,
# so twice the closing speed stopped (a fold closing faster than the penalty stops tunnels at any
# step), with k̂·dt², and so the step's stability, as before
CONTACT_ROWS = 512  # rows of vertex pairs at a time in ``vertex_on_vertex_contacts``


def default_stiffness(thickness: float) -> float:
    """(``REFERENCE_SPEED`` / thickness)² [1/s²], thickness in m (module docstring)."""
    return (REFERENCE_SPEED / thickness) ** 2


def fitted_stiffness(stiffness: float, dt: float, integrator: str, step_requested) -> float:
    """The default ``stiffness`` [1/s²] fitted to the run's step dt [s]: for backward Euler at
    most ``STEP_STIFFNESS``/dt²; for an explicit integrator with a step given in seconds
    (``step_requested`` not "auto") at most ``FIXED_STEP_STIFFNESS``; with dt = "auto" the
    step was chosen for it."""
    if integrator == "implicit":
        return min(stiffness, STEP_STIFFNESS / dt ** 2)
    if step_requested != "auto":
        return min(stiffness, FIXED_STEP_STIFFNESS)
    return stiffness


def redo_stiffness(stiffness: float, halvings: int) -> float:
    """The stiffness [1/s²] of a frame redone by the tunnelling guard at the run's step over
    2^``halvings``: ``REDO_STIFFENING``^halvings times the run's."""
    return stiffness * REDO_STIFFENING ** halvings


def vertex_on_vertex_contacts(triangles: np.ndarray, edges: np.ndarray, mass: np.ndarray,
                              pinned: np.ndarray) -> float:
    """How many contacts of stiffness k̂ push two vertices resting on each other apart, at the
    mesh's most: the count n of self-collision's stiffest mode (``penalty.ContactMode``), for
    (T, 3) ``triangles`` and (E, 2) ``edges`` of particle indices, particle ``mass`` [kg] and
    ``pinned`` (N,) bools. A vertex p resting on a vertex q of another layer is within the
    thickness of each triangle at q, q of each triangle at p, and each edge at p of each edge
    at q, all along one normal: T(p) + T(q) + E(p)·E(q) pairs (T, E: the triangles and edges at
    a vertex; 6 + 6 + 36 = 48 on a regular grid). A vertex–triangle pair pushes with its
    vertex's mass, an edge–edge pair with its four particles' mean (``SelfCollision``), each on
    both vertices with weight 1, so the vertices' relative coordinate feels n(p, q)·k̂ with

        n(p, q) = (1/m_p + 1/m_q)·(T(q)·m_p + T(p)·m_q + (E(q)·M(p) + E(p)·M(q))/4),

    M(v) the sum of the masses at the ends of v's edges and 1/m = 0 for a pinned (or
    massless) particle: 2·48 = 96 on a regular grid of equal masses, more where neighbouring
    masses differ (a graded or irregular mesh: ~125 on ``twirl``'s circle skirt). The largest
    over all p ≠ q, taken over the vertices' distinct (T, E, m, M, 1/m) (a grid has a few
    dozen), in blocks of rows."""
    count = len(mass)
    edges = np.asarray(edges)
    end_mass = np.zeros(count)
    np.add.at(end_mass, edges.ravel(), np.repeat(mass[edges].sum(axis=1), 2))
    kinds, members = np.unique(np.column_stack([
        np.bincount(np.asarray(triangles).ravel(), minlength=count),
        np.bincount(edges.ravel(), minlength=count), mass, end_mass,
        np.divide(1.0, mass, out=np.zeros(count), where=~pinned & (mass > 0))]),
        axis=0, return_counts=True)
    triangles_at, edges_at, kind_mass, kind_end_mass, inverse = kinds.T
    most = 0.0
    for first in range(0, len(kinds), CONTACT_ROWS):
        rows = slice(first, min(first + CONTACT_ROWS, len(kinds)))
        n = (inverse[rows, None] + inverse[None, :]) * (
            np.outer(kind_mass[rows], triangles_at) + np.outer(triangles_at[rows], kind_mass)
            + 0.25 * (np.outer(kind_end_mass[rows], edges_at)
                      + np.outer(edges_at[rows], kind_end_mass)))
        alone = np.flatnonzero(members[rows] == 1)  # a vertex is not on itself
        n[alone, rows.start + alone] = 0.0
        most = max(most, float(n.max(initial=0.0)))
    return most
