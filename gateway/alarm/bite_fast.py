"""The bite detector of `gateway.alarm.bite` as one numba kernel per block: the same results, bit for bit, cheaper.

`bite.BiteDetector` is the readable reference: it works on whole blocks with numpy masks, which costs a dozen
numpy calls (about 1 µs each on 10 samples) per rod per packet. `FastBiteDetector` keeps the same state in one
float64 vector (the `_S_*` slots below) and the open frame's samples in a small buffer, and `bite_block` walks
the block sample by sample. Every decision of the reference is per sample (runs, latches and the cue carry
across blocks), so the walk takes the same decisions; the frame sums are computed as numpy computes them
(`np_add_reduce` is numpy's pairwise summation; `mean_square` calls BLAS ddot as `np.dot` does, through
scipy's OpenBLAS where numpy has its own build of it), so the rest baseline and the vibration level are the
same to the last bit. tests/alarm/test_bite_fast.py holds both to that on random
streams cut at random.

Two block-level rules of the reference are kept on purpose: the cue is looked for only in segments whose lowest
deviation reaches the cue level, and a segment whose every number lies in a re-arm band counts as one run of it
even across nan samples (elsewhere a nan ends the run). One difference in state never reaches an output: the
reference leaves the re-arm band's run start untouched while a latch stays armed (it is only read after a
firing, by which time both have restarted it).
"""

from __future__ import annotations

import math
from typing import Literal

import numpy as np

from gateway.alarm.bite import (
    _EPS_S,
    _FRAME_EPS,
    ACC_RMS_DECAY_S,
    ACC_RMS_LAG_FRAMES,
    ACC_WINDOW,
    CUE_HOLD_S,
    CUE_NOISE_FACTOR,
    DROP_BACK_HOLD_S,
    FRAME_S,
    REARM_FRACTION,
    REBASELINE_FACTOR,
    STEADY_FRACTION,
    WARMUP_FRAMES,
    BiteParams,
    BiteState,
    EventKind,
    FloatArray,
    RodBlock,
    RodEvent,
)
from gateway.config import RodThresholds
from gateway.fusion.quaternion import njit

# Slots of the state vector (float64; flags are 0.0 / 1.0, frame indices whole numbers). As `BiteState`.
_S_BASELINE = 0
_S_BITE_ARMED = 1
_S_DROP_ARMED = 2
_S_BITE_DISARMED_AT = 3
_S_DROP_DISARMED_AT = 4
_S_BITE_PEAK = 5
_S_DROP_PEAK = 6
_S_BITE_RUN = 7
_S_DROP_RUN = 8
_S_NEAR_BITE_RUN = 9
_S_NEAR_DROP_RUN = 10
_S_LAST_CUE = 11
_S_ACC_PREV2 = 12  # the acceleration sample before the last (the cue's 3-sample mean continues across blocks)
_S_ACC_PREV1 = 13  # the last acceleration sample
_S_ACC_SEEN = 14  # acceleration samples seen, capped at 2
_S_ACC_MS = 15
_S_ACC_MS_SNAPSHOT = 16
_S_ACC_MS_LAGGED = 17
_S_ACC_CHECKPOINT_K = 18
_S_STEADY_REF = 19
_S_STEADY_SINCE = 20
_S_WARMED = 21
_S_WARM_SUM = 22
_S_WARM_N = 23
_S_ORIGIN = 24
_S_FRAME_K = 25
_S_CLOSED_K = 26
_S_FRAME_T0 = 27
_S_FRAME_LO = 28
_S_FRAME_HI = 29
_S_FRAME_N_PITCH = 30  # samples of the open frame in the buffer's row 0 (pitch) and row 1 (acceleration)
_S_FRAME_N_ACC = 31
_N_SLOTS = 32

# Parameter vector: `BiteParams` in field order.
_P_BITE, _P_CONFIRM, _P_CUE, _P_CUE_ACC, _P_DROP, _P_QUIET, _P_TAU = range(7)

