"""What a run needs to go on exactly as it would have, as host copies (``Simulation.snapshot``
and ``restore``: checkpoints, redone frames, repeated runs from one state)."""

from dataclasses import dataclass, field

import numpy as np


@dataclass(frozen=True)
class Snapshot:
    """Positions [m] and velocities [m/s] (N, 3), the step dt [s] and substeps per frame in
    force, what the integrator carries between steps (``Integrator.memory``) and, when asked
    for, what the effects carry (``Effect.memory``, by ``effect.key``: self-collision's pair
    list and side records; empty: the effects start their history afresh)."""

    positions: np.ndarray
    velocities: np.ndarray
    dt: float
    substeps_per_frame: int
    integrator_memory: dict
    effect_memory: dict = field(default_factory=dict)
