"""Bite and drop-back detection from rod-tip pitch (seed 000 §3.3 and §4.2), one block of samples at a time.

A bite pulls the tip down: pitch falls by >= theta1 below its rest value (the paper: 10 deg, adjustable).
A drop-back (fish swims towards the angler) slackens the line: the tip springs up above rest.
Roll and yaw never alarm (seed 000 Table 2): pitch = elevation of the rod axis, which neither changes.

Per block, all work is vectorised with numpy; Python does O(1) work plus one loop turn per latch change.

- Warm-up: the first WARMUP_S seconds only learn the rest pitch (their mean) and the vibration level. A block
  that spans the end of the warm-up is split there: its head learns, its tail is already checked for bites.
- Rest baseline: an exponential average (time constant `baseline_tau_s`) of block-mean pitch, updated only
  while both latches are armed and every sample of the block lies inside the re-arm band. Vibration (wind,
  waves) averages out; a holder drifting at r deg/s lags by only r * tau, far below theta1 for slow drifts.
- Bite: deviation <= -theta1 held for `confirm_s` (the sensitivity step), or sooner by the acceleration cue:
  deviation <= -cue_fraction * theta1 while the 30 ms mean of the tip's upward acceleration is below
  -max(cue_acc, CUE_NOISE_FACTOR * recent rms). For any free oscillation about rest, displacement and
  acceleration are in anti-phase (a = -w^2 x): a tip below rest accelerates *upwards*, so zero-mean vibration
  cannot meet the cue while a bite's onset can. Forced motion (gusts) breaks the anti-phase, hence the rms bar:
  in wind the cue backs off and the pitch rule alone decides.
- Drop-back: deviation >= drop_back held for `confirm_s`.
- Hysteresis: each latch fires once, then re-arms only after the deviation has stayed inside the re-arm band
  (REARM_FRACTION of its threshold) for `rearm_quiet_s`. Detection time = time of the triggering sample.
- If the rod settles at a new rest (e.g. re-cast) while disarmed, the baseline is re-taken after
  REBASELINE_FACTOR * rearm_quiet_s of steady pitch, so the detector does not stay disarmed forever.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace
from typing import Literal

import numpy as np
from numpy.typing import NDArray

from gateway.config import SENSITIVITY_STEPS, RodThresholds

FloatArray = NDArray[np.float64]
BoolArray = NDArray[np.bool_]

REARM_FRACTION = 0.7  # re-arm band: |deviation| below this share of the trigger threshold
ACC_WINDOW = 3  # samples averaged for the acceleration cue (30 ms at 100 Hz)
CUE_NOISE_FACTOR = 3.0  # the cue needs a downward acceleration >= this x the recent rms (wind raises the bar)
ACC_RMS_DECAY_S = 3.0  # the rms estimate rises at once and decays with this time constant
ACC_RMS_LAG_S = 0.5  # the cue uses an rms estimate 0.5-1 s old, so a bite's own onset cannot raise the bar
WARMUP_S = 2.0  # the first 2 s only learn the rest pitch (mean) and the vibration level: no alarms
REBASELINE_FACTOR = 6.0  # steady this many quiet times while disarmed -> new rest baseline
STEADY_FRACTION = 0.3  # "steady": block mean within this share of theta1 of the candidate rest
_EPS_S = 1e-9

EventKind = Literal["bite", "bite_rearmed", "drop_back", "drop_back_rearmed"]


@dataclass(frozen=True, slots=True)
class BiteParams:
    """Thresholds in radians and seconds, derived once from `RodThresholds`."""

    bite_rad: float
    confirm_s: float
    cue_rad: float  # inf = cue off
    cue_acc_m_s2: float
    drop_back_rad: float
    rearm_quiet_s: float
    baseline_tau_s: float

    @classmethod
    def from_thresholds(cls, th: RodThresholds) -> BiteParams:
        """Apply the sensitivity step (config.SENSITIVITY_STEPS) to theta1, confirmation and the cue."""
        _, confirm_s, cue_fraction, cue_acc = SENSITIVITY_STEPS[th.sensitivity]
        bite_rad = math.radians(th.effective_bite_deg)
        return cls(
            bite_rad=bite_rad,
            confirm_s=confirm_s,
            cue_rad=cue_fraction * bite_rad if cue_fraction > 0 else math.inf,
            cue_acc_m_s2=cue_acc,
            drop_back_rad=math.radians(th.drop_back_rise_deg),
            rearm_quiet_s=th.rearm_quiet_s,
            baseline_tau_s=th.baseline_tau_s,
        )


@dataclass(frozen=True, slots=True)
class RodEvent:
    """A latch change: the time is that of the sample that caused it."""

    kind: EventKind
    t_s: float
    deviation_rad: float
    threshold_rad: float
    cue: Literal["pitch", "accel", ""] = ""


@dataclass(frozen=True, slots=True)
class RodBlock:
    """Result of one block: latch events plus the deviation summary the line guard needs."""

    events: tuple[RodEvent, ...]
    baseline_rad: float  # the rest pitch the block's deviations were measured from
    min_deviation_rad: float  # most negative deviation (largest drop) in the block
    t_min_s: float  # time of that sample
    last_deviation_rad: float


@dataclass(slots=True)
class BiteState:
    """Mutable detector state; every `*_s` is a device time."""

    baseline_rad: float = math.nan
    bite_armed: bool = True
    drop_armed: bool = True
    bite_disarmed_at_s: float = -math.inf
    drop_disarmed_at_s: float = -math.inf
    bite_run_s: float = math.nan  # start of a beyond-theta1 run still open at the last block's end
    drop_run_s: float = math.nan
    near_bite_run_s: float = math.nan  # start of an open in-re-arm-band run
    near_drop_run_s: float = math.nan
    last_t_s: float = math.nan
    acc_tail: FloatArray = field(default_factory=lambda: np.zeros(0))
    acc_ms: float = 0.0  # recent mean-square vertical acceleration, (m/s^2)^2: fast attack, slow decay
    acc_ms_snapshot: float = 0.0  # acc_ms at the last checkpoint
    acc_ms_lagged: float = 0.0  # acc_ms at the checkpoint before: what the cue uses
    acc_checkpoint_s: float = -math.inf
    steady_ref_rad: float = math.nan
    steady_since_s: float = math.nan
    warmed: bool = False
    warm_until_s: float = math.nan
    warm_sum_rad: float = 0.0
    warm_n: int = 0


def tip_acc_up(quat_wxyz: FloatArray, acc_m_s2: FloatArray, g_m_s2: float = 9.81) -> FloatArray:
    """Earth-frame vertical (ENU z) acceleration of the IMU, gravity removed (m/s^2, up > 0), shape (...,).

    Rotates the body specific force by the body->earth quaternion (third row of R(q)) and subtracts g.
    """
    w, x, y, z = (quat_wxyz[..., i] for i in range(4))
    up: FloatArray = (2 * (x * z - w * y) * acc_m_s2[..., 0] + 2 * (y * z + w * x) * acc_m_s2[..., 1]
                      + (w * w - x * x - y * y + z * z) * acc_m_s2[..., 2] - g_m_s2)  # fmt: skip
    return up


def run_starts(cond: BoolArray, t_s: FloatArray, carry_s: float) -> FloatArray:
    """Start time of the run of True containing each sample (nan where False).

    `carry_s` is the start of a run still open at the end of the previous block (nan if none).
    """
    n = cond.size
    last_false = np.maximum.accumulate(np.where(cond, -1, np.arange(n)))
    starts = t_s[np.minimum(last_false + 1, n - 1)]
    head = t_s[0] if math.isnan(carry_s) else carry_s
    return np.where(cond, np.where(last_false < 0, head, starts), np.nan)


def near_runs(near: BoolArray, all_near: bool, t_s: FloatArray, carry_s: float) -> tuple[BoolArray, FloatArray, float]:
    """(mask, run starts, carry) for the re-arm band; a block entirely inside it needs no run search."""
    if all_near:
        start = float(t_s[0]) if math.isnan(carry_s) else carry_s
        return near, np.full(t_s.size, start), start
    starts = run_starts(near, t_s, carry_s)
    return near, starts, float(starts[-1])


def held(cond: BoolArray, t_s: FloatArray, carry_s: float, hold_s: float) -> tuple[BoolArray, float]:
    """Samples where `cond` has held for >= hold_s, and the open run's start to carry to the next block."""
    starts = run_starts(cond, t_s, carry_s)
    with np.errstate(invalid="ignore"):
        ok = t_s - starts >= hold_s - _EPS_S
    return ok, float(starts[-1])