# Event rows: kind, sample index, deviation (rad), threshold (rad), cue, peak (rad).
_KINDS: tuple[EventKind, ...] = ("bite", "bite_rearmed", "drop_back", "drop_back_rearmed")
_CUES: tuple[Literal["", "pitch", "accel"], ...] = ("", "pitch", "accel")
_EV_BITE, _EV_BITE_REARMED, _EV_DROP, _EV_DROP_REARMED = 0.0, 1.0, 2.0, 3.0
_CUE_NONE, _CUE_PITCH, _CUE_ACCEL = 0.0, 1.0, 2.0

assert ACC_WINDOW == 3, "the kernel keeps the 2 acceleration samples before each one for the cue's mean"


_STATE_SLOTS: dict[str, int] = {
    "baseline_rad": _S_BASELINE, "bite_armed": _S_BITE_ARMED, "drop_armed": _S_DROP_ARMED,
    "bite_disarmed_at_s": _S_BITE_DISARMED_AT, "drop_disarmed_at_s": _S_DROP_DISARMED_AT,
    "bite_peak_rad": _S_BITE_PEAK, "drop_peak_rad": _S_DROP_PEAK, "bite_run_s": _S_BITE_RUN, "drop_run_s": _S_DROP_RUN,
    "near_bite_run_s": _S_NEAR_BITE_RUN, "near_drop_run_s": _S_NEAR_DROP_RUN, "last_cue_s": _S_LAST_CUE,
    "acc_ms": _S_ACC_MS, "acc_ms_snapshot": _S_ACC_MS_SNAPSHOT, "acc_ms_lagged": _S_ACC_MS_LAGGED,
    "acc_checkpoint_k": _S_ACC_CHECKPOINT_K, "steady_ref_rad": _S_STEADY_REF, "steady_since_s": _S_STEADY_SINCE,
    "warmed": _S_WARMED, "warm_sum_rad": _S_WARM_SUM, "warm_n": _S_WARM_N, "origin_s": _S_ORIGIN,
    "frame_k": _S_FRAME_K, "closed_k": _S_CLOSED_K, "frame_t0_s": _S_FRAME_T0, "frame_lo_rad": _S_FRAME_LO,
    "frame_hi_rad": _S_FRAME_HI,
}  # fmt: skip
"""`BiteState` field -> its slot (the reference's other fields, its sample lists, are the kernel's buffers)."""


def initial_state() -> FloatArray:
    """The state of a new detector, as `BiteState()`."""
    s, d = np.zeros(_N_SLOTS), BiteState()
    for name, k in _STATE_SLOTS.items():
        s[k] = getattr(d, name)
    return s


def params_vector(p: BiteParams) -> FloatArray:
    """`BiteParams` as the kernel's parameter vector."""
    return np.array([p.bite_rad, p.confirm_s, p.cue_rad, p.cue_acc_m_s2, p.drop_back_rad, p.rearm_quiet_s,
                     p.baseline_tau_s])  # fmt: skip


@njit
def _pairwise_block(x: FloatArray, a: int, b: int) -> float:
    """numpy's pairwise summation of x[a:b] for b - a <= 128 (numpy/_core/src/umath/loops_utils.h.src)."""
    n = b - a
    if n < 8:
        res = 0.0
        for i in range(a, b):
            res += x[i]
        return res
    r0, r1, r2, r3 = x[a], x[a + 1], x[a + 2], x[a + 3]
    r4, r5, r6, r7 = x[a + 4], x[a + 5], x[a + 6], x[a + 7]
    i = 8
    while i < n - n % 8:
        r0 += x[a + i]
        r1 += x[a + i + 1]
        r2 += x[a + i + 2]
        r3 += x[a + i + 3]
        r4 += x[a + i + 4]
        r5 += x[a + i + 5]
        r6 += x[a + i + 6]
        r7 += x[a + i + 7]
        i += 8
    res = ((r0 + r1) + (r2 + r3)) + ((r4 + r5) + (r6 + r7))
    while i < n:
        res += x[a + i]
        i += 1
    return float(res)


