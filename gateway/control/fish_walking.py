"""Fish walking (遛鱼, seed 000 §3.4): turn the rod's pitch deviation into reel commands that tire the fish.

Sign conventions: `pitch_deviation_rad` is pitch − rest baseline, as in `gateway.alarm.bite`; a fish pulling
drags the tip down, so the deviation is negative. Internally the controller works on the **bend**
β = −deviation (> 0 under load) and its rate β' = −pitch rate. Reel speed is signed, > 0 reels line in.

The paper's rule: reel in while β < θ2, pay out above θ2, and never reach θ3 (the bend at the line's breaking
load). Here the cascade of Fig. 7 decides *how fast*:

    β'_ref = C_angle(β_ref − β),     β_ref = setpoint_fraction·θ2 (just below θ2)
    v      = C_rate(β'_ref − β')     reel-in speed, m/s

Reeling in raises the line tension and so the bend; paying out lowers both, so both loops have positive gain.
Bend and bend rate pass a first-order low-pass (`measurement_filter_s`) first: the rod tip is a lightly damped
≈ 2.5 Hz mode, and a loop fast enough to chase it turns the stiff line into a limit cycle. While auto is on the
controller also asks for a reel drag of `drag_fraction` of the breaking load, so the spool slips before the
line breaks during the fraction of a second the motor needs to reverse.

Safety layers, applied around the cascade in this order (the first that applies wins):

1. manual: the angler's command passes through untouched; auto stays off until `enable()` (which resets).
2. data timeout: no attitude newer than `attitude_timeout_s` → stop the motor.
3. landed: while line out ≤ `landed_line_m` the reel stops (the fish is at the tip; the angler nets it).
4. tension guard: tension T̂ = the load cell's reading when the reel reports one (`trust_load_cell`), else
   T(β_pred) with β_pred = β + max(β', 0)·lookahead (and ≥ the raw β if `guard_on_raw_bend`), T(β) the rod's
   calibration curve (default linear, T(θ3) = breaking load). T̂ ≥ payout_fraction·breaking → pay out at full
   speed, latched until T̂ < hold_fraction·breaking (hysteresis); T̂ ≥ hold_fraction·breaking → no reeling in.
5. θ2 cap: never reel in while the filtered or the raw bend is ≥ θ2 (the paper's switch); pay out at least
   `min_payout_m_s` there (default 0: stop, and the drag, set below the breaking load, gives line).
6. chatter: a direction hysteresis (separate on/off speed thresholds) and a minimum dwell before reversing.

Two baselines share the interface: `DragOnly` (no control; the reel's drag alone) and `BangBang` (full speed
in below θ2, full speed out above).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from typing import Literal, Protocol

import numpy as np

from gateway.control.cascade import Cascade, CascadeSettings
from gateway.control.pid import PidSettings

ReelAction = Literal["in", "out", "stop"]
Reason = Literal[
    "cascade", "manual", "disabled", "timeout", "tension_guard", "tension_hold", "theta2_cap", "landed", "hysteresis",
    "baseline",
]


@dataclass(frozen=True)
class Observation:
    """What the gateway knows about the rod at one instant (no physics hidden state)."""

    attitude_t_s: float
    """Time stamp of the attitude sample, same clock as `step(t_s)`."""
    pitch_deviation_rad: float
    """Pitch minus the rest baseline, rad (< 0 when the fish pulls the tip down)."""
    pitch_rate_rad_s: float | None = None
    """d(pitch)/dt from the gyro, rad/s; None: differentiated from the deviation."""
    tension_n: float | None = None
    """Measured line tension from the reel status, N, if the reel has a load cell."""
    line_out_m: float | None = None
    """Line out from the reel status, m."""


@dataclass(frozen=True)
class ReelDecision:
    """A reel command: signed speed (> 0 reels in), the action it maps to, and why."""

    t_s: float
    speed_m_s: float
    action: ReelAction
    reason: Reason
    drag_n: float | None = None
    """Reel drag to set, N (None: leave it as it is)."""

    def command_fields(self) -> dict[str, float | str]:
        """Fields for `gateway.schemas.ReelCommand`: `speed` with the signed value, or `stop`; plus `drag_n`."""
        out: dict[str, float | str] = {"action": "stop"} if self.action == "stop" else {
            "action": "speed", "speed_m_s": self.speed_m_s}
        if self.drag_n is not None:
            out["drag_n"] = self.drag_n
        return out


class ReelPolicy(Protocol):
    """Anything that turns observations into reel decisions (controller or baseline)."""

    def step(self, t_s: float, obs: Observation | None) -> ReelDecision: ...


def _action(speed_m_s: float) -> ReelAction:
    return "in" if speed_m_s > 0.0 else "out" if speed_m_s < 0.0 else "stop"


@dataclass(frozen=True)
class FishWalkingSettings:
    """Thresholds in rad (θ2, θ3 as in `RodThresholds`, converted), speeds in m/s, times in s, loads in N."""

    theta2_rad: float = math.radians(20.0)
    theta3_rad: float = math.radians(35.0)
    line_breaking_n: float = 100.0
    setpoint_fraction: float = 0.95
    """Outer-loop setpoint as a share of θ2: just below the switch, so the fish works against a steady load."""
    max_in_m_s: float = 1.0
    max_out_m_s: float = 2.0
    cruise_in_m_s: float = 1.0
    """Feedforward reel-in speed added to the cascade while the bend is below its setpoint, m/s: the
    cascade then only trims around it, instead of winding its integral up from zero after every run."""
    min_payout_m_s: float = 0.0
    """Pay-out speed forced at or above θ2, m/s. 0: stop and let the drag give line (it is set to `drag_fraction`);
    paying out 0.3 m/s there gave line away on every burst and landed 10 % slower (docs/control.md)."""
    hold_fraction: float = 0.58
    payout_fraction: float = 0.75
    lookahead_s: float = 0.0
    """Bend-rate lookahead of the bend-based guard, s. 0 by default: 0.3 s made the guard pay out on every burst
    (the flat top of the bend curve maps a small predicted overshoot to a large tension) and landed 50 % slower
    without a load cell, while the drag already caps the tension (docs/control.md)."""
    attitude_timeout_s: float = 0.3
    measurement_filter_s: float = 0.2
    """First-order low-pass on bend and bend rate, s: keeps the rod's tip mode (≈ 2.5 Hz) out of the loops."""
    on_threshold_m_s: float = 0.08
    off_threshold_m_s: float = 0.03
    reverse_dwell_s: float = 0.15
    landed_line_m: float = 1.0
    drag_fraction: float | None = 0.6
    """Drag set while auto is on, as a share of the breaking load: the spool then slips before the line can
    break even while the motor reverses. (Anglers set 25-33 %; 60 % lands fish faster in the fight bench.)
    None: leave the drag alone."""
    trust_load_cell: bool = True
    """Tension guard on the load cell alone when the reel reports one. The bend is a poor tension gauge near θ2:
    under a tanh bend curve 50 % → 100 % of the breaking load is only a few degrees of bend, so tip ringing and
    0.3° attitude noise trip a bend-based guard at loads the drag already caps (docs/control.md)."""
    guard_on_raw_bend: bool = False
    """Without a load cell, let the raw (unfiltered) bend trip the tension guard too, not only the filtered one.
    Off by default: on a tanh bend curve tip ringing alone reaches the guard level (see `trust_load_cell`)."""
    tension_curve: tuple[tuple[float, float], ...] | None = None
    """Rod calibration: (bend rad, tension N) pairs, bend increasing (e.g. from hanging known weights);
    None: linear, with bend θ3 at the breaking load."""
    angle: PidSettings = PidSettings(kp=1.0, ki=0.0, kd=0.0, output_min=-4.0, output_max=4.0)
    """Outer loop: bend error (rad) → bend-rate setpoint (rad/s).

    The gains are low on purpose: with a taut, stiff line (300 N/m in `devices.rod_physics`) reel speed → bend
    is an integrator of gain ≈ 5-20 rad per m of line, so the effective angle gain kp_i·kp_o + ki_i ≈ 0.2 m/s
    per rad puts the crossover at ≈ 1-4 rad/s, under the tip mode (≈ 16 rad/s) and the motor lag (0.15 s).
    Ten times more made the loop snatch the line in a 3 Hz limit cycle (docs/control.md, the search)."""
    rate: PidSettings = PidSettings(kp=0.03, ki=0.2, kd=0.0)
    """Inner loop: bend-rate error (rad/s) → reel-in speed (m/s); its output limits are set to the reel's speeds."""

    def __post_init__(self) -> None:
        if not 0.0 < self.theta2_rad < self.theta3_rad:
            raise ValueError("need 0 < theta2 < theta3")
        if not 0.0 < self.hold_fraction < self.payout_fraction < 1.0:
            raise ValueError("need 0 < hold_fraction < payout_fraction < 1")
        if self.off_threshold_m_s > self.on_threshold_m_s:
            raise ValueError("off threshold must not exceed on threshold (hysteresis)")
        if self.tension_curve is not None:
            xs = [p[0] for p in self.tension_curve]
            if len(xs) < 2 or any(b <= a for a, b in zip(xs, xs[1:], strict=False)):
                raise ValueError("tension_curve needs >= 2 points with strictly increasing bend")


