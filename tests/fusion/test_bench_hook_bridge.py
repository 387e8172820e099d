"""`bench.hook_bridge_cost`: it times both kinds of hook call and accounts for every packet offered."""

from __future__ import annotations

from bench.hook_bridge_cost import _line, replay


def test_the_bridge_cost_bench_times_plain_and_bridged_calls_and_counts_every_offered_packet() -> None:
    """A 20-s crane with half its packets lost after 2 s: both call kinds are timed (bridged ones exist), each
    call's kernel time is part of its whole time, and the packets offered are those after 2 s, lost or not."""
    r = replay(4, 20.0, 0.5, 2.0)
    n_run, whole_run, kernel_run = r["run"]
    n_bridged, whole_bridged, kernel_bridged = r["bridged"]
    assert n_run > 10 and n_bridged > 10
    assert 0.0 < kernel_run <= whole_run and 0.0 < kernel_bridged <= whole_bridged
    offered, spent = r["offered"]
    assert offered == (2000 - 200) // 10  # 10-sample packets from 2 s to 20 s at 100 Hz
    assert n_run + n_bridged < offered  # the lost ones cost nothing
    assert spent >= whole_run + whole_bridged - 1e-9
    assert "per packet offered" in _line("4", r)
