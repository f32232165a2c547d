"""What a run measures, on the host once per frame or per try of a frame (never inside the
substep loop): the stretch springs' strain, the elastic energy, the check that a state is usable
(``state_problem``), the depth of the cloth's surface in the colliders (``surface_penetration``),
and the per-frame and per-run records that become ``stats.json`` (docs/physics.md, "Metrics")."""

from dataclasses import dataclass, field, fields

import numpy as np


def spring_energy(model, positions: np.ndarray) -> float:
    """Elastic energy Σ ½ k (l − L)² [J] (NumPy, per frame)."""
    ends = model.host_spring_ends
    length = np.linalg.norm(positions[ends[:, 1]] - positions[ends[:, 0]], axis=1)
    return float(0.5 * np.sum(model.host_stiffness * (length - model.host_rest_length) ** 2))


def stretch_strain(model, positions: np.ndarray) -> np.ndarray:
    """(l − L) / L of every stretch spring."""
    ends = model.host_spring_ends[:model.stretch_count]
    rest = model.host_rest_length[:model.stretch_count]
    length = np.linalg.norm(positions[ends[:, 1]] - positions[ends[:, 0]], axis=1)
    return (length - rest) / rest


def largest_stretch_strain(model, positions: np.ndarray) -> float:
    """The largest (l − L) / L over the stretch springs (0 without any)."""
    return float(np.max(stretch_strain(model, positions))) if model.stretch_count else 0.0


def surface_samples(positions: np.ndarray, edges: np.ndarray, triangles: np.ndarray) -> np.ndarray:
    """Points that stand for the whole cloth surface (P, 3) [m]: the particles, the midpoints of
    the edges (E, 2) and the centroids of the triangles (T, 3), in that order. A capsule can
    pass between particles; at these spacings it cannot also pass between these samples
    without one of them inside."""
    corner = positions[triangles.T]  # (3, T, 3); the same sums as NumPy's ``mean``, ~3× faster
    return np.concatenate([positions, 0.5 * (positions[edges[:, 0]] + positions[edges[:, 1]]),
                           (corner[0] + corner[1] + corner[2]) / 3])


def state_problem(model, settings, x: np.ndarray, v: np.ndarray,
                  strain: float | None = None) -> str | None:
    """Why the state x [m], v [m/s] of ``model``'s cloth is not usable (non-finite,
    over-strained or too fast for ``settings``, a scene's [simulation] table), or None;
    ``strain``: x's largest stretch strain when already taken."""
    if not (np.isfinite(x).all() and np.isfinite(v).all()):
        return "became non-finite"
    strain = largest_stretch_strain(model, x) if strain is None else strain
    if strain > settings.blowup_strain:
        return f"exploded (max strain {strain:.3g} > simulation.blowup_strain " \
               f"{settings.blowup_strain:g})"
    speed = float(np.sqrt(np.max(np.sum(v * v, axis=1))))
    if speed > settings.max_speed:
        return f"exploded (a particle at {speed:.3g} m/s > simulation.max_speed " \
               f"{settings.max_speed:g})"
    return None


def surface_penetration(effects, positions: np.ndarray, edges: np.ndarray,
                        triangles: np.ndarray) -> np.ndarray:
    """How deep [m] each surface sample (``surface_samples``) of the cloth at ``positions``
    lies inside the deepest collider of ``effects`` (``Effect.penetration_depths``: capsules,
    ground, support plate; without their margins), 0 outside: (P,)."""
    samples = surface_samples(positions, edges, triangles)
    depth = np.zeros(len(samples))
    for effect in effects:
        inside = effect.penetration_depths(samples)
        if inside is not None:
            depth = np.maximum(depth, inside)
    return depth


@dataclass
class FrameMetrics:
    """One frame's measurements (SI units) as they go into ``stats.json``."""

    frame: int
    t: float
    kinetic_energy: float
    potential_energy: float
    max_strain: float
    max_penetration: float  # deepest surface sample inside a collider [m]
    center_of_mass: list
    penetrating_samples: int = 0  # surface samples inside a collider
    mean_speed: float = 0.0  # of the free particles [m/s]
    self_intersections: int = 0  # pairs of non-adjacent triangles that meet (intersections.py)
    cg_iterations: float | None = None  # implicit integrator: mean CG iterations per step
    extra: dict = field(default_factory=dict)  # the effects' own metrics (bending_energy [J])

    def as_dict(self) -> dict:
        values = {key: value for key, value in self.__dict__.items()
                  if value is not None and key != "extra"}
        return {**values, **self.extra}

    @classmethod
    def from_dict(cls, document: dict) -> "FrameMetrics":
        """The inverse of ``as_dict`` (a resumed run reads its finished frames back)."""
        names = {f.name for f in fields(cls)} - {"extra"}
        return cls(**{key: value for key, value in document.items() if key in names},
                   extra={key: value for key, value in document.items() if key not in names})


@dataclass
class RunRecord:
    """What a run measured: per-frame metrics and wall-clock seconds per phase."""

    frames: list = field(default_factory=list)
    wall_seconds: dict = field(default_factory=lambda: {"compile": 0.0, "simulate": 0.0})
    cg_iterations: list = field(default_factory=list)  # per implicit step
    retries: int = 0  # frames rolled back and redone with the step halved

    @property
    def max_strain(self) -> float:
        return max((f.max_strain for f in self.frames), default=0.0)

    @property
    def max_penetration(self) -> float:
        return max((f.max_penetration for f in self.frames), default=0.0)

    @property
    def max_penetrating_samples(self) -> int:
        return max((f.penetrating_samples for f in self.frames), default=0)

    @property
    def max_self_intersections(self) -> int:
        return max((f.self_intersections for f in self.frames), default=0)


def run_stats(simulation, record: RunRecord) -> dict:
    """The ``stats.json`` document of ``simulation`` (a ``physics.simulation.Simulation``) after
    the run in ``record`` (README, "Outputs")."""
    scene = simulation.scene
    return {
        "scene": scene.name,
        "integrator": scene.simulation.integrator,
        "dt": simulation.time_step.dt,
        "substeps_per_frame": simulation.time_step.substeps_per_frame,
        "retries": record.retries,
        "time_step": simulation.time_step.report(),
        "precision": scene.simulation.precision,
        "material": scene.material.name,
        "frames": len(record.frames),
        "particles": simulation.model.particle_count,
        "springs": simulation.model.spring_count,
        "springs_per_family": simulation.model.family_counts,
        "capsules": simulation.body_rig.capsule_count if simulation.body_rig is not None else 0,
        "effects": simulation.effect_names,
        "finite": True,
        "max_strain": record.max_strain,
        "max_penetration": record.max_penetration,
        "max_penetrating_samples": record.max_penetrating_samples,
        "max_self_intersections": record.max_self_intersections,
        "surface_samples": simulation.model.particle_count + len(simulation.surface_edges)
        + len(simulation.garment.triangles),
        "wall_seconds": {k: round(v, 4) for k, v in record.wall_seconds.items()},
        **simulation.integrator.solver_report(record.cg_iterations),
        **({"settle": simulation.settle_report} if simulation.settle_report is not None else {}),
        "per_frame": [f.as_dict() for f in record.frames],
    }
