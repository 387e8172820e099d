"""The gateway (fusion + rod rules, as the service runs them) on two tuning seeds of the rod scenario suite:
every bite and run alarms within 50 ms (device time) of the true theta1 crossing, nothing else raises a bite,
every drop-back is reported as one. `python -m bench.bite_suite` reports the untuned seeds."""

from __future__ import annotations

import pytest

from bench.bite_suite import run_gateway, score
from devices.rod_scenarios import make_scenario


@pytest.mark.parametrize("seed", [0, 1])
def test_suite_seed_meets_the_issue_10_targets(seed: int) -> None:
    sc = make_scenario(seed)
    run = run_gateway(sc)
    s = score(sc, run.bite_s, run.drop_s)
    assert s.caught["bite"] + s.caught["run"] == s.total["bite"] + s.total["run"] > 0, s.notes
    assert sum(s.false_bites.values()) == 0, s.notes
    assert 0.0 <= min(s.latency_ms) and max(s.latency_ms) <= 50.0, s.latency_ms
    assert s.caught["drop_back"] == s.total["drop_back"] and sum(s.false_drops.values()) == 0, s.notes
    assert all("below rest ≥ θ1 10.0°" in m for m in run.messages if " bite: " in m), run.messages
