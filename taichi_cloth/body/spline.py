"""Natural cubic spline interpolation of uniformly sampled curves, in NumPy: values and first
derivatives anywhere, twice continuously differentiable, through every sample exactly.

For samples y_0 … y_n at spacing h, the second derivatives M_i solve
M_{i−1} + 4 M_i + M_{i+1} = 6 (y_{i+1} − 2 y_i + y_{i−1}) / h² with M_0 = M_n = 0 (natural ends),
a tridiagonal system solved by the Thomas algorithm; between samples i and i+1, with u = t/h − i,

    S(t)  = (1 − u) y_i + u y_{i+1} + h²/6 [((1 − u)³ − (1 − u)) M_i + (u³ − u) M_{i+1}]
    S′(t) = (y_{i+1} − y_i)/h + h/6 [(1 − 3 (1 − u)²) M_i + (3 u² − 1) M_{i+1}]

(de Boor, "A Practical Guide to Splines", 1978, ch. IV).
"""

import numpy as np


class CubicSpline:
    """The natural cubic spline through ``values`` (F, ...) sampled every ``spacing`` from
    time 0; F ≥ 2."""

    def __init__(self, values: np.ndarray, spacing: float):
        self.values = np.asarray(values, dtype=float)
        self.spacing = float(spacing)
        count = len(self.values)
        second = np.zeros_like(self.values)
        if count > 2:
            rhs = 6.0 * (self.values[2:] - 2.0 * self.values[1:-1] + self.values[:-2]) \
                / self.spacing ** 2
            diagonal = np.full(count - 2, 4.0)
            for i in range(1, count - 2):  # forward sweep (off-diagonals are 1)
                factor = 1.0 / diagonal[i - 1]
                diagonal[i] -= factor
                rhs[i] -= factor * rhs[i - 1]
            solution = np.empty_like(rhs)
            solution[-1] = rhs[-1] / diagonal[-1]
            for i in range(count - 4, -1, -1):  # back substitution
                solution[i] = (rhs[i] - solution[i + 1]) / diagonal[i]
            second[1:-1] = solution
        self.second = second

    @property
    def duration(self) -> float:
        return (len(self.values) - 1) * self.spacing

    def __call__(self, t: float) -> tuple[np.ndarray, np.ndarray]:
        """(value, first derivative) at time ``t`` [s], clamped to [0, duration]."""
        position = min(max(t, 0.0), self.duration) / self.spacing
        i = min(int(position), len(self.values) - 2)
        u = position - i
        h, y, m = self.spacing, self.values, self.second
        value = (1 - u) * y[i] + u * y[i + 1] + h * h / 6.0 * (
            ((1 - u) ** 3 - (1 - u)) * m[i] + (u ** 3 - u) * m[i + 1])
        slope = (y[i + 1] - y[i]) / h + h / 6.0 * (
            (1 - 3 * (1 - u) ** 2) * m[i] + (3 * u * u - 1) * m[i + 1])
        return value, slope
