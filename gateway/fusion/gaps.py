"""Lost packets: the samples a filter never got, bridged so that its state crosses the gap in time.

A device's packets carry their samples' device times (`t0_us`, `rate_hz`). When a packet is lost on the link the
next one starts later than the sample period allows, but a filter fed the samples back to back would step across
the gap as if no time had passed: a rod's gyroscope integral misses the rotation during it (the accelerometer
takes seconds to pull it back), a hook's pendulum model its phase (the swing-rate innovations then look like a
boom-tip move). `fill_gaps` inserts the missing samples, interpolated linearly between the sample before the gap
and the one after, for the filter only: every output stays on the device's own samples (`keep`).

Gaps longer than `MAX_BRIDGE_S` are left as they are (an interpolation over seconds is a guess, not a bridge).
A kind may taper the interpolated gyroscope towards zero inside a gap (`taper_inserted`): the rate at the edges is
measured, the rate in the middle of a long gap is not, and a line between two samples of a rod tip's ringing or
spring-back turns it by many degrees that never happened.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from numpy.typing import NDArray

from gateway.fusion.quaternion import njit

FloatArray = NDArray[np.float64]

MAX_BRIDGE_S = 2.0  # longest gap bridged, s (20 lost 10-sample packets at 100 Hz)
BRIDGE_AVERAGE_S = 0.01  # samples either side of a gap averaged for the line across it, s (0.01: the next ones)
COAST_MIN_S = 0.0  # gaps at least this long: a filter with a model (`run_bridged`) coasts on it (0: every gap)
GAP_FACTOR = 1.5  # a spacing above this many sample periods is a gap (packet times are sample-exact to 1 µs)
JITTER_TOL_S = 0.025  # ... but between packets whose seq follows on (none lost), only one this much past a period:
# a device that stamps t0_us when it sends, not on the sample clock, jitters by milliseconds, and a filter fed
# invented samples runs ahead of time (hook seeds 1-3 with ±9 ms: Θ RMSE 0.137 -> 0.187° before this)


def has_gap(t_s: FloatArray, prev_t_s: float, dt_s: float, tol_s: float | None = None) -> bool:
    """Whether samples at device times `t_s` (s, ascending), after a sample at `prev_t_s` (nan: none), miss any
    sample, i.e. are spaced more than `tol_s` (default (GAP_FACTOR - 1) periods) past a period somewhere: two float
    comparisons when there is none (span and start), so every device can be asked every batch."""
    n = t_s.shape[0]
    if n == 0:
        return False
    tol = (GAP_FACTOR - 1.0) * dt_s if tol_s is None else tol_s
    return bool(t_s[0] - prev_t_s > dt_s + tol or t_s[n - 1] - t_s[0] > (n - 1) * dt_s + tol)


def gap_tol_s(dt_s: Any, none_lost: Any) -> Any:
    """Spacing past a period that counts as a gap, s: (GAP_FACTOR - 1) periods, but at least JITTER_TOL_S after a
    packet whose seq follows on (`none_lost`); elementwise for arrays, a float for floats."""
    strict = (GAP_FACTOR - 1.0) * dt_s
    if isinstance(dt_s, float) and isinstance(none_lost, bool):  # a device's own block: no numpy on scalars
        return max(strict, JITTER_TOL_S) if none_lost else strict
    tol = np.where(none_lost, np.maximum(strict, JITTER_TOL_S), strict)
    return float(tol) if tol.ndim == 0 else tol


def has_gaps(first_s: FloatArray, last_s: FloatArray, n: NDArray[np.int64], prev_t_s: FloatArray, dt_s: FloatArray,
             tol_s: FloatArray) -> NDArray[np.bool_]:  # fmt: skip
    """`has_gap` of many devices' blocks at once, from each block's first and last sample time (s), sample count
    (>= 1), the sample before it (nan: none), period and tolerance (s): the same comparisons in float64, elementwise."""
    out: NDArray[np.bool_] = (first_s - prev_t_s > dt_s + tol_s) | (last_s - first_s > (n - 1) * dt_s + tol_s)
    return out


def fill_gaps(t_s: FloatArray, rows: FloatArray, dt_s: float, prev_t_s: FloatArray | None = None,
              prev_rows: FloatArray | None = None, max_gap_s: float = MAX_BRIDGE_S, average_n: int = 1,
              tol_s: FloatArray | None = None) -> tuple[FloatArray, NDArray[np.int64]] | None:  # fmt: skip
    """`rows` (n, k) at device times `t_s` (n,) with the samples missing before each one inserted (after the rows
    `prev_rows` (p, k) at `prev_t_s` (p,) that came before, when given).

    The missing samples lie on the line through the mean of up to `average_n` samples either side of the gap, each at
    the mean of its samples' times: with 1, the samples next to the gap; with more, a vibration averages out while a
    steady rate or slope is still carried across (a linear signal is filled exactly either way).
    Returns (filled rows (n + m, k), `keep` (n,): the index of each original row in them), or None when nothing was
    inserted (no gap, or every gap longer than `max_gap_s`). A gap of g seconds holds round(g / dt_s) - 1 samples;
    a spacing counts as a gap when it exceeds a period by more than `tol_s` (n,), the tolerance before each row
    (default (GAP_FACTOR - 1) periods everywhere)."""
    n = t_s.shape[0]
    if n == 0:
        return None
    p, times, stitched = 0, t_s, rows
    if prev_rows is not None and prev_t_s is not None and prev_t_s.shape[0]:
        p, times, stitched = prev_t_s.shape[0], np.concatenate((prev_t_s, t_s)), np.concatenate((prev_rows, rows))
    tol = np.full(n, (GAP_FACTOR - 1.0) * dt_s) if tol_s is None else np.ascontiguousarray(tol_s, dtype=np.float64)
    out, keep = _fill_gaps(np.ascontiguousarray(times, dtype=np.float64),
                           np.ascontiguousarray(stitched, dtype=np.float64), p, dt_s, max_gap_s, max(1, average_n), tol)
    return None if out.shape[0] == n else (out, keep)


@njit
def _fill_gaps(times: FloatArray, stitched: FloatArray, p: int, dt_s: float, max_gap_s: float, w: int,
               tol_s: FloatArray) -> tuple[FloatArray, NDArray[np.int64]]:  # fmt: skip
    """`fill_gaps` on `stitched` (p previous rows, then the block's n): (filled block rows, keep); no inserted row
    when the filled block has n rows. One pass in numba: a device that loses packets under load costs ~µs, not the
    ~60 µs of numpy calls on 10-row arrays (which fed back into the load: the more the gateway dropped, the more
    it had to bridge)."""
    total, k = stitched.shape
    n = total - p
    before = np.zeros(n, dtype=np.int64)  # samples missing just before original row i
    for i in range(1 if p == 0 else 0, n):
        j = p + i
        spacing = times[j] - times[j - 1]
        m = np.int64(np.rint(spacing / dt_s)) - 1
        if m >= 1 and spacing - dt_s > tol_s[i] and not m * dt_s > max_gap_s:
            before[i] = m
    keep = np.empty(n, dtype=np.int64)
    acc = 0
    for i in range(n):
        acc += before[i]
        keep[i] = i + acc
    out = np.empty((n + acc, k))
    for i in range(n):
        out[keep[i]] = stitched[p + i]
        m = before[i]
        if m == 0:
            continue
        j = p + i  # the row after the gap in `stitched`
        a, b = max(0, j - w), min(total, j + w)
        t_l = 0.0
        t_r = 0.0
        for r in range(a, j):
            t_l += times[r]
        for r in range(j, b):
            t_r += times[r]
        t_l /= j - a
        t_r /= b - j
        for c in range(k):
            v_l = 0.0
            v_r = 0.0
            for r in range(a, j):
                v_l += stitched[r, c]
            for r in range(j, b):
                v_r += stitched[r, c]
            v_l /= j - a
            v_r /= b - j
            for q in range(m):
                t_missing = times[j - 1] + dt_s * (q + 1)
                out[keep[i] - m + q, c] = v_l + (t_missing - t_l) / (t_r - t_l) * (v_r - v_l)
    return out, keep


def taper_inserted(rows: FloatArray, keep: NDArray[np.int64], dt_s: float, tau_s: float) -> FloatArray:
    """`rows` (m, k) with each inserted row (not in `keep`, ascending) scaled by exp(-d / `tau_s`), d (s) its time
    to the nearest sample that arrived (an inserted row before `keep[0]` has the previous block's last sample at
    index -1); kept rows as they are. `tau_s` <= 0: `rows` unchanged (the line itself)."""
    if tau_s <= 0.0 or keep.shape[0] == rows.shape[0]:
        return rows
    return _taper_inserted(np.ascontiguousarray(rows, dtype=np.float64), keep, dt_s, tau_s)


@njit
def _taper_inserted(rows: FloatArray, keep: NDArray[np.int64], dt_s: float, tau_s: float) -> FloatArray:
    out = rows.copy()
    _taper_in_place(out, keep, dt_s, tau_s)
    return out


@njit
def _taper_in_place(rows: FloatArray, keep: NDArray[np.int64], dt_s: float, tau_s: float) -> None:
    """`taper_inserted` on `rows` itself (numba: also a column view, as `_bridge_rows` passes)."""
    left = -1  # the last kept row before row r
    at = 0  # the first entry of `keep` at or after row r
    for r in range(rows.shape[0]):
        if at < keep.shape[0] and keep[at] == r:
            left = r
            at += 1
            continue
        right = keep[min(at, keep.shape[0] - 1)]
        d = min(r - left, right - r)
        rows[r] *= np.exp(-d * dt_s / tau_s)


_NO_ROWS = np.empty((0, 3))
_NO_TIMES = np.empty(0)


def bridge_block(gyr: FloatArray, acc: FloatArray, mag: FloatArray | None, t_s: FloatArray, dt_s: float,
                 prev: tuple[FloatArray, FloatArray, FloatArray | None, FloatArray] | None,
                 max_gap_s: float = MAX_BRIDGE_S, average_n: int = 1, gyro_taper_s: float = 0.0,
                 tol_s: FloatArray | None = None,
                 ) -> tuple[FloatArray, FloatArray, FloatArray | None, NDArray[np.int64]] | None:  # fmt: skip
    """`fill_gaps` of one device's block (gyr, acc, mag or None; (n, 3) each; times `t_s`) after its previous block
    `prev` (gyr, acc, mag, t_s; None: none; its mag must be there as this one's is, or it is not used): the filled
    gyr (inserted rates tapered with `gyro_taper_s`, `taper_inserted`), acc, mag and `keep`, or None when nothing
    was missing; `tol_s` as in `fill_gaps`. One numba call (`_bridge_rows`): under overload every device that lost
    a packet comes here each batch, and the numpy stitching around `_fill_gaps` cost more than the fill."""
    n = t_s.shape[0]
    if n == 0:
        return None
    use_mag, rows_mag = (True, mag) if mag is not None else (False, _NO_ROWS)
    w = max(1, average_n)
    p_gyr, p_acc, p_mag, p_t = _NO_ROWS, _NO_ROWS, _NO_ROWS, _NO_TIMES
    if prev is not None and (prev[2] is not None) == use_mag:  # else the previous block is not used
        p_gyr, p_acc, p_t = prev[0][-w:], prev[1][-w:], prev[3][-w:]
        if use_mag:
            p_mag = prev[2][-w:]  # type: ignore[index]
    tol = np.full(n, (GAP_FACTOR - 1.0) * dt_s) if tol_s is None else np.ascontiguousarray(tol_s, dtype=np.float64)
    out, keep = _bridge_rows(gyr, acc, rows_mag, use_mag, t_s, p_gyr, p_acc, p_mag, p_t,
                             dt_s, max_gap_s, w, gyro_taper_s, tol)  # fmt: skip
    if out.shape[0] == n:
        return None
    return out[:, :3], out[:, 3:6], out[:, 6:9] if use_mag else None, keep


@njit
def _bridge_rows(gyr: FloatArray, acc: FloatArray, mag: FloatArray, use_mag: bool, t_s: FloatArray,
                 p_gyr: FloatArray, p_acc: FloatArray, p_mag: FloatArray, p_t: FloatArray, dt_s: float,
                 max_gap_s: float, w: int, taper_s: float, tol_s: FloatArray) -> tuple[FloatArray, NDArray[np.int64]]:
    """`bridge_block` in one call: the previous block's tail (`p_*`, p rows; none: 0 rows) and the block stitched
    as `np.hstack` / `np.concatenate` would, `_fill_gaps`, and the inserted gyroscope rows tapered
    (`_taper_in_place`): the same operations in the same order, so the same floats."""
    p, n = p_t.shape[0], t_s.shape[0]
    k = 9 if use_mag else 6
    times = np.empty(p + n)
    stitched = np.empty((p + n, k))
    for i in range(p + n):
        src, gy, ac, mg = (i, p_gyr, p_acc, p_mag) if i < p else (i - p, gyr, acc, mag)
        times[i] = p_t[src] if i < p else t_s[src]
        for c in range(3):
            stitched[i, c] = gy[src, c]
            stitched[i, 3 + c] = ac[src, c]
            if use_mag:
                stitched[i, 6 + c] = mg[src, c]
    out, keep = _fill_gaps(times, stitched, p, dt_s, max_gap_s, w, tol_s)
    if taper_s > 0.0 and out.shape[0] > n:
        _taper_in_place(out[:, :3], keep, dt_s, taper_s)
    return out, keep


def coast_mask(n_rows: int, keep: NDArray[np.int64], min_run: int) -> NDArray[np.bool_]:
    """(n_rows,) bool: the inserted rows (not in `keep`) of every gap of at least `min_run` of them, which a filter
    with a model of its own (`run_bridged`) carries across on that model rather than on the interpolation."""
    inserted = np.ones(n_rows, dtype=np.bool_)
    inserted[keep] = False
    if min_run <= 1:  # every inserted run (the default, `COAST_MIN_S` 0)
        return inserted
    edges = np.flatnonzero(np.diff(np.r_[0, inserted.astype(np.int8), 0]))
    out = np.zeros(n_rows, dtype=np.bool_)
    for a, b in zip(edges[::2].tolist(), edges[1::2].tolist(), strict=True):
        if b - a >= min_run:
            out[a:b] = True
    return out
