"""bench.heave feeds the heave estimator what the gateway feeds it: rates less the filter's running gyro bias."""

from __future__ import annotations

import numpy as np

from bench import heave as bench_heave
from devices.common import ImuErrorModel, SensorModel


def test_rates_are_less_the_bias_the_filter_held_before_each_packet() -> None:
    d = bench_heave.hoist(101)
    dt = float(d["dt"])
    g, a, m = SensorModel(ImuErrorModel.calibrated(), 1, np.random.default_rng(201)).measure(
        d["gyr"], d["acc"], d["mag"], dt)  # fmt: skip
    q, seen = bench_heave.fused_as_gateway("default", g, a, m, dt, 50)
    assert q.shape == (g.shape[0], 4) and np.allclose(np.linalg.norm(q, axis=1), 1.0)
    hold = slice(2000, 2500)  # a hold after the first hoist: the load hangs still, the true rate is 0
    raw_bias = np.linalg.norm(g[hold].mean(axis=0))
    left = np.linalg.norm(seen[hold].mean(axis=0))
    assert raw_bias > 0.02, "this draw has a gyro offset worth removing"
    assert left < 0.25 * raw_bias  # the filter learnt most of it within 20 s; the raw rates keep it all


def test_rest_is_detected_on_a_draw_whose_raw_gyro_offset_exceeds_the_rest_threshold() -> None:
    row = next(r for r in bench_heave.sim_rows("default", [101]) if "default (rest;" in r)
    rms_m, rest_pct = float(row.split("|")[3]), float(row.split("|")[7])
    assert rest_pct > 40.0  # the raw rates (0.053 rad/s here) never fell below the 0.05 rad/s rest threshold
    assert rms_m < 0.3  # 1.19 m when the bench fed raw rates
