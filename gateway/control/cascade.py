"""Cascade PID (seed 000, Fig. 7): an outer angle loop sets the rate setpoint of an inner angular-rate loop.

    ω_ref = sat_ω(C_angle(θ_ref − θ))          outer loop, output limited to ±rate_limit
    u     = sat_u(C_rate(ω_ref − ω))           inner loop, output limited by the actuator

The inner loop sees the gyro rate directly, so disturbances that act on the rate (a fish pulling, a gust) are
rejected before they show in the angle. Anti-windup across loops: each PID has back-calculation on its own
limit; in addition, while the inner loop is saturated in the direction the outer error pushes, the outer integral
is frozen (conditional integration), because a larger rate setpoint could not be delivered anyway
(Åström & Hägglund 2006, §3.5, windup in cascade loops).
"""

from __future__ import annotations

from dataclasses import dataclass, field

from gateway.control.pid import Pid, PidSettings


@dataclass(frozen=True)
class CascadeSettings:
    """Outer (angle, rad → rad/s) and inner (rate, rad/s → actuator units) PID settings."""

    angle: PidSettings
    rate: PidSettings


@dataclass
class Cascade:
    """Two PIDs in series; `update()` takes angle and rate measurements of the same instant."""

    settings: CascadeSettings
    outer: Pid = field(init=False)
    inner: Pid = field(init=False)
    rate_setpoint: float = 0.0
    """Last rate setpoint the outer loop produced, in rad/s (for logs and plots)."""

    def __post_init__(self) -> None:
        self.outer = Pid(self.settings.angle)
        self.inner = Pid(self.settings.rate)

    def reset(self, output: float = 0.0) -> None:
        """Forget both loops' history; the inner loop starts from `output` for a bumpless start."""
        self.outer.reset(0.0)
        self.inner.reset(output)
        self.rate_setpoint = 0.0

    def update(self, angle_ref: float, angle: float, rate: float, dt_s: float, feedforward: float = 0.0) -> float:
        """One step: angles in rad, `rate` = measured dθ/dt in rad/s; returns the saturated actuator command.

        `feedforward` is added to the inner loop's output before its saturation (so its anti-windup sees it).
        """
        self.rate_setpoint = self.outer.update(angle_ref, angle, dt_s)
        u = self.inner.update(self.rate_setpoint, rate, dt_s, feedforward)
        s = self.settings.rate
        if u in (s.output_min, s.output_max) and self.settings.angle.ki != 0.0:
            # Inner loop saturated: undo the outer integral's growth from this step (conditional integration
            # at the outer level; back-calculation already protects the inner one).
            err = angle_ref - angle
            grows = (u == s.output_max and err > 0.0) or (u == s.output_min and err < 0.0)
            if grows:
                self.outer.state.integral -= dt_s * self.settings.angle.ki * err
        return u

    def track(self, applied: float, angle_ref: float, angle: float, rate: float, dt_s: float) -> float:
        """Manual mode: the actuator is at `applied`; both loops track it so auto resumes without a bump."""
        self.rate_setpoint = rate
        self.outer.track(rate, angle_ref, angle, dt_s)
        return self.inner.track(applied, rate, rate, dt_s)