def trailing_mean(x: FloatArray, tail: FloatArray, window: int) -> tuple[FloatArray, FloatArray]:
    """Mean of each sample and the window-1 before it (continuing across blocks via `tail`); returns new tail."""
    full = np.concatenate((tail, x))
    c = np.concatenate(([0.0], np.cumsum(full)))
    k = np.arange(tail.size + 1, full.size + 1)
    lo = np.maximum(k - window, 0)
    return (c[k] - c[lo]) / (k - lo), full[-(window - 1) :] if window > 1 else full[:0]


def keep_tail(tail: FloatArray, x: FloatArray, k: int) -> FloatArray:
    """The last k samples of tail + x (k >= 0)."""
    if k <= 0:
        return x[:0]
    return x[-k:] if x.size >= k else np.concatenate((tail, x))[-k:]


def _or_none(mask: BoolArray | None, n: int) -> BoolArray:
    return np.zeros(n, dtype=bool) if mask is None else mask


def latch_step(
    armed: bool,
    disarmed_at_s: float,
    trig: BoolArray,
    near: BoolArray,
    near_starts: FloatArray,
    t_s: FloatArray,
    quiet_s: float,
) -> tuple[bool, float, list[tuple[bool, int]]]:
    """Walk one latch through a block: fire on the first `trig` sample while armed; re-arm once `near` has held
    for `quiet_s` counted from no earlier than the firing. Returns (armed, disarmed_at_s, [(rearmed?, index)])."""
    out: list[tuple[bool, int]] = []
    pos, n = 0, t_s.size
    while pos < n:
        if armed:
            hits = np.flatnonzero(trig[pos:])
            if hits.size == 0:
                break
            k = pos + int(hits[0])
            armed, disarmed_at_s = False, float(t_s[k])
            out.append((False, k))
        else:
            with np.errstate(invalid="ignore"):
                ok = near[pos:] & (t_s[pos:] - np.maximum(near_starts[pos:], disarmed_at_s) >= quiet_s - _EPS_S)
            hits = np.flatnonzero(ok)
            if hits.size == 0:
                break
            k = pos + int(hits[0])
            armed = True
            out.append((True, k))
        pos = k + 1
    return armed, disarmed_at_s, out


