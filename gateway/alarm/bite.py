"""Bite and drop-back detection from rod-tip pitch (seed 000 §3.3 and §4.2), sample by sample, fed in blocks.

A bite pulls the tip down: pitch falls by >= theta1 below its rest value (the paper: 10 deg, adjustable).
A drop-back (fish swims towards the angler) slackens the line: the tip springs up above rest.
Roll and yaw never alarm (seed 000 Table 2): pitch = elevation of the rod axis, which neither changes.

Decisions depend only on the samples and the settings, never on how they were cut into blocks (packet size,
bursts, batches): every threshold test is per sample, runs and latches carry across blocks, and the slow state
(rest baseline, vibration level, new-rest search) moves only at the end of fixed FRAME_S frames of device time
counted from the first sample, from that frame's samples alone. A sample is judged against the state left by
the frames before its own, so splitting a block anywhere changes nothing.

- Warm-up: the first WARMUP_FRAMES frames (2 s) only learn the rest pitch (their mean) and the vibration level.
- Rest baseline: an exponential average (time constant `baseline_tau_s`) of frame-mean pitch, updated only
  while both latches are armed and every sample of the frame lies inside the re-arm band. Vibration (wind,
  waves) averages out; a holder drifting at r deg/s lags by only r * tau, far below theta1 for slow drifts.
- Bite (theta1 is a floor): the deviation must reach -theta1; the alarm fires once it has held there for
  `confirm_s` (the sensitivity step). The acceleration cue can only shorten that confirmation: a sample at or
  beyond -theta1 fires at once if within the last CUE_HOLD_S the tip, already cue_fraction * theta1 below rest,
  accelerated downwards by more than max(cue_acc, CUE_NOISE_FACTOR * recent rms) (30 ms mean). For any free
  oscillation about rest displacement and acceleration are in anti-phase (a = -w^2 x), so a tip below rest
  accelerates *upwards*: vibration rarely meets the cue, a pull does; either way it never fires below theta1.
- Drop-back: deviation >= drop_back held for DROP_BACK_HOLD_S (longer than the ringing of a released bite).
- Hysteresis: each latch fires once, then re-arms only after the deviation has stayed inside the re-arm band
  (REARM_FRACTION of its threshold) for `rearm_quiet_s`. Detection time = time of the triggering sample.
- If the rod settles at a new rest (e.g. re-cast) while disarmed, the baseline is re-taken after
  REBASELINE_FACTOR * rearm_quiet_s of steady pitch, so the detector does not stay disarmed forever.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Literal

import numpy as np
from numpy.typing import NDArray

from gateway.config import SENSITIVITY_STEPS, RodThresholds

FloatArray = NDArray[np.float64]
BoolArray = NDArray[np.bool_]

FRAME_S = 0.1  # the slow state moves at the end of each frame of this much device time
WARMUP_FRAMES = 20  # the first 2 s only learn the rest pitch (mean) and the vibration level: no alarms
REARM_FRACTION = 0.7  # re-arm band: |deviation| below this share of the trigger threshold
ACC_WINDOW = 3  # samples averaged for the acceleration cue (30 ms at 100 Hz)
CUE_NOISE_FACTOR = 3.0  # the cue needs a downward acceleration >= this x the recent rms (wind raises the bar)
CUE_HOLD_S = 0.3  # a cue this recent lets a sample at -theta1 fire without waiting for `confirm_s`
ACC_RMS_DECAY_S = 3.0  # the rms estimate rises at once and decays with this time constant
ACC_RMS_LAG_FRAMES = 5  # the cue uses an rms estimate 0.5-1 s old, so a bite's own onset cannot raise the bar
DROP_BACK_HOLD_S = 0.5  # a drop-back must hold this long: a released bite rings above rest for less
REBASELINE_FACTOR = 6.0  # steady this many quiet times while disarmed -> new rest baseline
STEADY_FRACTION = 0.3  # "steady": frame mean within this share of theta1 of the candidate rest
_EPS_S = 1e-9
_FRAME_EPS = 1e-6  # frame index rounding guard: sample times of the same sample may differ in the last bits

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
    """A latch change: the time is that of the sample that caused it.

    `deviation_rad` is that sample's deviation from rest; on a re-arm, `peak_rad` is the largest deviation (signed,
    in the latch's direction) between the firing and the re-arm."""

    kind: EventKind
    t_s: float
    deviation_rad: float
    threshold_rad: float
    cue: Literal["pitch", "accel", ""] = ""
    peak_rad: float = 0.0