@njit
def _pairwise_sum(x: FloatArray, a: int, b: int) -> float:
    """numpy's pairwise summation of x[a:b]: blocks of <= 128 summed as above, longer runs split in two (at a
    multiple of 8) and the halves added. numpy recurses; this walks the same tree with a stack (numba's cache
    crashed on loading a recursive kernel)."""
    if b - a <= 128:
        return _pairwise_block(x, a, b)
    todo = np.empty((192, 3), dtype=np.int64)  # (start, stop, 0 = sum it / 1 = add the last two sums)
    sums = np.empty(96)
    n_todo, n_sums = 1, 0
    todo[0, 0], todo[0, 1], todo[0, 2] = a, b, 0
    while n_todo:
        n_todo -= 1
        lo, hi, add = todo[n_todo, 0], todo[n_todo, 1], todo[n_todo, 2]
        if add:
            n_sums -= 1
            sums[n_sums - 1] += sums[n_sums]
        elif hi - lo <= 128:
            sums[n_sums] = _pairwise_block(x, lo, hi)
            n_sums += 1
        else:
            n2 = (hi - lo) // 2
            n2 -= n2 % 8
            todo[n_todo, 0], todo[n_todo, 1], todo[n_todo, 2] = lo, hi, 1  # after both halves
            todo[n_todo + 1, 0], todo[n_todo + 1, 1], todo[n_todo + 1, 2] = lo + n2, hi, 0
            todo[n_todo + 2, 0], todo[n_todo + 2, 1], todo[n_todo + 2, 2] = lo, lo + n2, 0  # first
            n_todo += 3
    return float(sums[0])


@njit
def np_add_reduce(x: FloatArray, n: int) -> float:
    """`np.add.reduce(x[:n])` bit for bit: the identity 0.0 plus numpy's pairwise sum (so -0.0 sums to 0.0)."""
    return 0.0 + _pairwise_sum(x, 0, n)


@njit
def mean_square(x: FloatArray) -> float:
    """`np.dot(x, x) / x.size` bit for bit: numba's `np.dot` of two vectors is the same BLAS ddot call."""
    return float(np.dot(x, x)) / x.size


@njit
def _track_acc(s: FloatArray, acc: FloatArray, gap_frames: float) -> None:
    """`BiteDetector._track_acc` on the closing frame's acceleration samples."""
    frame_ms = mean_square(acc)
    if not math.isfinite(frame_ms):
        return
    decayed = s[_S_ACC_MS] * math.exp(-gap_frames * FRAME_S / ACC_RMS_DECAY_S)
    s[_S_ACC_MS] = decayed if decayed > frame_ms else frame_ms  # Python's max(frame_ms, decayed)
    if s[_S_FRAME_K] - s[_S_ACC_CHECKPOINT_K] >= ACC_RMS_LAG_FRAMES:
        s[_S_ACC_MS_LAGGED], s[_S_ACC_MS_SNAPSHOT] = s[_S_ACC_MS_SNAPSHOT], s[_S_ACC_MS]
        s[_S_ACC_CHECKPOINT_K] = s[_S_FRAME_K]


