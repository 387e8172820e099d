"""Hostile input fuzz at CI size (issue 13): schemathesis over the OpenAPI schema with 0 server errors, and hostile
zenoh packets among valid streams (every packet counted, rejects by reason, bounded state). Full size, with printed
figures: `python -m bench.hostile_fuzz`."""

from __future__ import annotations

from pathlib import Path

import pytest

from bench.hostile_fuzz import fuzz_rest, fuzz_zenoh, rest_server

pytestmark = pytest.mark.timeout(600)


def test_openapi_fuzz_gives_no_server_error(tmp_path: Path) -> None:
    pytest.importorskip("schemathesis")
    with rest_server(tmp_path) as server:
        result = fuzz_rest(server, examples=15)
    assert result["operations"] >= 12 and result["requests"] >= 100
    assert result["server_errors"] == []
    assert 422 in result["statuses"] and 200 in result["statuses"]  # it did reach past validation


def test_hostile_zenoh_packets_cost_nothing_else(tmp_path: Path) -> None:
    z = fuzz_zenoh(tmp_path, packets=3000, seed=1)
    assert z["received"] == z["expected"] and z["queue_drops"] == 0
    assert z["valid_ok"] == z["valid_streams"]  # no valid stream lost a packet
    assert z["health"] == "ok" and z["tick_devices"] >= z["valid_streams"]
    assert z["invalid_tokens"] == 20
    for reason in ("bad_json", "too_large", "unknown_key", "key_mismatch", "out_of_range", "schema"):
        assert z["rejected"].get(reason, 0) > 0, (reason, z["rejected"])
    assert z["rejected"].get("wall_time_ignored", 0) > 0 and z["rejected"].get("time_range", 0) > 0
    assert z["rejected"].get("device_conflict", 0) > 0  # the spoofed boots on rod-1 are reported
    assert z["raw_buffers"] <= 2 * z["devices_known"]
    binary = ("bin_damaged", "bin_not_finite", "bin_key_mismatch", "bin_kind_mismatch", "bin_t0_extreme")
    assert all(z["hostile_kinds"].get(k, 0) > 0 for k in binary), z["hostile_kinds"]  # protocol v2 packets too
