"""End to end over real zenoh: a swinging, twisting hook PROCESS -> gateway PROCESS -> `gw/hook/*/swing`, compared
with ground truth by sequence number. Bounds are loose (they hold the transport, pipeline and units, not the
filter's last tenth of a degree, which `python -m bench.hook_e2e` measures)."""

from __future__ import annotations

from pathlib import Path

import pytest

from bench.hook_e2e import analyse, run_session

pytestmark = pytest.mark.timeout(180)


def test_swing_and_torsion_follow_the_truth_through_zenoh(tmp_path: Path) -> None:
    duration_s = 12.0
    rec, code = run_session(duration_s, still_s=2.0, seed=2, work=tmp_path)
    assert code == 0
    r = analyse(rec)
    assert r["n"] >= 0.8 * (duration_s - 1.5) / 0.05, "about one swing message per packet after warm-up"
    assert r["swing_angle_max_deg"] > 2.0, "the trolley move made the hook swing"
    assert r["swing_angle_rmse_deg"] < 1.5, r
    assert r["torsion_rmse_deg"] < 25.0, r
    assert r["direction_rmse_deg"] < 70.0, r
