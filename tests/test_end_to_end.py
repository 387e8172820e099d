"""End to end over real zenoh on loopback: a simulated rod PROCESS with scripted bites and distractors (handling
with roll/yaw, wind, waves) -> the gateway PROCESS (`python -m gateway`) -> alarms on `gw/rod/*/alarm`, seen by
an observer session. Every bite alarms; no distractor does. Multicast off, explicit endpoints, free ports."""

from __future__ import annotations

import math
from pathlib import Path

import pytest

from bench.bite_latency import analyse, bite_script, run_session
from gateway.config import RodThresholds

pytestmark = pytest.mark.timeout(180)


def test_every_bite_alarms_and_no_distractor_does(tmp_path: Path) -> None:
    n_bites = 3
    script = bite_script(n_bites, spacing_s=10.0, first_s=5.0)
    labels = {item["type"] for item in script}
    assert {"handling", "wind", "waves"} <= labels, "distractors between the bites"
    rec, rod = run_session(script, duration_s=5.0 + 10.0 * n_bites, seed=3, work=tmp_path)
    assert rod.returncode == 0, rod.stderr.decode()[-2000:]
    report = analyse(rec, math.radians(RodThresholds().effective_bite_deg))
    assert report.bites == n_bites, "the truth stream shows every scripted bite"
    ingest = {k: rec.gateway_stats.get(k) for k in ("received", "queue_drops", "rejected", "devices")}
    assert report.missed == 0, (report, ingest)
    assert report.false_alarms == [], report.false_alarms
    assert len(report.onset_ms) == n_bites
    assert all(0.0 < ms < 1000.0 for ms in report.onset_ms), report.onset_ms
