"""The dashboard history's batched fold (`OpenBuckets.fold`, fed by the hub's `PlotBatch` columns) keeps the same
buckets as the point-by-point fold it replaced, kept here as `ReferenceHistory`: the same ring rows, columns and
REST series on random streams (late points, gaps, NaN and inf values, fields arriving late, several points of a
device in one batch); and `PlotBatch` gives the points and degrees of `plot_point`."""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from types import SimpleNamespace
from typing import Any

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st
from numpy.typing import NDArray

from gateway import schemas
from gateway.api.routes.history import FIELDS, DeviceHistory, History, OpenBuckets, ring_columns
from gateway.views import PLOT_FIELDS, PlotBatch, plot_point


@dataclass
class _Bucket:
    t0_s: float
    t_s: float = 0.0
    n: dict[str, int] = field(default_factory=dict)
    value: dict[str, float] = field(default_factory=dict)

    def add(self, t_s: float, vals: dict[str, float]) -> None:
        if t_s > self.t_s:
            self.t_s = t_s
        count, value = self.n, self.value
        for k, v in vals.items():
            if not math.isfinite(v):
                continue
            n = count.get(k, 0)
            if n == 0:
                value[k] = v
            else:
                agg = FIELDS.get(k, "mean")
                if agg == "last":
                    value[k] = v
                elif agg == "max":
                    value[k] = max(value[k], v)
                else:
                    value[k] += (v - value[k]) / (n + 1)
            count[k] = n + 1


class ReferenceHistory:
    """`DeviceHistory` as it was before `OpenBuckets`: a `_Bucket` per device, folded point by point."""

    def __init__(self, bucket_s: float, maxlen: int) -> None:
        self.bucket_s = bucket_s
        self.maxlen = maxlen
        self.t_s = np.full(maxlen, np.nan)
        self.cols: dict[str, NDArray[np.float32]] = {}
        self.written = 0  # closed buckets so far; bucket i lives in row i % maxlen
        self._open: _Bucket | None = None

    def add(self, t_s: float, **vals: float) -> None:
        self.add_values(t_s, vals)

    def add_values(self, t_s: float, vals: dict[str, float]) -> None:
        """`add` with the values as one dict (the hub's plot points carry one)."""
        b = self._open
        if b is not None and t_s < b.t0_s:  # late sample of a closed bucket: dropped (histories are monotonic)
            return
        if b is None or t_s >= b.t0_s + self.bucket_s:
            if b is not None and b.value:
                self._close(b)
            b = self._open = _Bucket(t0_s=math.floor(t_s / self.bucket_s) * self.bucket_s)
        b.add(t_s, vals)

    def _close(self, b: _Bucket) -> None:
        row = self.written % self.maxlen
        self.t_s[row] = round(b.t_s, 3)
        for col in self.cols.values():
            col[row] = np.nan
        for k, v in b.value.items():
            if k not in self.cols:
                self.cols[k] = np.full(self.maxlen, np.nan, dtype=np.float32)
            self.cols[k][row] = v
        self.written += 1

    def columns(self, since_s: float, max_points: int) -> dict[str, list[float | None]]:
        b = self._open
        open_bucket = (b.t_s, b.value) if b is not None and b.value else None
        return ring_columns(self.t_s, self.cols, self.written, open_bucket, since_s, max_points)


NAMES = [*FIELDS, "other_field"]  # every kind of aggregate, and a field FIELDS does not list (a mean)
values = st.one_of(st.floats(-1e6, 1e6), st.sampled_from([math.nan, math.inf, -math.inf, 0.0, -0.0]))


@st.composite
def streams(draw: st.DrawFn) -> list[list[tuple[int, float, dict[str, float]]]]:
    """Batches of points (device, wall time s, values by field): time mostly moving on by 0-0.6 s per point and
    device, sometimes back (late points) or far ahead (gaps of several buckets)."""
    n_dev = draw(st.integers(1, 5))
    now = [draw(st.floats(1e9, 1e9 + 10.0)) for _ in range(n_dev)]
    batches = []
    for _ in range(draw(st.integers(1, 8))):
        batch = []
        for _ in range(draw(st.integers(0, 8))):
            d = draw(st.integers(0, n_dev - 1))
            now[d] += draw(st.sampled_from([0.0, 0.1, 0.25, 0.5, 0.6, -0.3, -1.0, 3.7]))
            names = draw(st.lists(st.sampled_from(NAMES), unique=True, max_size=4))
            batch.append((d, now[d], {k: draw(values) for k in names}))
        batches.append(batch)
    return batches


