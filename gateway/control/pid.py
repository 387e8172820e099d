"""Discrete PID controller: output limits, back-calculation anti-windup, filtered derivative, bumpless transfer.

Form (parallel, Åström & Hägglund, *Advanced PID Control*, 2006, ch. 3):

    u = kp·e + I + D,       e = r − y
    I_k = I_{k−1} + dt·(ki·e_k + (sat(u_k) − u_k)/T_t)                 (back-calculation, eq. 3.23)
    D_k = T_f/(T_f + dt)·D_{k−1} − kd/(T_f + dt)·(y_k − y_{k−1})       (backward Euler of −kd·s/(T_f s + 1)·y)

Anti-windup is **back-calculation**, not conditional integration: it also unwinds an integral that is already
large (e.g. after a setpoint change or a limit change), it has a single documented knob T_t, and the same
tracking path gives bumpless manual → auto transfer (in manual the integral tracks the applied output).
The integral term is stored in output units (I, not ∫e), so gain changes do not bump the output.

Derivative acts on the measurement by default (no kick on setpoint steps); `derivative_on="error"` reproduces
the Simulink PID block (D·N·s/(s + N) on the error, N = 1/T_f) for the paper study.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Literal


@dataclass(frozen=True)
class PidSettings:
    """Gains and limits. Units: output per unit error (kp), per unit error·s (ki), per unit error/s (kd)."""

    kp: float
    ki: float = 0.0
    kd: float = 0.0
    derivative_filter_s: float = 0.0
    """Time constant T_f of the first-order derivative filter in s (0: unfiltered, not advised on real data)."""
    output_min: float = -math.inf
    output_max: float = math.inf
    tracking_time_s: float | None = None
    """Back-calculation time constant T_t in s; None: sqrt(Ti·Td) if kd > 0 else Ti/2 (Åström's rule), Ti = kp/ki."""
    derivative_on: Literal["measurement", "error"] = "measurement"

    def __post_init__(self) -> None:
        if self.output_min > self.output_max:
            raise ValueError(f"output_min {self.output_min} > output_max {self.output_max}")
        if self.derivative_filter_s < 0.0:
            raise ValueError("derivative_filter_s must be >= 0")
        if self.tracking_time_s is not None and self.tracking_time_s <= 0.0:
            raise ValueError("tracking_time_s must be > 0")

    @property
    def tracking_s(self) -> float:
        """Effective back-calculation time constant T_t in s (inf when there is no integral action)."""
        if self.tracking_time_s is not None:
            return self.tracking_time_s
        if self.ki == 0.0:
            return math.inf
        ti_s = abs(self.kp / self.ki) if self.kp != 0.0 else 1.0 / abs(self.ki)
        if self.kd != 0.0 and self.kp != 0.0:
            return max(math.sqrt(ti_s * abs(self.kd / self.kp)), 1e-6)
        return max(ti_s / 2.0, 1e-6)


@dataclass
class PidState:
    """Mutable controller memory. `integral` is in output units."""

    integral: float = 0.0
    derivative: float = 0.0
    last_input: float | None = None
    """Previous y (derivative on measurement) or previous e (on error); None before the first sample."""
    output: float = 0.0
    manual: bool = False


def clamp(x: float, lo: float, hi: float) -> float:
    """x limited to [lo, hi]."""
    return lo if x < lo else hi if x > hi else x


def filtered_derivative(d_prev: float, x: float, x_prev: float, kd: float, tf_s: float, dt_s: float) -> float:
    """Backward-Euler discretisation of kd·s/(T_f·s + 1) applied to x: one step, returns the new D term."""
    return (tf_s * d_prev + kd * (x - x_prev)) / (tf_s + dt_s)


@dataclass
class Pid:
    """PID controller; call `update()` once per sample with the elapsed `dt_s`."""

    settings: PidSettings
    state: PidState = field(default_factory=PidState)

    def reset(self, output: float = 0.0) -> None:
        """Forget history; the next auto output starts from `output` (integral pre-loaded) for a bumpless start."""
        self.state = PidState(integral=output, output=output)

    def update(self, setpoint: float, measurement: float, dt_s: float, feedforward: float = 0.0) -> float:
        """One auto step: returns the saturated output. `feedforward` is added before saturation."""
        if dt_s <= 0.0:
            raise ValueError(f"dt_s must be > 0, got {dt_s}")
        s, st = self.settings, self.state
        error = setpoint - measurement
        p = s.kp * error
        d = self._derivative(error, measurement, dt_s)
        unsat = p + st.integral + d + feedforward
        out = clamp(unsat, s.output_min, s.output_max)
        # Integrate after computing the output (the integral used is I_{k-1}); back-calculate the saturation excess.
        st.integral += dt_s * s.ki * error
        if math.isfinite(s.tracking_s):
            st.integral += dt_s * (out - unsat) / s.tracking_s
        st.integral = clamp(st.integral, s.output_min - feedforward, s.output_max - feedforward)
        st.output = out
        st.manual = False
        return out

    def track(self, applied: float, setpoint: float, measurement: float, dt_s: float) -> float:
        """Manual mode: the actuator is driven by someone else at `applied`; keep state so auto resumes bumplessly.

        The integral is set so that P + I + D equals the applied output, i.e. full tracking (T_t → 0).
        """
        if dt_s <= 0.0:
            raise ValueError(f"dt_s must be > 0, got {dt_s}")
        s, st = self.settings, self.state
        error = setpoint - measurement
        d = self._derivative(error, measurement, dt_s)
        st.integral = clamp(applied - s.kp * error - d, s.output_min, s.output_max)
        st.output = applied
        st.manual = True
        return applied

    def _derivative(self, error: float, measurement: float, dt_s: float) -> float:
        s, st = self.settings, self.state
        x = -measurement if s.derivative_on == "measurement" else error
        if st.last_input is None or s.kd == 0.0:
            st.derivative = 0.0
        else:
            st.derivative = filtered_derivative(st.derivative, x, st.last_input, s.kd, s.derivative_filter_s, dt_s)
        st.last_input = x
        return st.derivative