def estimated_tension_n(s: FishWalkingSettings, bend_rad: float, measured_n: float | None) -> float:
    """T̂ = max(measured, T(β)): T(β) from the rod's calibration curve, else linear with T(θ3) = breaking load.

    Beyond the last calibration point the curve is extended by its last slope (never flattened), so an
    over-bent rod reads as more load, not less.
    """
    b = max(bend_rad, 0.0)
    if s.tension_curve is None:
        from_bend = s.line_breaking_n * b / s.theta3_rad
    else:
        xs = [p[0] for p in s.tension_curve]
        ys = [p[1] for p in s.tension_curve]
        if b <= xs[-1]:
            from_bend = float(np.interp(b, xs, ys))
        else:
            slope = (ys[-1] - ys[-2]) / (xs[-1] - xs[-2])
            from_bend = ys[-1] + slope * (b - xs[-1])
    return from_bend if measured_n is None else max(measured_n, from_bend)


@dataclass
class FishWalkingController:
    """Cascade fish-walking controller with safety layers; pure: `step(t_s, obs) -> ReelDecision`."""

    settings: FishWalkingSettings = field(default_factory=FishWalkingSettings)
    enabled: bool = True
    cascade: Cascade = field(init=False)
    _manual_speed_m_s: float | None = field(default=None, init=False)
    _last_obs: Observation | None = field(default=None, init=False)
    _last_t_s: float | None = field(default=None, init=False)
    _last_bend_rad: float | None = field(default=None, init=False)
    _direction: ReelAction = field(default="stop", init=False)
    _direction_since_s: float = field(default=-math.inf, init=False)
    _bend_f: float | None = field(default=None, init=False)
    _rate_f: float = field(default=0.0, init=False)
    _guard: bool = field(default=False, init=False)

    def __post_init__(self) -> None:
        s = self.settings
        # The inner loop's limits are the reel's speeds, so its anti-windup knows the real actuator range.
        rate = replace(s.rate, output_min=-s.max_out_m_s, output_max=s.max_in_m_s)
        self.cascade = Cascade(CascadeSettings(s.angle, rate))

    # -- operator interface -------------------------------------------------------------------------------
    def manual(self, speed_m_s: float) -> None:
        """The angler takes over at `speed_m_s` (signed, > 0 in; 0 = stop); auto stays off until `enable()`."""
        self._manual_speed_m_s = speed_m_s
        self.enabled = False

    def enable(self) -> None:
        """Hand control back to auto, from a clean state (cascade reset, stopped)."""
        self._manual_speed_m_s = None
        self.enabled = True
        self.cascade.reset(0.0)
        self._last_t_s = self._last_bend_rad = self._bend_f = None
        self._rate_f, self._guard = 0.0, False
        self._direction, self._direction_since_s = "stop", -math.inf

    def disable(self) -> None:
        """Auto off, motor stopped (no manual command)."""
        self._manual_speed_m_s = None
        self.enabled = False

    # -- control ------------------------------------------------------------------------------------------
    def step(self, t_s: float, obs: Observation | None) -> ReelDecision:
        """One control tick at `t_s`; `obs` is the newest observation, or None when nothing new arrived."""
        s = self.settings
        if obs is not None:
            self._last_obs = obs
        if self._manual_speed_m_s is not None:
            return self._emit(t_s, self._manual_speed_m_s, "manual", force=True)
        if not self.enabled:
            return self._emit(t_s, 0.0, "disabled", force=True)
        last = self._last_obs
        if last is None or t_s - last.attitude_t_s > s.attitude_timeout_s:
            self._last_t_s = self._bend_f = None  # the next fresh sample restarts dt, filters and the derivative
            return self._emit(t_s, 0.0, "timeout", force=True)
        if last.line_out_m is not None and last.line_out_m <= s.landed_line_m:
            return self._emit(t_s, 0.0, "landed", force=True)

        raw_bend = -last.pitch_deviation_rad
        raw_rate = self._bend_rate(last, raw_bend)
        dt_s = t_s - self._last_t_s if self._last_t_s is not None else 0.0
        self._last_t_s = t_s
        if dt_s > 0.0 and self._bend_f is not None:
            a = dt_s / (s.measurement_filter_s + dt_s)
            self._bend_f += a * (raw_bend - self._bend_f)
            self._rate_f += a * (raw_rate - self._rate_f)
            cruise = s.cruise_in_m_s if self._bend_f < s.setpoint_fraction * s.theta2_rad else 0.0
            speed = self.cascade.update(s.setpoint_fraction * s.theta2_rad, self._bend_f, self._rate_f, dt_s, cruise)
        else:
            self._bend_f, self._rate_f = raw_bend, raw_rate
            speed = 0.0
        bend, bend_rate = self._bend_f, self._rate_f
        speed = min(max(speed, -s.max_out_m_s), s.max_in_m_s)

        # Filtered bend extrapolated by the lookahead; the raw bend as it is (raw rates are mostly tip ringing
        # when a slack line snaps taut, and tripping on them paid out line for nothing).
        bend_pred = bend + max(bend_rate, 0.0) * s.lookahead_s
        bend_pred = max(bend_pred, raw_bend) if s.guard_on_raw_bend else bend_pred
        if last.tension_n is not None and s.trust_load_cell:
            tension = last.tension_n
        else:
            tension = estimated_tension_n(s, bend_pred, None)
        # Guard with hysteresis: trips at payout_fraction, releases only below hold_fraction.
        release = s.hold_fraction * s.line_breaking_n
        was_guarded = self._guard
        self._guard = tension >= s.payout_fraction * s.line_breaking_n or (self._guard and tension >= release)
        if self._guard:
            return self._emit(t_s, -s.max_out_m_s, "tension_guard", force=True)
        if was_guarded:  # restart the loops from standstill, not from the guard's full pay-out
            self.cascade.reset(0.0)
            speed = 0.0
        reason: Reason = "cascade"
        if tension >= release and speed > 0.0:
            speed, reason = 0.0, "tension_hold"
        at_cap = max(bend, raw_bend) >= s.theta2_rad  # raw too: a spike never reels in
        if at_cap and speed > -s.min_payout_m_s:
            speed, reason = -s.min_payout_m_s, "theta2_cap"
        # at θ2 no reversal dwell: the cascade's own pay-out there was held to a stop when it came within
        # `reverse_dwell_s` of reeling in (found by hypothesis: bend 0.375 rad at 3 rad/s, then 1.0 rad)
        return self._emit(t_s, speed, reason, force=at_cap)

    def _bend_rate(self, obs: Observation, bend: float) -> float:
        if obs.pitch_rate_rad_s is not None:
            rate = -obs.pitch_rate_rad_s
        elif self._last_bend_rad is not None and self._last_t_s is not None and obs.attitude_t_s > self._last_t_s:
            rate = (bend - self._last_bend_rad) / (obs.attitude_t_s - self._last_t_s)
        else:
            rate = 0.0
        self._last_bend_rad = bend
        return rate

    def _emit(self, t_s: float, speed: float, reason: Reason, *, force: bool) -> ReelDecision:
        """Apply direction hysteresis and reversal dwell (unless `force`), remember the direction, decide."""
        s = self.settings
        if not force:
            cur = self._direction
            want = _action(speed)
            threshold = s.off_threshold_m_s if want == cur else s.on_threshold_m_s
            if abs(speed) < threshold:
                want, speed = "stop", 0.0
            if cur != "stop" and want not in (cur, "stop") and t_s - self._direction_since_s < s.reverse_dwell_s:
                want, speed, reason = "stop", 0.0, "hysteresis"
        action = _action(speed)
        if action != self._direction:
            self._direction, self._direction_since_s = action, t_s
        auto = reason not in ("manual", "disabled")
        drag = s.drag_fraction * s.line_breaking_n if auto and s.drag_fraction is not None else None
        return ReelDecision(t_s, speed, action, reason, drag)


@dataclass
class DragOnly:
    """Baseline: no control at all; the reel stays stopped and only its drag slips line."""

    def step(self, t_s: float, obs: Observation | None) -> ReelDecision:
        """Always stop."""
        return ReelDecision(t_s, 0.0, "stop", "baseline")


@dataclass
class BangBang:
    """Baseline: the paper's θ2 rule taken literally, full speed in below θ2 and full speed out above it."""

    theta2_rad: float = math.radians(20.0)
    max_in_m_s: float = 1.0
    max_out_m_s: float = 2.0
    landed_line_m: float = 1.0
    _last: Observation | None = field(default=None, init=False)

    def step(self, t_s: float, obs: Observation | None) -> ReelDecision:
        """Full in / full out by the sign of θ2 − bend on the newest data; stop once landed or before any data."""
        self._last = obs if obs is not None else self._last
        last = self._last
        if last is None or (last.line_out_m is not None and last.line_out_m <= self.landed_line_m):
            return ReelDecision(t_s, 0.0, "stop", "baseline")
        speed = self.max_in_m_s if -last.pitch_deviation_rad < self.theta2_rad else -self.max_out_m_s
        return ReelDecision(t_s, speed, _action(speed), "baseline")
