"""Lost packets: the samples a filter never got, bridged so that its state crosses the gap in time.

A device's packets carry their samples' device times (`t0_us`, `rate_hz`). When a packet is lost on the link the
next one starts later than the sample period allows, but a filter fed the samples back to back would step across
the gap as if no time had passed: a rod's gyroscope integral misses the rotation during it (the accelerometer
takes seconds to pull it back), a hook's pendulum model its phase (the swing-rate innovations then look like a
boom-tip move). `fill_gaps` inserts the missing samples, interpolated linearly between the sample before the gap
and the one after, for the filter only: every output stays on the device's own samples (`keep`).

Gaps longer than `MAX_BRIDGE_S` are left as they are (an interpolation over seconds is a guess, not a bridge).
"""

from __future__ import annotations

import math

import numpy as np
from numpy.typing import NDArray

FloatArray = NDArray[np.float64]

MAX_BRIDGE_S = 2.0  # longest gap bridged, s (20 lost 10-sample packets at 100 Hz)
GAP_FACTOR = 1.5  # a spacing above this many sample periods is a gap (packet times are sample-exact to 1 µs)


def has_gap(t_s: FloatArray, prev_t_s: float, dt_s: float) -> bool:
    """Whether samples at device times `t_s` (s, ascending), after a sample at `prev_t_s` (nan: none), miss any
    sample: two float comparisons when there is none (span and start), so every device can be asked every batch."""
    n = t_s.shape[0]
    if n == 0:
        return False
    limit = GAP_FACTOR * dt_s
    return bool(t_s[0] - prev_t_s > limit or t_s[n - 1] - t_s[0] > (n - 1) * dt_s + (limit - dt_s))


def fill_gaps(t_s: FloatArray, rows: FloatArray, dt_s: float, prev_t_s: float, prev_row: FloatArray | None,
              max_gap_s: float = MAX_BRIDGE_S) -> tuple[FloatArray, NDArray[np.int64]] | None:  # fmt: skip
    """`rows` (n, k) at device times `t_s` (n,) with the samples missing before each one inserted, linearly
    interpolated between its neighbours (the first one's left neighbour: `prev_row` at `prev_t_s`, when given).

    Returns (filled rows (n + m, k), `keep` (n,): the index of each original row in them), or None when nothing was
    inserted (no gap, or every gap longer than `max_gap_s`). A gap of g seconds holds round(g / dt_s) - 1 samples."""
    n = t_s.shape[0]
    if n == 0:
        return None
    with_prev = prev_row is not None and math.isfinite(prev_t_s)
    times = np.concatenate(([prev_t_s], t_s)) if with_prev else t_s
    missing = np.rint(np.diff(times) / dt_s).astype(np.int64) - 1
    missing[(missing < 1) | (missing * dt_s > max_gap_s)] = 0
    if not missing.any():
        return None
    before = np.zeros(n, dtype=np.int64)  # samples inserted just before original row i
    before[(1 if not with_prev else 0):] = missing
    keep = np.arange(n, dtype=np.int64) + np.cumsum(before)
    out = np.empty((n + int(before.sum()), rows.shape[1]))
    out[keep] = rows
    first = prev_row[None, :] if prev_row is not None and with_prev else rows[:1]
    left = np.concatenate((first, rows[:-1]))  # each row's left neighbour
    for i in np.flatnonzero(before).tolist():  # gaps are rare: a loop over them, not over samples
        m = int(before[i])
        frac = (np.arange(1, m + 1) / (m + 1))[:, None]
        out[keep[i] - m : keep[i]] = left[i] + frac * (rows[i] - left[i])
    return out, keep


def bridge_block(gyr: FloatArray, acc: FloatArray, mag: FloatArray | None, t_s: FloatArray, dt_s: float,
                 prev_t_s: float, prev: tuple[FloatArray, FloatArray, FloatArray | None] | None,
                 max_gap_s: float = MAX_BRIDGE_S
                 ) -> tuple[FloatArray, FloatArray, FloatArray | None, NDArray[np.int64]] | None:  # fmt: skip
    """`fill_gaps` of one device's block (gyr, acc, mag or None; (n, 3) each) after its previous block `prev` (the
    arrays whose last row came just before, at `prev_t_s`; None: none, or a block of another shape): the filled
    gyr, acc, mag and `keep`, or None when nothing was missing."""
    cols = [gyr, acc] if mag is None else [gyr, acc, mag]
    rows = np.hstack(cols)
    prev_row = None
    if prev is not None and (prev[2] is None) == (mag is None):
        prev_row = np.concatenate([c[-1] for c in prev if c is not None])
    filled = fill_gaps(t_s, rows, dt_s, prev_t_s if prev_row is not None else math.nan, prev_row, max_gap_s)
    if filled is None:
        return None
    out, keep = filled
    return out[:, :3], out[:, 3:6], None if mag is None else out[:, 6:9], keep
