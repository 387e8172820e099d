"""Linear plants given as transfer functions, simulated by exact zero-order-hold discretisation.

A strictly proper G(s) = num/den is put in controllable canonical state-space form (ẋ = A x + B u, y = C x)
and discretised exactly for a held input (Franklin, Powell & Workman, *Digital Control*, eq. 4.59):

    [[A, B], [0, 0]]·dt  --expm-->  [[Φ, Γ], [0, I]],      x_{k+1} = Φ x_k + Γ u_k

The rate measurement of the cascade's inner loop is the exact derivative of the output, ẏ = C A x + C B u
(an ideal gyro; C B = 0 whenever the relative degree is ≥ 2, as for 38.5/(0.1 s² + 1)).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray
from scipy.linalg import expm
from scipy.signal import tf2ss

FloatArray = NDArray[np.float64]


@dataclass(frozen=True)
class TransferFunction:
    """G(s) = num(s)/den(s), coefficients highest power first (numpy.polyval order)."""

    num: tuple[float, ...]
    den: tuple[float, ...]

    def __post_init__(self) -> None:
        if len(self.num) >= len(self.den):
            raise ValueError("only strictly proper transfer functions are supported")


PAPER_PLANTS: dict[str, TransferFunction] = {
    "pitch": TransferFunction((38.5,), (0.1, 0.0, 1.0)),  # G1, seed 000 eq. 46
    "roll": TransferFunction((38.5,), (0.1, 0.0, 1.0)),  # G2
    "yaw": TransferFunction((48.6,), (0.1, 0.0, 1.0)),  # G3
}


def state_space(tf: TransferFunction) -> tuple[FloatArray, FloatArray, FloatArray]:
    """(A, B, C) of a strictly proper transfer function (controllable canonical form)."""
    a, b, c, _ = tf2ss(np.asarray(tf.num, float), np.asarray(tf.den, float))
    return np.asarray(a, float), np.asarray(b, float).reshape(-1), np.asarray(c, float).reshape(-1)


def zoh(a: FloatArray, b: FloatArray, dt_s: float) -> tuple[FloatArray, FloatArray]:
    """Exact ZOH discretisation (Φ, Γ) of ẋ = A x + B u over `dt_s` via one block matrix exponential."""
    n = a.shape[0]
    m = np.zeros((n + 1, n + 1))
    m[:n, :n] = a
    m[:n, n] = b
    e = expm(m * dt_s)
    return e[:n, :n], e[:n, n]


@dataclass
class LtiPlant:
    """A transfer function simulated at a fixed step `dt_s` with the input held over each step."""

    tf: TransferFunction
    dt_s: float
    x: FloatArray = field(init=False)
    _a: FloatArray = field(init=False, repr=False)
    _b: FloatArray = field(init=False, repr=False)
    _c: FloatArray = field(init=False, repr=False)
    _phi: FloatArray = field(init=False, repr=False)
    _gamma: FloatArray = field(init=False, repr=False)

    def __post_init__(self) -> None:
        self._a, self._b, self._c = state_space(self.tf)
        self._phi, self._gamma = zoh(self._a, self._b, self.dt_s)
        self.x = np.zeros(self._a.shape[0])

    @property
    def output(self) -> float:
        """y = C x."""
        return float(self._c @ self.x)

    def output_rate(self, u: float = 0.0) -> float:
        """ẏ = C A x + C B u: the ideal rate sensor."""
        return float(self._c @ self._a @ self.x + (self._c @ self._b) * u)

    def step(self, u: float) -> float:
        """Hold `u` for one step of `dt_s`; returns the new output."""
        self.x = self._phi @ self.x + self._gamma * u
        return self.output
