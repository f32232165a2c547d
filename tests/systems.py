"""Small systems for the physics tests: one spring built straight from arrays, and the physics
of a hand-built model assembled without a scene."""

from dataclasses import dataclass

import numpy as np

from taichi_cloth.cloth.garment import Garment
from taichi_cloth.effects import EffectContext
from taichi_cloth.physics.control import Control
from taichi_cloth.physics.forces import Forces
from taichi_cloth.physics.integrators import make_integrator
from taichi_cloth.physics.model import Model
from taichi_cloth.physics.packed_grid import ROWS_PER_BLOCK, packed_grid_for


@dataclass
class Physics:
    """A model's prescribed motion, effects, forces and (optionally) integrator."""

    model: Model
    control: Control
    effects: list
    forces: Forces
    integrator: object = None


def assemble(model: Model, effects=(), packed: bool = False, integrator: str | None = None,
             capsule_radius=(), sample_count: int = 2, post_step=None,
             rows_per_block: int = ROWS_PER_BLOCK, **options) -> Physics:
    """The physics of ``model`` as ``Simulation`` builds it: ``effects`` as (effect class,
    settings) pairs, a packed grid when ``packed`` (and the cloth is one; ``rows_per_block`` of
    its parallel launches), ``capsule_radius`` [m]
    of the capsules in the control's track, ``sample_count`` samples per track; ``options`` go to
    the integrator (the implicit solver's tolerance...)."""
    control = Control(model.garment.pinned, model.garment.positions, model.real,
                      np.asarray(capsule_radius, dtype=float), sample_count)
    context = EffectContext(model, control)
    built = [effect(settings, context) for effect, settings in effects]
    control.upload(model.uploads)
    for effect in built:
        effect.upload()
    forces = Forces(model, built, packed_grid_for(model, packed, built, rows_per_block))
    stepper = None
    if integrator is not None:
        stepper = make_integrator(integrator, forces, control, post_step) if not options else \
            make_integrator(integrator, forces, control, post_step, **options)
    model.uploads.send()  # every field filled now: a test may set the tracks next
    return Physics(model, control, built, forces, stepper)


def one_spring_garment(omega: float, rest_length: float = 1.0, amplitude: float = 0.1,
                       damping_time: float = 0.0) -> Garment:
    """Particle 0 pinned at the origin, particle 1 (mass 1 kg) on a spring of stiffness ω² along
    x, displaced by ``amplitude``; particle 2 pinned, unconnected (the mesh needs a triangle).
    Displacement u = x₁ − L obeys ü = −ω²u − β·ω²·u̇."""
    positions = np.array([[0.0, 0.0, 0.0], [rest_length, 0.0, 0.0], [0.0, 1.0, 0.0]])
    garment = Garment(
        positions=positions, uvs=np.zeros((3, 2)), triangles=np.array([[0, 1, 2]], np.int32),
        springs={"stretch": np.array([[0, 1]], np.int32)},
        spring_stiffness={"stretch": np.array([omega ** 2])}, mass=np.ones(3),
        pinned=np.array([True, False, True]), columns=3, rows=1, periodic=False,
        damping_time=damping_time)
    return garment


class SpringOscillator:
    """The one-spring system with an integrator, run from a displaced start at rest."""

    def __init__(self, integrator: str, omega: float, damping_ratio: float = 0.0,
                 amplitude: float = 0.1):
        damping_time = 2.0 * damping_ratio / omega  # ζ = β·ω/2 for c = β·k, m = 1
        self.garment = one_spring_garment(omega, amplitude=amplitude, damping_time=damping_time)
        self.model = Model(self.garment, "f64", 1.0 if damping_ratio > 0 else None)
        self.integrator = assemble(self.model, integrator=integrator).integrator
        self.omega, self.amplitude = omega, amplitude
        self.states = self.model.states(2)
        self.state_in, self.state_out = self.states.members

    def reset(self) -> None:
        x = self.garment.positions.copy()
        x[1, 0] += self.amplitude
        self.states.write(self.state_in, x, np.zeros_like(x))

    def run(self, steps: int, h: float) -> list[tuple[float, float]]:
        """(u, v) of the free particle after each step, from a fresh start."""
        self.reset()
        history = []
        for n in range(steps):
            self.integrator.step(self.state_in, self.state_out, n * h, h)
            self.state_in, self.state_out = self.state_out, self.state_in
            x, v = self.states.read(self.state_in)
            history.append((x[1, 0] - 1.0, v[1, 0]))
        return history

    def energy(self, u: float, v: float) -> float:
        return 0.5 * (v * v + self.omega ** 2 * u * u)


def energy_gradient(energy, x: np.ndarray, step: float) -> np.ndarray:
    """∂energy/∂x by central differences of ``step`` in every coordinate of x (N, 3)."""
    gradient = np.zeros_like(x)
    for index in np.ndindex(*x.shape):
        offset = np.zeros_like(x)
        offset[index] = step
        gradient[index] = (energy(x + offset) - energy(x - offset)) / (2 * step)
    return gradient