class BiteDetector:
    """Per-rod bite / drop-back detector; feed consecutive blocks in time order."""

    def __init__(self, thresholds: RodThresholds | None = None) -> None:
        self.params = BiteParams.from_thresholds(thresholds or RodThresholds())
        self.state = BiteState()

    def set_thresholds(self, thresholds: RodThresholds) -> None:
        """Change thresholds live; the baseline and latches are kept."""
        self.params = BiteParams.from_thresholds(thresholds)

    def rebaseline(self, pitch_rad: float) -> None:
        """Take `pitch_rad` as the new rest (e.g. the angler re-set the rod) and re-arm both latches."""
        self.state = BiteState(baseline_rad=pitch_rad, warmed=True)

    def update(
        self,
        t_s: FloatArray,
        pitch_rad: FloatArray,
        roll_rad: FloatArray | None = None,
        yaw_rad: FloatArray | None = None,
        acc_up_m_s2: FloatArray | None = None,
    ) -> RodBlock:
        """Process one block, shapes (n,): device times, fused pitch (tip up > 0), and optionally the tip's
        earth-frame vertical acceleration with gravity removed (m/s^2, up > 0) for the cue.

        Roll and yaw are accepted so callers pass the whole attitude, and deliberately unused: rotating the rod
        about its own axis or turning it in the holder is not a bite (seed 000 Table 2).
        """
        del roll_rad, yaw_rad
        s = self.state
        if t_s.size == 0:
            return RodBlock((), s.baseline_rad, 0.0, math.nan, 0.0)
        if s.warmed:
            return self._detect(t_s, pitch_rad, acc_up_m_s2)
        # Warm-up ends inside this block: learn from its head, detect on the rest (a burst may hold both).
        if math.isnan(s.warm_until_s):
            s.warm_until_s = float(t_s[0]) + WARMUP_S
        end = min(int(np.searchsorted(t_s, s.warm_until_s - _EPS_S)) + 1, t_s.size)
        head = self._warm_up(t_s[:end], pitch_rad[:end], None if acc_up_m_s2 is None else acc_up_m_s2[:end])
        if end == t_s.size:
            return head
        tail_acc = None if acc_up_m_s2 is None else acc_up_m_s2[end:]
        if not s.warmed:  # no finite pitch yet: keep learning
            return self._warm_up(t_s[end:], pitch_rad[end:], tail_acc)
        rest = self._detect(t_s[end:], pitch_rad[end:], tail_acc)
        head_dev = pitch_rad[:end] - rest.baseline_rad
        if np.isfinite(head_dev).any() and float(np.nanmin(head_dev)) < rest.min_deviation_rad:
            i = int(np.nanargmin(head_dev))
            return replace(rest, min_deviation_rad=float(head_dev[i]), t_min_s=float(t_s[i]))
        return rest

    def _detect(self, t_s: FloatArray, pitch_rad: FloatArray, acc_up_m_s2: FloatArray | None) -> RodBlock:
        """One non-empty block after the warm-up: latches, events, baseline tracking."""
        p, s = self.params, self.state
        n = t_s.size
        dev = pitch_rad - s.baseline_rad
        i_min = int(dev.argmin())
        lo, hi = float(dev[i_min]), float(dev.max())
        # Quiet blocks (the common case) skip every mask: only min, max and mean are computed.
        cue = None
        if acc_up_m_s2 is not None:
            if lo <= -p.cue_rad and s.bite_armed:
                acc_mean, s.acc_tail = trailing_mean(acc_up_m_s2, s.acc_tail, ACC_WINDOW)
                need = max(p.cue_acc_m_s2, CUE_NOISE_FACTOR * math.sqrt(s.acc_ms_lagged))
                cue = (dev <= -p.cue_rad) & (acc_mean <= -need)
            else:
                s.acc_tail = keep_tail(s.acc_tail, acc_up_m_s2, ACC_WINDOW - 1)
            self._track_acc(t_s, acc_up_m_s2)
        bite_ok = None
        if lo <= -p.bite_rad:
            bite_ok, s.bite_run_s = held(dev <= -p.bite_rad, t_s, s.bite_run_s, p.confirm_s)
        else:
            s.bite_run_s = math.nan
        drop_ok = None
        if hi >= p.drop_back_rad:
            drop_ok, s.drop_run_s = held(dev >= p.drop_back_rad, t_s, s.drop_run_s, p.confirm_s)
        else:
            s.drop_run_s = math.nan

        events: list[RodEvent] = []
        bite_trig = bite_ok if cue is None else cue if bite_ok is None else bite_ok | cue
        near_lo = -REARM_FRACTION * p.bite_rad
        if not s.bite_armed and hi <= near_lo:
            s.near_bite_run_s = math.nan  # still pulled down: nothing can re-arm in this block
        elif not s.bite_armed or (bite_trig is not None and bite_trig.any()):
            near, starts, s.near_bite_run_s = near_runs(dev > near_lo, lo > near_lo, t_s, s.near_bite_run_s)
            s.bite_armed, s.bite_disarmed_at_s, changes = latch_step(
                s.bite_armed, s.bite_disarmed_at_s, _or_none(bite_trig, n), near, starts, t_s, p.rearm_quiet_s
            )
            for rearmed, k in changes:
                if rearmed:
                    events.append(RodEvent("bite_rearmed", float(t_s[k]), float(dev[k]), -p.bite_rad))
                elif bite_ok is not None and bite_ok[k]:
                    events.append(RodEvent("bite", float(t_s[k]), float(dev[k]), -p.bite_rad, "pitch"))
                else:
                    events.append(RodEvent("bite", float(t_s[k]), float(dev[k]), -p.cue_rad, "accel"))
        near_hi = REARM_FRACTION * p.drop_back_rad
        if not s.drop_armed and lo >= near_hi:
            s.near_drop_run_s = math.nan
        elif not s.drop_armed or (drop_ok is not None and drop_ok.any()):
            near, starts, s.near_drop_run_s = near_runs(dev < near_hi, hi < near_hi, t_s, s.near_drop_run_s)
            s.drop_armed, s.drop_disarmed_at_s, changes = latch_step(
                s.drop_armed, s.drop_disarmed_at_s, _or_none(drop_ok, n), near, starts, t_s, p.rearm_quiet_s
            )
            for rearmed, k in changes:
                kind: EventKind = "drop_back_rearmed" if rearmed else "drop_back"
                events.append(RodEvent(kind, float(t_s[k]), float(dev[k]), p.drop_back_rad, "" if rearmed else "pitch"))
        if len(events) > 1:
            events.sort(key=lambda e: e.t_s)

        used = s.baseline_rad
        self._track_baseline(t_s, pitch_rad, lo, hi)
        return RodBlock(tuple(events), used, lo, float(t_s[i_min]), float(dev[-1]))

    def _warm_up(self, t_s: FloatArray, pitch_rad: FloatArray, acc_up_m_s2: FloatArray | None) -> RodBlock:
        """Learn the rest pitch as the mean of the first WARMUP_S seconds (nan samples skipped); no alarms."""
        s = self.state
        ok = pitch_rad[np.isfinite(pitch_rad)]
        s.warm_sum_rad += float(np.add.reduce(ok))
        s.warm_n += ok.size
        if s.warm_n:
            s.baseline_rad = s.warm_sum_rad / s.warm_n
        if acc_up_m_s2 is not None:
            s.acc_tail = keep_tail(s.acc_tail, acc_up_m_s2, ACC_WINDOW - 1)
            self._track_acc(t_s, acc_up_m_s2)
        s.last_t_s = float(t_s[-1])
        s.warmed = s.warm_n > 0 and s.last_t_s >= s.warm_until_s
        dev = pitch_rad - s.baseline_rad
        return RodBlock(
            (), s.baseline_rad, float(np.nanmin(dev)) if ok.size else math.nan, float(t_s[0]), float(dev[-1])
        )

    def _track_acc(self, t_s: FloatArray, acc_up_m_s2: FloatArray) -> None:
        """Vibration level for the cue's bar: mean square with fast attack and ACC_RMS_DECAY_S decay, lagged."""
        s, n = self.state, t_s.size
        block_ms = float(np.dot(acc_up_m_s2, acc_up_m_s2)) / n
        if not math.isfinite(block_ms):
            return
        span_s = float(t_s[-1] - t_s[0]) * n / max(n - 1, 1)
        s.acc_ms = max(block_ms, s.acc_ms * math.exp(-span_s / ACC_RMS_DECAY_S))
        if t_s[-1] - s.acc_checkpoint_s >= ACC_RMS_LAG_S:
            s.acc_ms_lagged, s.acc_ms_snapshot = s.acc_ms_snapshot, s.acc_ms
            s.acc_checkpoint_s = float(t_s[-1])

    def _track_baseline(self, t_s: FloatArray, pitch_rad: FloatArray, lo: float, hi: float) -> None:
        """Follow the rest pitch while quiet and armed; re-take it after a long steady spell while disarmed."""
        p, s = self.params, self.state
        t_end = float(t_s[-1])
        dt_s = t_end - s.last_t_s if not math.isnan(s.last_t_s) else t_end - float(t_s[0])
        s.last_t_s = t_end
        mean = float(np.add.reduce(pitch_rad)) / pitch_rad.size
        if not math.isfinite(mean):
            return  # a block with gaps (nan) never moves the baseline
        if s.bite_armed and s.drop_armed:
            s.steady_since_s = math.nan
            if lo > -REARM_FRACTION * p.bite_rad and hi < REARM_FRACTION * p.drop_back_rad:
                s.baseline_rad += (1.0 - math.exp(-max(dt_s, 0.0) / p.baseline_tau_s)) * (mean - s.baseline_rad)
            return
        if math.isnan(s.steady_since_s) or abs(mean - s.steady_ref_rad) > STEADY_FRACTION * p.bite_rad:
            s.steady_ref_rad, s.steady_since_s = mean, float(t_s[0])
            return
        s.steady_ref_rad += 0.1 * (mean - s.steady_ref_rad)
        if t_end - s.steady_since_s >= REBASELINE_FACTOR * max(p.rearm_quiet_s, 1.0):
            s.baseline_rad, s.steady_since_s = s.steady_ref_rad, math.nan