@njit
def _close_frame(s: FloatArray, p: FloatArray, frame: FloatArray) -> None:
    """`BiteDetector._close_frame`: the open frame's samples move the warm-up sums, vibration level and baseline."""
    n_pitch, n_acc = int(s[_S_FRAME_N_PITCH]), int(s[_S_FRAME_N_ACC])
    if s[_S_FRAME_K] < 0 or n_pitch == 0:
        return
    s[_S_FRAME_N_PITCH], s[_S_FRAME_N_ACC] = 0.0, 0.0
    lo, hi = s[_S_FRAME_LO], s[_S_FRAME_HI]
    s[_S_FRAME_LO], s[_S_FRAME_HI] = math.inf, -math.inf
    gap_frames = s[_S_FRAME_K] - s[_S_CLOSED_K] if s[_S_CLOSED_K] >= 0 else 1.0
    s[_S_CLOSED_K] = s[_S_FRAME_K]
    if n_acc > 0:
        _track_acc(s, frame[1, :n_acc], gap_frames)
    pitch = frame[0]
    if s[_S_WARMED] == 0.0:
        ok = np.empty(n_pitch)
        m = 0
        for i in range(n_pitch):
            if math.isfinite(pitch[i]):
                ok[m] = pitch[i]
                m += 1
        s[_S_WARM_SUM] += np_add_reduce(ok, m)
        s[_S_WARM_N] += m
        if s[_S_WARM_N] > 0:
            s[_S_BASELINE] = s[_S_WARM_SUM] / s[_S_WARM_N]
        s[_S_WARMED] = 1.0 if s[_S_WARM_N] > 0 and s[_S_FRAME_K] >= WARMUP_FRAMES - 1 else 0.0
        return
    mean = np_add_reduce(pitch, n_pitch) / n_pitch
    if not math.isfinite(mean):
        return  # a frame with gaps (nan) never moves the baseline
    if s[_S_BITE_ARMED] != 0.0 and s[_S_DROP_ARMED] != 0.0:
        s[_S_STEADY_SINCE] = math.nan
        if lo > -REARM_FRACTION * p[_P_BITE] and hi < REARM_FRACTION * p[_P_DROP]:
            dt_s = gap_frames * FRAME_S
            s[_S_BASELINE] += (1.0 - math.exp(-dt_s / p[_P_TAU])) * (mean - s[_S_BASELINE])
        return
    if math.isnan(s[_S_STEADY_SINCE]) or abs(mean - s[_S_STEADY_REF]) > STEADY_FRACTION * p[_P_BITE]:
        s[_S_STEADY_REF], s[_S_STEADY_SINCE] = mean, s[_S_FRAME_T0]
        return
    s[_S_STEADY_REF] += 0.1 * (mean - s[_S_STEADY_REF])
    if s[_S_FRAME_T0] + FRAME_S - s[_S_STEADY_SINCE] >= REBASELINE_FACTOR * max(p[_P_QUIET], 1.0):
        s[_S_BASELINE], s[_S_STEADY_SINCE] = s[_S_STEADY_REF], math.nan


@njit
def _np_maximum(a: float, b: float) -> float:
    """`np.maximum` of two floats: nan if either is."""
    if math.isnan(a) or math.isnan(b):
        return math.nan
    return a if a >= b else b


@njit
def _since(holds: bool, since_s: float, t_s: float) -> float:
    """When a condition that holds at `t_s` began (`since_s`, or `t_s` if it did not hold before); nan when it
    does not hold: the run timers of both latches."""
    if not holds:
        return math.nan
    return t_s if math.isnan(since_s) else since_s


@njit
def _event(events: FloatArray, n_ev: int, kind: float, k: int, dev: float, thr: float, cue: float,
           peak: float) -> int:  # fmt: skip
    events[n_ev, 0], events[n_ev, 1], events[n_ev, 2] = kind, k, dev
    events[n_ev, 3], events[n_ev, 4], events[n_ev, 5] = thr, cue, peak
    return n_ev + 1


