"""The reference sheet's symplectic Euler step in NumPy: the benchmark's baseline, and the oracle
the tests hold the packed and gathered Taichi spring passes against."""

import numpy as np

from taichi_cloth.physics.model import Model


class NumpyCloth:
    """The reference step in NumPy: spring and dashpot forces per spring, summed per particle
    with ``bincount`` (f_i = Σ_s k_s (l − L)/l · d + c_s ((v_j − v_i)·d)/l² · d, d = x_j − x_i,
    the formula of ``forces.py``), gravity m·g, then symplectic Euler v' = v + h·F/m,
    x' = x + h·v'. Pinned particles keep their position, at rest."""

    def __init__(self, model: Model, gravity: float):
        self.model = model
        self.first, self.second = model.host_spring_ends.T
        self.rest_length = model.host_rest_length.astype(model.numpy_real)
        self.stiffness = model.host_stiffness.astype(model.numpy_real)
        self.damping = model.spring_damping.to_numpy() if model.has_dashpots else None
        self.mass = model.particle_mass.to_numpy()
        self.inv_mass = model.particle_inv_mass.to_numpy()
        self.weight = np.zeros((model.particle_count, 3), model.numpy_real)
        self.weight[:, 1] = -gravity * self.mass

    def forces(self, x: np.ndarray, v: np.ndarray) -> np.ndarray:
        """Total force on every particle [N], shape (N, 3)."""
        d = x[self.second] - x[self.first]
        length = np.sqrt(np.einsum("sk,sk->s", d, d))
        coefficient = self.stiffness * (length - self.rest_length) / length
        if self.damping is not None:
            relative = v[self.second] - v[self.first]
            coefficient += self.damping * np.einsum("sk,sk->s", relative, d) / length ** 2
        spring = coefficient[:, None] * d
        total = self.weight.copy()
        count = self.model.particle_count
        for c in range(3):
            total[:, c] += (np.bincount(self.first, spring[:, c], count)
                            - np.bincount(self.second, spring[:, c], count))
        return total

    def step(self, x: np.ndarray, v: np.ndarray, dt: float):
        """One symplectic Euler substep; returns the new (x, v)."""
        h = self.model.numpy_real(dt)
        v_new = v + h * self.inv_mass[:, None] * self.forces(x, v)
        v_new[self.inv_mass == 0] = 0.0
        return x + h * v_new, v_new