@dataclass(slots=True)  # not frozen: a frozen dataclass's __init__ costs about 1 µs more, once per rod per batch
class RodBlock:
    """Result of one block: latch events plus the per-sample deviations the line guard needs."""

    events: tuple[RodEvent, ...]
    baseline_rad: float  # the rest pitch at the block's end
    deviation_rad: FloatArray  # per sample, from the rest in force at that sample; nan during the warm-up
    min_deviation_rad: float  # most negative deviation (largest drop) in the block (nan: none yet)
    t_min_s: float  # time of that sample


@dataclass(slots=True)
class BiteState:
    """Mutable detector state; every `*_s` is a device time."""

    baseline_rad: float = math.nan
    bite_armed: bool = True
    drop_armed: bool = True
    bite_disarmed_at_s: float = -math.inf
    drop_disarmed_at_s: float = -math.inf
    bite_peak_rad: float = 0.0  # deepest deviation since the bite latch fired
    drop_peak_rad: float = 0.0  # highest deviation since the drop-back latch fired
    bite_run_s: float = math.nan  # start of a beyond-theta1 run still open at the last block's end
    drop_run_s: float = math.nan
    near_bite_run_s: float = math.nan  # start of an open in-re-arm-band run
    near_drop_run_s: float = math.nan
    last_cue_s: float = -math.inf  # time of the latest cue sample
    acc_tail: FloatArray = field(default_factory=lambda: np.zeros(0))
    acc_ms: float = 0.0  # recent mean-square vertical acceleration, (m/s^2)^2: fast attack, slow decay
    acc_ms_snapshot: float = 0.0  # acc_ms at the last checkpoint
    acc_ms_lagged: float = 0.0  # acc_ms at the checkpoint before: what the cue uses
    acc_checkpoint_k: int = -(10**9)
    steady_ref_rad: float = math.nan
    steady_since_s: float = math.nan
    warmed: bool = False
    warm_sum_rad: float = 0.0
    warm_n: int = 0
    origin_s: float = math.nan  # time of the first sample: frame k covers [origin + k FRAME_S, + FRAME_S)
    frame_k: int = -1  # the open frame
    closed_k: int = -1  # the last frame closed
    frame_pitch: list[FloatArray] = field(default_factory=list)  # the open frame's samples, as fed
    frame_acc: list[FloatArray] = field(default_factory=list)
    frame_t0_s: float = math.nan
    frame_lo_rad: float = math.inf  # lowest and highest deviation of the open frame's samples (after the warm-up)
    frame_hi_rad: float = -math.inf


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
    """Mean of each sample and the window-1 before it (continuing across blocks via `tail`); returns new tail.

    Summed term by term in a fixed order, so a sample's mean is bit-identical however the stream is cut. Before
    `window` samples exist, the first sample stands in for the missing ones."""
    full = np.concatenate((tail, x))
    if full.size < x.size + window - 1:
        full = np.concatenate((np.full(x.size + window - 1 - full.size, full[0]), full))
    total = full[: x.size].copy()
    for j in range(1, window):
        total += full[j : j + x.size]
    return total / window, full[full.size - (window - 1) :]


def keep_tail(tail: FloatArray, x: FloatArray, k: int) -> FloatArray:
    """The last k samples of tail + x (k >= 0)."""
    if k <= 0:
        return x[:0]
    return x[-k:] if x.size >= k else np.concatenate((tail, x))[-k:]


def last_true_time(cond: BoolArray, t_s: FloatArray, carry_s: float) -> FloatArray:
    """Time of the latest True sample at or before each sample (`carry_s` before the block; -inf: never)."""
    stamped = np.where(cond, t_s, -np.inf)
    return np.maximum.accumulate(np.concatenate(([carry_s], stamped)))[1:]


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


def disarmed_spans(armed_at_start: bool, changes: list[tuple[bool, int]], n: int) -> list[tuple[int, int]]:
    """Index ranges [a, b) of a block during which a latch was disarmed (from its firing to its re-arm)."""
    spans, start = [], None if armed_at_start else 0
    for rearmed, k in changes:
        if rearmed and start is not None:
            spans.append((start, k))
            start = None
        elif not rearmed:
            start = k
    if start is not None:
        spans.append((start, n))
    return spans