@njit
def _detect(s: FloatArray, p: FloatArray, t: FloatArray, acc: FloatArray, has_acc: bool, a: int, b: int,
            dev: FloatArray, events: FloatArray, n_ev: int) -> tuple[int, float, int]:  # fmt: skip
    """`BiteDetector._detect` on samples a:b, one sample at a time; returns (events, lowest deviation, its index)."""
    # lowest (first of equals) and highest deviation, skipping nan, as the reference's argmin / fmin / fmax
    lo, hi, i_lo = math.nan, math.nan, -1
    for i in range(a, b):
        d = dev[i]
        if math.isnan(d):
            continue
        if i_lo < 0 or d < lo:
            lo, i_lo = d, i
        if not d <= hi:
            hi = d
    if lo < s[_S_FRAME_LO]:
        s[_S_FRAME_LO] = lo
    if hi > s[_S_FRAME_HI]:
        s[_S_FRAME_HI] = hi
    bite, drop = p[_P_BITE], p[_P_DROP]
    cue_rad, quiet_s = p[_P_CUE], p[_P_QUIET]
    need = CUE_NOISE_FACTOR * math.sqrt(s[_S_ACC_MS_LAGGED])
    if not need > p[_P_CUE_ACC]:
        need = p[_P_CUE_ACC]  # Python's max(cue_acc, need)
    near_lo, near_hi = -REARM_FRACTION * bite, REARM_FRACTION * drop
    cue_block = has_acc and lo <= -cue_rad  # the reference looks for the cue only in such segments
    # A segment whose every number lies in a re-arm band is one run of it, nan samples included (as the reference's
    # `near_runs` shortcut); otherwise a nan sample ends the run.
    all_near_bite, all_near_drop = lo > near_lo, hi < near_hi
    # bite latch (and the cue), then the drop-back latch: events in the reference's order before its sort
    armed, run, near_run, last_cue = s[_S_BITE_ARMED] != 0.0, s[_S_BITE_RUN], s[_S_NEAR_BITE_RUN], s[_S_LAST_CUE]
    prev2, prev1, seen = s[_S_ACC_PREV2], s[_S_ACC_PREV1], s[_S_ACC_SEEN]
    for i in range(a, b):
        d, ti = dev[i], t[i]
        fast = False
        if has_acc:
            x = acc[i]
            if seen == 0.0:
                prev2 = prev1 = x
            acc_mean = ((prev2 + prev1) + x) / 3.0
            prev2, prev1, seen = prev1, x, min(seen + 1.0, 2.0)
            if cue_block:
                if d <= -cue_rad and acc_mean <= -need:
                    last_cue = _np_maximum(last_cue, ti)
                fast = d <= -bite and ti - last_cue <= CUE_HOLD_S + _EPS_S
        run = _since(d <= -bite, run, ti)
        by_pitch = d <= -bite and ti - run >= p[_P_CONFIRM] - _EPS_S
        near = d > near_lo
        near_run = _since(near or all_near_bite, near_run, ti)
        if armed:
            if by_pitch or fast:
                armed = False
                s[_S_BITE_DISARMED_AT], s[_S_BITE_PEAK] = ti, d
                n_ev = _event(events, n_ev, _EV_BITE, i, d, -bite, _CUE_PITCH if by_pitch else _CUE_ACCEL, 0.0)
        else:
            if d < s[_S_BITE_PEAK]:
                s[_S_BITE_PEAK] = d
            if near and ti - max(near_run, s[_S_BITE_DISARMED_AT]) >= quiet_s - _EPS_S:
                armed = True
                n_ev = _event(events, n_ev, _EV_BITE_REARMED, i, d, -bite, _CUE_NONE, s[_S_BITE_PEAK])
    s[_S_BITE_ARMED], s[_S_BITE_RUN], s[_S_NEAR_BITE_RUN] = armed, run, near_run
    s[_S_ACC_PREV2], s[_S_ACC_PREV1], s[_S_ACC_SEEN] = prev2, prev1, seen
    s[_S_LAST_CUE] = last_cue
    armed, run, near_run = s[_S_DROP_ARMED] != 0.0, s[_S_DROP_RUN], s[_S_NEAR_DROP_RUN]
    for i in range(a, b):
        d, ti = dev[i], t[i]
        run = _since(d >= drop, run, ti)
        by_pitch = d >= drop and ti - run >= DROP_BACK_HOLD_S - _EPS_S
        near = d < near_hi
        near_run = _since(near or all_near_drop, near_run, ti)
        if armed:
            if by_pitch:
                armed = False
                s[_S_DROP_DISARMED_AT], s[_S_DROP_PEAK] = ti, d
                n_ev = _event(events, n_ev, _EV_DROP, i, d, drop, _CUE_PITCH, 0.0)
        else:
            if d > s[_S_DROP_PEAK]:
                s[_S_DROP_PEAK] = d
            if near and ti - max(near_run, s[_S_DROP_DISARMED_AT]) >= quiet_s - _EPS_S:
                armed = True
                n_ev = _event(events, n_ev, _EV_DROP_REARMED, i, d, drop, _CUE_NONE, s[_S_DROP_PEAK])
    s[_S_DROP_ARMED], s[_S_DROP_RUN], s[_S_NEAR_DROP_RUN] = armed, run, near_run
    return n_ev, lo, i_lo


