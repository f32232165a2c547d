"""Small systems for the physics tests: one spring, built straight from arrays."""

import numpy as np

from taichi_cloth.physics.forces import Forces
from taichi_cloth.cloth.garment import Garment
from taichi_cloth.physics.integrators import make_integrator
from taichi_cloth.physics.model import Model


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
        self.integrator = make_integrator(integrator, Forces(self.model, []))
        self.omega, self.amplitude = omega, amplitude
        self.state_in, self.state_out = self.model.state(), self.model.state()

    def reset(self) -> None:
        x = self.garment.positions.copy()
        x[1, 0] += self.amplitude
        self.state_in.x.from_numpy(x)
        self.state_in.v.fill(0.0)

    def run(self, steps: int, h: float) -> list[tuple[float, float]]:
        """(u, v) of the free particle after each step, from a fresh start."""
        self.reset()
        history = []
        for n in range(steps):
            self.integrator.step(self.state_in, self.state_out, n * h, h)
            self.state_in, self.state_out = self.state_out, self.state_in
            x, v = self.state_in.x.to_numpy(), self.state_in.v.to_numpy()
            history.append((x[1, 0] - 1.0, v[1, 0]))
        return history

    def energy(self, u: float, v: float) -> float:
        return 0.5 * (v * v + self.omega ** 2 * u * u)