def state(h: DeviceHistory | ReferenceHistory) -> Any:
    cols = {k: v.tobytes() for k, v in h.cols.items()}
    return h.written, h.t_s.tobytes(), cols, h.columns(0.0, 10_000), h.columns(1e9 + 5.0, 7)


@settings(max_examples=300, deadline=None)
@given(streams())
def test_the_batched_fold_keeps_the_buckets_of_the_point_by_point_one(batches: list[list[Any]]) -> None:
    buckets = OpenBuckets()
    mine: dict[int, DeviceHistory] = {}
    ref: dict[int, ReferenceHistory] = {}
    for batch in batches:
        cols = buckets.columns_of(NAMES)
        rows, times, vals = [], [], np.full((len(batch), len(NAMES)), np.nan)
        for k, (d, t, v) in enumerate(batch):
            if d not in mine:
                mine[d], ref[d] = DeviceHistory(0.5, 6, buckets), ReferenceHistory(0.5, 6)
            rows.append(mine[d].row)
            times.append(t)
            for name, x in v.items():
                vals[k, NAMES.index(name)] = x
            ref[d].add_values(t, v)
        buckets.fold(np.array(rows, dtype=np.int64), np.array(times), cols, vals, 0.5)
        for d in mine:
            assert state(mine[d]) == state(ref[d])


@settings(max_examples=100, deadline=None)
@given(streams())
def test_one_point_at_a_time_keeps_the_buckets_of_the_reference(batches: list[list[Any]]) -> None:
    """`DeviceHistory.add_values` alone (the poll's and a standalone history's path), fields in any order."""
    mine, ref = DeviceHistory(0.5, 6), ReferenceHistory(0.5, 6)
    for batch in batches:
        for _, t, v in batch:
            mine.add_values(t, v)
            ref.add_values(t, v)
    assert state(mine) == state(ref)


angles = st.floats(-2 * math.pi, 2 * math.pi)
walls = st.sampled_from([10**15, 2**62, 2**62 + 1, 1_800_000_000_123_457])


@settings(max_examples=100, deadline=None)
@given(st.lists(st.tuples(st.integers(0, 3), angles, angles, angles, walls), max_size=8),
       st.lists(st.tuples(st.integers(0, 3), angles, angles, angles, walls), max_size=8))
def test_a_plot_batch_is_the_points_and_their_columns(atts: list[Any], swings: list[Any]) -> None:
    """Its points are `plot_point`'s; its columns the same degrees and times; a History fed the batch holds what
    one fed the points one by one holds."""
    a_models = [schemas.Attitude.model_construct(
        v=1, device_id=f"rod-{d}", kind="rod", seq=1, t_us=1, wall_t_us=w, quat_wxyz=(1.0, 0.0, 0.0, 0.0),
        roll_rad=r, pitch_rad=p, yaw_rad=0.0, yaw_unwrapped_rad=y) for d, r, p, y, w in atts]  # fmt: skip
    s_models = [schemas.Swing.model_construct(
        v=1, device_id=f"rod-{d}", seq=1, t_us=1, wall_t_us=w, swing_angle_rad=a, swing_direction_rad=b,
        torsion_rad=c) for d, a, b, c, w in swings]  # fmt: skip
    batch = PlotBatch(a_models, s_models)
    want = [plot_point(m) for m in [*a_models, *s_models]]
    assert len(batch) == len(want) and batch == want and list(batch) == want and batch[-1:] == want[-1:]
    ids, times, degrees = batch.columns()
    for k, (device_id, t_s, vals) in enumerate(want):  # type: ignore[misc]
        assert ids[k] == device_id and times[k] == t_s
        assert {f: degrees[k, PLOT_FIELDS.index(f)] for f in vals} == vals
        assert np.isnan(np.delete(degrees[k], [PLOT_FIELDS.index(f) for f in vals])).all()
    service = SimpleNamespace(accept=lambda d: d != "rod-3")
    fed, one_by_one = History(service), History(service)  # type: ignore[arg-type]
    fed.on_plot(batch)
    one_by_one.on_plot(want)  # type: ignore[arg-type]
    assert fed.devices.keys() == one_by_one.devices.keys() and "rod-3" not in fed.devices
    for d, h in fed.devices.items():
        assert state(h) == state(one_by_one.devices[d])