@njit
def _segment(s: FloatArray, p: FloatArray, frame: FloatArray, t: FloatArray, pitch: FloatArray, acc: FloatArray,
             has_acc: bool, a: int, b: int, dev: FloatArray, events: FloatArray, n_ev: int
             ) -> tuple[int, float, int]:  # fmt: skip
    """`BiteDetector._segment`: samples a:b of one frame join its buffer and are judged (after the warm-up)."""
    m = int(s[_S_FRAME_N_PITCH])
    frame[0, m : m + b - a] = pitch[a:b]
    s[_S_FRAME_N_PITCH] = m + b - a
    if has_acc:
        m = int(s[_S_FRAME_N_ACC])
        frame[1, m : m + b - a] = acc[a:b]
        s[_S_FRAME_N_ACC] = m + b - a
    if s[_S_WARMED] == 0.0:
        if has_acc:
            for i in range(a, b):  # the cue's 3-sample mean continues across the warm-up's end
                if s[_S_ACC_SEEN] == 0.0:
                    s[_S_ACC_PREV1] = acc[i]
                s[_S_ACC_PREV2], s[_S_ACC_PREV1] = s[_S_ACC_PREV1], acc[i]
                s[_S_ACC_SEEN] = min(s[_S_ACC_SEEN] + 1.0, 2.0)
        dev[a:b] = math.nan
        return n_ev, math.nan, -1
    base = s[_S_BASELINE]
    for i in range(a, b):
        dev[i] = pitch[i] - base
    return _detect(s, p, t, acc, has_acc, a, b, dev, events, n_ev)


@njit
def bite_block(s: FloatArray, p: FloatArray, frame: FloatArray, t: FloatArray, pitch: FloatArray,
               acc: FloatArray, has_acc: bool, dev: FloatArray, events: FloatArray
               ) -> tuple[int, float, float, float]:  # fmt: skip
    """`BiteDetector.update` on one non-empty block: fills `dev` (n,) and `events` (rows of kind, sample index,
    deviation, threshold, cue, peak); returns (events, rest baseline, lowest deviation, its time).

    Events -1: nothing done, as the frame buffer (2, m) has no room for the open frame's samples plus n, or
    `events` has fewer than 2 n rows (each latch changes at most once per sample)."""
    n = t.size
    if pitch.size != n or dev.size != n or (has_acc and acc.size != n):
        raise ValueError("bite_block: the block's arrays differ in length")
    if s[_S_FRAME_N_PITCH] + n > frame.shape[1] or events.shape[0] < 2 * n:
        return -1, s[_S_BASELINE], math.nan, math.nan
    n_ev, lo, i_lo = _walk_block(s, p, frame, t, pitch, acc, has_acc, dev, events)
    return n_ev, s[_S_BASELINE], lo, t[i_lo] if i_lo >= 0 else math.nan


@njit
def _walk_block(s: FloatArray, p: FloatArray, frame: FloatArray, t: FloatArray, pitch: FloatArray,
                acc: FloatArray, has_acc: bool, dev: FloatArray, events: FloatArray) -> tuple[int, float, int]:
    """The block frame by frame, as `BiteDetector.update`: returns (events, lowest deviation, its index or -1)."""
    n = t.size
    if math.isnan(s[_S_ORIGIN]):
        s[_S_ORIGIN] = t[0]
    origin = s[_S_ORIGIN]
    k_first = math.floor((t[0] - origin) / FRAME_S + _FRAME_EPS)
    k_last = math.floor((t[n - 1] - origin) / FRAME_S + _FRAME_EPS)
    if k_first == k_last:  # the common case: the block lies in one frame
        if k_first != s[_S_FRAME_K]:
            _close_frame(s, p, frame)
            s[_S_FRAME_K], s[_S_FRAME_T0] = k_first, t[0]
        return _segment(s, p, frame, t, pitch, acc, has_acc, 0, n, dev, events, 0)
    # frame j starts at the first sample with (t - origin) / FRAME_S + _FRAME_EPS >= j (as the reference's cuts)
    n_ev, lo, i_lo = 0, math.nan, -1
    a = 0
    for j in range(k_first + 1, k_last + 2):
        b = n if j == k_last + 1 else np.searchsorted(t, origin + (j - _FRAME_EPS) * FRAME_S)
        if b <= a:
            continue
        k = math.floor((t[a] - origin) / FRAME_S + _FRAME_EPS)
        if k != s[_S_FRAME_K]:
            _close_frame(s, p, frame)
            s[_S_FRAME_K], s[_S_FRAME_T0] = k, t[a]
        n_ev, seg_lo, seg_i = _segment(s, p, frame, t, pitch, acc, has_acc, a, b, dev, events, n_ev)
        if seg_i >= 0 and not seg_lo >= lo:
            lo, i_lo = seg_lo, seg_i
        a = b
    return n_ev, lo, i_lo