class BiteDetector:
    """Per-rod bite / drop-back detector; feed consecutive blocks in time order, cut anywhere."""

    def __init__(self, thresholds: RodThresholds | None = None) -> None:
        self.params = BiteParams.from_thresholds(thresholds or RodThresholds())
        self.state = BiteState()

    def set_thresholds(self, thresholds: RodThresholds) -> None:
        """Change thresholds live; the baseline and latches are kept."""
        self.params = BiteParams.from_thresholds(thresholds)

    def rebaseline(self, pitch_rad: float) -> None:
        """Take `pitch_rad` as the new rest (e.g. the angler re-set the rod) and re-arm both latches."""
        old = self.state
        self.state = BiteState(baseline_rad=pitch_rad, warmed=True, origin_s=old.origin_s, frame_k=old.frame_k,
                               closed_k=old.closed_k, frame_t0_s=old.frame_t0_s)  # fmt: skip

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
        s, n = self.state, t_s.size
        if n == 0:
            return RodBlock((), s.baseline_rad, np.zeros(0), math.nan, math.nan)
        t_first = float(t_s[0])
        if math.isnan(s.origin_s):
            s.origin_s = t_first
        events: list[RodEvent] = []
        origin = s.origin_s  # frame indices as `_frame_of` (inlined: this runs per rod per batch)
        k_first = math.floor((t_first - origin) / FRAME_S + _FRAME_EPS)
        k_last = math.floor((float(t_s[-1]) - origin) / FRAME_S + _FRAME_EPS)
        if k_first == k_last:  # the common case: the block lies in one frame
            if k_first != s.frame_k:
                self._close_frame()
                s.frame_k, s.frame_t0_s = k_first, t_first
            dev, lo, i_lo = self._segment(t_s, pitch_rad, acc_up_m_s2, events)
            return RodBlock(tuple(events) if events else (), s.baseline_rad, dev, lo,
                            float(t_s[i_lo]) if i_lo >= 0 else math.nan)  # fmt: skip
        # frame j starts at the first sample with (t - origin) / FRAME_S + _FRAME_EPS >= j (as `_frame_of`)
        starts = s.origin_s + (np.arange(k_first + 1, k_last + 1) - _FRAME_EPS) * FRAME_S
        cuts = np.unique(np.r_[0, np.searchsorted(t_s, starts), n]).tolist()
        dev = np.empty(n)
        lo, t_lo = math.nan, math.nan
        for a, b in zip(cuts[:-1], cuts[1:], strict=True):
            k = self._frame_of(float(t_s[a]))
            if k != s.frame_k:
                self._close_frame()
                s.frame_k, s.frame_t0_s = k, float(t_s[a])
            acc = None if acc_up_m_s2 is None else acc_up_m_s2[a:b]
            dev[a:b], seg_lo, i_lo = self._segment(t_s[a:b], pitch_rad[a:b], acc, events)
            if i_lo >= 0 and not seg_lo >= lo:
                lo, t_lo = seg_lo, float(t_s[a + i_lo])
        return RodBlock(tuple(events), s.baseline_rad, dev, lo, t_lo)

    def _frame_of(self, t_s: float) -> int:
        """Index of the frame holding a sample at device time t_s."""
        return math.floor((t_s - self.state.origin_s) / FRAME_S + _FRAME_EPS)

    def _segment(self, t_s: FloatArray, pitch_rad: FloatArray, acc: FloatArray | None, events: list[RodEvent]
                 ) -> tuple[FloatArray, float, int]:  # fmt: skip
        """Samples of one frame (all of it or a part), judged against the state the earlier frames left; returns
        their deviations, the lowest and its index (-1: none, e.g. in the warm-up)."""
        s = self.state
        s.frame_pitch.append(pitch_rad)
        if acc is not None:
            s.frame_acc.append(acc)
        if not s.warmed:
            if acc is not None:
                s.acc_tail = keep_tail(s.acc_tail, acc, ACC_WINDOW - 1)
            return np.full(t_s.size, math.nan), math.nan, -1
        return self._detect(t_s, pitch_rad, acc, events)

    def _detect(self, t_s: FloatArray, pitch_rad: FloatArray, acc_up_m_s2: FloatArray | None,
                events: list[RodEvent]) -> tuple[FloatArray, float, int]:  # fmt: skip
        """Latches and events for samples after the warm-up; returns their deviations from rest, the lowest and
        its index (-1 if all are nan)."""
        p, s = self.params, self.state
        n = t_s.size
        dev = pitch_rad - s.baseline_rad
        i_lo = int(dev.argmin())  # nan wins argmin: then fall back to the nan-skipping reductions
        lo, hi = float(dev[i_lo]), float(dev.max())
        if math.isnan(lo):
            lo, hi = float(np.fmin.reduce(dev)), float(np.fmax.reduce(dev))
            i_lo = -1 if math.isnan(lo) else int(np.argmax(dev == lo))
        s.frame_lo_rad, s.frame_hi_rad = min(s.frame_lo_rad, lo), max(s.frame_hi_rad, hi)
        # Quiet segments (the common case) skip every mask: only min and max are computed.
        fast = None
        if acc_up_m_s2 is not None:
            if lo <= -p.cue_rad:
                acc_mean, s.acc_tail = trailing_mean(acc_up_m_s2, s.acc_tail, ACC_WINDOW)
                need = max(p.cue_acc_m_s2, CUE_NOISE_FACTOR * math.sqrt(s.acc_ms_lagged))
                last_cue = last_true_time((dev <= -p.cue_rad) & (acc_mean <= -need), t_s, s.last_cue_s)
                s.last_cue_s = float(last_cue[-1])
                if lo <= -p.bite_rad:
                    fast = (dev <= -p.bite_rad) & (t_s - last_cue <= CUE_HOLD_S + _EPS_S)
            else:
                s.acc_tail = keep_tail(s.acc_tail, acc_up_m_s2, ACC_WINDOW - 1)
        bite_ok = None
        if lo <= -p.bite_rad:
            bite_ok, s.bite_run_s = held(dev <= -p.bite_rad, t_s, s.bite_run_s, p.confirm_s)
        else:
            s.bite_run_s = math.nan
        drop_ok = None
        if hi >= p.drop_back_rad:
            drop_ok, s.drop_run_s = held(dev >= p.drop_back_rad, t_s, s.drop_run_s, DROP_BACK_HOLD_S)
        else:
            s.drop_run_s = math.nan

        bite_trig = fast if bite_ok is None else bite_ok if fast is None else bite_ok | fast
        near_lo = -REARM_FRACTION * p.bite_rad
        if not s.bite_armed and hi <= near_lo:
            s.near_bite_run_s = math.nan  # still pulled down: nothing can re-arm here
            s.bite_peak_rad = min(s.bite_peak_rad, lo)
        elif not s.bite_armed or (bite_trig is not None and bite_trig.any()):
            was_armed = s.bite_armed
            near, starts, s.near_bite_run_s = near_runs(dev > near_lo, lo > near_lo, t_s, s.near_bite_run_s)
            s.bite_armed, s.bite_disarmed_at_s, changes = latch_step(
                s.bite_armed, s.bite_disarmed_at_s, _or_none(bite_trig, n), near, starts, t_s, p.rearm_quiet_s
            )
            spans = iter(disarmed_spans(was_armed, changes, n))
            if not was_armed:
                a, b = next(spans)
                s.bite_peak_rad = min(s.bite_peak_rad, float(np.fmin.reduce(dev[a : b + 1])))
            for rearmed, k in changes:
                if rearmed:
                    events.append(RodEvent("bite_rearmed", float(t_s[k]), float(dev[k]), -p.bite_rad, "",
                                           s.bite_peak_rad))  # fmt: skip
                    continue
                a, b = next(spans)
                s.bite_peak_rad = float(np.fmin.reduce(dev[a : b + 1]))
                by_pitch = bite_ok is not None and bool(bite_ok[k])
                events.append(RodEvent("bite", float(t_s[k]), float(dev[k]), -p.bite_rad,
                                       "pitch" if by_pitch else "accel"))  # fmt: skip
        near_hi = REARM_FRACTION * p.drop_back_rad
        if not s.drop_armed and lo >= near_hi:
            s.near_drop_run_s = math.nan
            s.drop_peak_rad = max(s.drop_peak_rad, hi)
        elif not s.drop_armed or (drop_ok is not None and drop_ok.any()):
            was_armed = s.drop_armed
            near, starts, s.near_drop_run_s = near_runs(dev < near_hi, hi < near_hi, t_s, s.near_drop_run_s)
            s.drop_armed, s.drop_disarmed_at_s, changes = latch_step(
                s.drop_armed, s.drop_disarmed_at_s, _or_none(drop_ok, n), near, starts, t_s, p.rearm_quiet_s
            )
            spans = iter(disarmed_spans(was_armed, changes, n))
            if not was_armed:
                a, b = next(spans)
                s.drop_peak_rad = max(s.drop_peak_rad, float(np.fmax.reduce(dev[a : b + 1])))
            for rearmed, k in changes:
                if rearmed:
                    events.append(RodEvent("drop_back_rearmed", float(t_s[k]), float(dev[k]), p.drop_back_rad, "",
                                           s.drop_peak_rad))  # fmt: skip
                    continue
                a, b = next(spans)
                s.drop_peak_rad = float(np.fmax.reduce(dev[a : b + 1]))
                events.append(RodEvent("drop_back", float(t_s[k]), float(dev[k]), p.drop_back_rad, "pitch"))
        if len(events) > 1:
            events.sort(key=lambda e: e.t_s)
        return dev, lo, i_lo

    def _close_frame(self) -> None:
        """End of the open frame: its samples move the warm-up sums, vibration level and rest baseline."""
        p, s = self.params, self.state
        if s.frame_k < 0 or not s.frame_pitch:
            return
        pitch = s.frame_pitch[0] if len(s.frame_pitch) == 1 else np.concatenate(s.frame_pitch)
        acc = None if not s.frame_acc else s.frame_acc[0] if len(s.frame_acc) == 1 else np.concatenate(s.frame_acc)
        s.frame_pitch, s.frame_acc = [], []
        lo, hi = s.frame_lo_rad, s.frame_hi_rad
        s.frame_lo_rad, s.frame_hi_rad = math.inf, -math.inf
        gap_frames = s.frame_k - s.closed_k if s.closed_k >= 0 else 1
        s.closed_k = s.frame_k
        if acc is not None:
            self._track_acc(acc, gap_frames)
        if not s.warmed:
            ok = pitch[np.isfinite(pitch)]
            s.warm_sum_rad += float(np.add.reduce(ok))
            s.warm_n += ok.size
            if s.warm_n:
                s.baseline_rad = s.warm_sum_rad / s.warm_n
            s.warmed = s.warm_n > 0 and s.frame_k >= WARMUP_FRAMES - 1
            return
        mean = float(np.add.reduce(pitch)) / pitch.size
        if not math.isfinite(mean):
            return  # a frame with gaps (nan) never moves the baseline
        if s.bite_armed and s.drop_armed:
            s.steady_since_s = math.nan
            if lo > -REARM_FRACTION * p.bite_rad and hi < REARM_FRACTION * p.drop_back_rad:
                dt_s = gap_frames * FRAME_S
                s.baseline_rad += (1.0 - math.exp(-dt_s / p.baseline_tau_s)) * (mean - s.baseline_rad)
            return
        if math.isnan(s.steady_since_s) or abs(mean - s.steady_ref_rad) > STEADY_FRACTION * p.bite_rad:
            s.steady_ref_rad, s.steady_since_s = mean, s.frame_t0_s
            return
        s.steady_ref_rad += 0.1 * (mean - s.steady_ref_rad)
        if s.frame_t0_s + FRAME_S - s.steady_since_s >= REBASELINE_FACTOR * max(p.rearm_quiet_s, 1.0):
            s.baseline_rad, s.steady_since_s = s.steady_ref_rad, math.nan

    def _track_acc(self, acc_up_m_s2: FloatArray, gap_frames: int) -> None:
        """Vibration level for the cue's bar: mean square with fast attack and ACC_RMS_DECAY_S decay, lagged."""
        s = self.state
        frame_ms = float(np.dot(acc_up_m_s2, acc_up_m_s2)) / acc_up_m_s2.size
        if not math.isfinite(frame_ms):
            return
        s.acc_ms = max(frame_ms, s.acc_ms * math.exp(-gap_frames * FRAME_S / ACC_RMS_DECAY_S))
        if s.frame_k - s.acc_checkpoint_k >= ACC_RMS_LAG_FRAMES:
            s.acc_ms_lagged, s.acc_ms_snapshot = s.acc_ms_snapshot, s.acc_ms
            s.acc_checkpoint_k = s.frame_k


def _or_none(mask: BoolArray | None, n: int) -> BoolArray:
    return np.zeros(n, dtype=bool) if mask is None else mask