_NO_ACC = np.zeros(0)


class FastBiteDetector:
    """`bite.BiteDetector` with its per-block step in one numba kernel (same interface, same results)."""

    def __init__(self, thresholds: RodThresholds | None = None) -> None:
        self.params = BiteParams.from_thresholds(thresholds or RodThresholds())
        self._p = params_vector(self.params)
        self._s = initial_state()
        self._frame = np.zeros((2, 64))  # the open frame's pitch and acceleration samples
        self._events = np.zeros((16, 6))

    def set_thresholds(self, thresholds: RodThresholds) -> None:
        """Change thresholds live; the baseline and latches are kept."""
        self.params = BiteParams.from_thresholds(thresholds)
        self._p = params_vector(self.params)

    def rebaseline(self, pitch_rad: float) -> None:
        """Take `pitch_rad` as the new rest and re-arm both latches (as `BiteDetector.rebaseline`)."""
        old, s = self._s, initial_state()
        s[_S_BASELINE], s[_S_WARMED] = pitch_rad, 1.0
        for k in (_S_ORIGIN, _S_FRAME_K, _S_CLOSED_K, _S_FRAME_T0):
            s[k] = old[k]
        self._s = s

    @property
    def state(self) -> BiteState:
        """A snapshot of the state as the reference holds it (for tests and inspection; not the frame's samples)."""
        s, d = self._s, BiteState()
        return BiteState(**{name: type(getattr(d, name))(s[k]) for name, k in _STATE_SLOTS.items()})

    def update(
        self,
        t_s: FloatArray,
        pitch_rad: FloatArray,
        roll_rad: FloatArray | None = None,
        yaw_rad: FloatArray | None = None,
        acc_up_m_s2: FloatArray | None = None,
    ) -> RodBlock:
        """Process one block, shapes (n,), as `BiteDetector.update` (roll and yaw deliberately unused)."""
        del roll_rad, yaw_rad
        n = t_s.size
        if n == 0:
            return RodBlock((), float(self._s[_S_BASELINE]), np.zeros(0), math.nan, math.nan)
        dev = np.empty(n)
        acc = _NO_ACC if acc_up_m_s2 is None else acc_up_m_s2
        has_acc = acc_up_m_s2 is not None
        n_ev, baseline, lo, t_lo = bite_block(self._s, self._p, self._frame, t_s, pitch_rad, acc, has_acc, dev,
                                              self._events)  # fmt: skip
        if n_ev < 0:  # a longer block than the buffers have room for: grow them, then run it
            self._grow(n)
            n_ev, baseline, lo, t_lo = bite_block(self._s, self._p, self._frame, t_s, pitch_rad, acc, has_acc, dev,
                                                  self._events)  # fmt: skip
        return RodBlock(self._rod_events(n_ev, t_s) if n_ev else (), baseline, dev, lo, t_lo)

    def _grow(self, n: int) -> None:
        """Room for a block of n samples: the frame buffer (keeping the open frame) and the event rows."""
        frame = np.zeros((2, 2 * (self._frame.shape[1] + n)))
        frame[:, : self._frame.shape[1]] = self._frame
        self._frame = frame
        self._events = np.zeros((max(2 * n, self._events.shape[0]), 6))

    def _rod_events(self, n_ev: int, t_s: FloatArray) -> tuple[RodEvent, ...]:
        """The kernel's event rows as `RodEvent`s in time order (a stable sort, as the reference)."""
        out = [
            RodEvent(_KINDS[int(kind)], float(t_s[int(k)]), float(dev), float(thr), _CUES[int(cue)], float(peak))
            for kind, k, dev, thr, cue, peak in self._events[:n_ev].tolist()
        ]
        if len(out) > 1:
            out.sort(key=lambda e: e.t_s)
        return tuple(out)


def warm_up() -> None:
    """Compile (or load from numba's cache) `bite_block` for the contiguous float64 blocks the rod kind passes."""
    t = np.arange(30) / 100.0
    det = FastBiteDetector()
    det.update(t, np.zeros(30), None, None, np.zeros(30))
    det.update(t + 0.3, np.zeros(30))
