"""The hot path's shared outputs: the hub computes each batch's dashboard points once for every sink, the live
stream buffers nothing while nobody reads it, the batched sample conversion and the batched Swing fields give
exactly what the per-device and per-message code gave."""

from __future__ import annotations

import math
from types import SimpleNamespace
from typing import Any

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from gateway import schemas
from gateway.api.ws import ClientQueue, LiveStream
from gateway.fusion import hook as hook_geo
from gateway.fusion.bank import gather, gather_all
from gateway.hub import Hub, listens_to, wants
from gateway.ingest.bus import MemoryBus
from gateway.pipeline import Output, Pipeline, PipelineSettings
from gateway.views import plot_point
from tests.gateway.test_kinds import PERIOD_S, T0_WALL_S, mixed_batches


def attitude(device_id: str, seq: int, pitch_rad: float) -> schemas.Attitude:
    return schemas.Attitude(v=1, device_id=device_id, kind="rod", seq=seq, t_us=seq, wall_t_us=10**15 + seq,
                            quat_wxyz=(1.0, 0.0, 0.0, 0.0), roll_rad=0.0, pitch_rad=pitch_rad, yaw_rad=0.0,
                            yaw_unwrapped_rad=0.0)  # fmt: skip


def test_hub_hands_each_batch_s_points_to_every_plot_sink_once() -> None:
    """Both sinks get the same list, once per emit: the points of the attitudes published (the newest per device)
    and of every swing."""
    hub = Hub(MemoryBus(), writer=None)  # type: ignore[arg-type]  # no alarms: the store writer is not used
    got: list[list[Any]] = [[], []]
    hub.plot_listeners += [got[0].append, got[1].append]
    swing = schemas.Swing(device_id="hook-1", seq=1, t_us=1, wall_t_us=10**15, swing_angle_rad=0.1,
                          swing_direction_rad=0.2, torsion_rad=0.3)  # fmt: skip
    out = Output(attitudes=[attitude("rod-1", 1, 0.1), attitude("rod-2", 1, 0.2), attitude("rod-1", 2, 0.3)],
                 swings=[swing])  # fmt: skip
    hub.emit(out)
    hub.emit(Output())  # nothing plotted: no call
    want = [plot_point(m) for m in (out.attitudes[1], out.attitudes[2], swing)]
    assert got[0] == [want] and got[1] is not got[0] and got[1] == [want]
    assert got[0][0] is got[1][0]  # computed once, shared


def test_a_listener_marked_for_some_topics_gets_only_those_and_unmarked_ones_get_all() -> None:
    """`listens_to`: the hub calls a marked listener only for its topics (decided once per batch and topic), an
    unmarked one for every published model, each in publishing order; what was published is the same."""
    hub = Hub(MemoryBus(), writer=None)  # type: ignore[arg-type]  # no alarms: the store writer is not used
    every: list[tuple[str, Any]] = []
    swings: list[tuple[str, Any]] = []
    hub.listeners += [lambda t, m: every.append((t, m)),
                      listens_to("swing", "reel_cmd")(lambda t, m: swings.append((t, m)))]  # fmt: skip
    swing = schemas.Swing(device_id="hook-1", seq=1, t_us=1, wall_t_us=10**15, swing_angle_rad=0.1,
                          swing_direction_rad=0.2, torsion_rad=0.3)  # fmt: skip
    height = schemas.Height(device_id="rod-1", kind="rod", seq=1, t_us=1, wall_t_us=10**15, vz_m_s=0.0, height_m=0.1,
                            at_rest=True, aided="rest")  # fmt: skip
    out = Output(attitudes=[attitude("rod-1", 1, 0.1), attitude("rod-2", 1, 0.2)], swings=[swing], heights=[height])
    hub.emit(out)
    cmd = hub.send_reel("rod-1", "stop")
    assert every == [("attitude", out.attitudes[0]), ("attitude", out.attitudes[1]), ("swing", swing),
                     ("height", height), ("reel_cmd", cmd)]  # fmt: skip
    assert swings == [("swing", swing), ("reel_cmd", cmd)]
    # two attitudes, their gw/attitudes batch (not a listener's model), the swing and the height
    assert hub.published == 5 and [wants(cb, "height") for cb in hub.listeners] == [True, False]


def live_stream() -> LiveStream:
    svc = SimpleNamespace(pipeline=SimpleNamespace(kinds={"rod-1": "rod"}), accept=None)
    return LiveStream(svc)  # type: ignore[arg-type]


def test_live_stream_buffers_nothing_while_nobody_reads_it() -> None:
    live = live_stream()
    points = [p for p in (plot_point(attitude("rod-1", 1, 0.1)),) if p is not None]
    packet = schemas.ImuPacket(v=1, device_id="rod-1", kind="rod", boot_id=1, seq=1, t0_us=0, rate_hz=100.0,
                               gyr_rad_s=[(0.0, 0.0, 0.0)], acc_m_s2=[(0.0, 0.0, 9.8)])  # fmt: skip
    live.on_plot(points)
    live.on_packet(packet)
    assert not live._series and not live._imu
    live.clients.add(ClientQueue(4))  # a browser connected: buffered from now on
    live.on_plot(points)
    live.on_packet(packet)
    assert len(live._series["rod-1"].t_s) == 1 and len(live._imu["rod-1"]) == 1
    live.clients.clear()
    live.remote = True  # another endpoint's client wants this shard's frames
    live.on_plot(points)
    assert len(live._series["rod-1"].t_s) == 2


triples = st.tuples(*[st.floats(-30.0, 30.0, allow_nan=False)] * 3)  # within every sensor's range
packets = st.lists(triples, min_size=1, max_size=6).map(lambda rows: schemas.ImuPacket(
    v=1, device_id="d", kind="rod", boot_id=1, seq=1, t0_us=1000, rate_hz=100.0, gyr_rad_s=rows,
    acc_m_s2=[(x + 1.0, y, z) for x, y, z in rows], mag_uT=[(z, y, x) for x, y, z in rows] if len(rows) % 2 else None,
))  # fmt: skip


@settings(max_examples=60, deadline=None)
@given(st.lists(st.lists(packets, min_size=1, max_size=3), min_size=1, max_size=4))
def test_gather_all_is_gather_per_device(groups: list[list[schemas.ImuPacket]]) -> None:
    """One conversion for all devices gives each device's own arrays, bit for bit (mag only when every packet
    of the device has it)."""
    for got, (gyr, acc, mag, t_s) in zip(gather_all(groups), map(gather, groups), strict=True):
        assert np.array_equal(got[0], gyr) and np.array_equal(got[1], acc) and np.array_equal(got[3], t_s)
        assert (got[2] is None) == (mag is None) and (mag is None or np.array_equal(got[2], mag))


@settings(max_examples=60, deadline=None)
@given(st.lists(st.lists(packets, min_size=1, max_size=3), min_size=1, max_size=4), st.booleans())
def test_gather_all_from_binary_rows_is_gather_per_device(groups: list[list[schemas.ImuPacket]], mixed: bool
                                                          ) -> None:  # fmt: skip
    """Packets decoded from the binary encoding (`schemas.decode_many`) bring their float32 rows, and `gather_all`
    concatenates those: the same float64 arrays, bit for bit, as gathering their float tuples (and with one JSON
    packet in the batch, the tuples of all)."""
    key = schemas.imu_key("rod", "d")
    decoded = [schemas.decode_many([(key, schemas.imu_to_binary(p)) for p in g]) for g in groups]
    binary = [[p for p in g if isinstance(p, schemas.ImuPacket)] for g in decoded]
    assert all(schemas.sample_rows(p) is not None for g in binary for p in g)
    if mixed:  # one packet without rows: the whole batch reads the tuples
        binary[0][0] = schemas.decode(key, binary[0][0].to_json())  # type: ignore[assignment]
        assert schemas.sample_rows(binary[0][0]) is None
    for got, (gyr, acc, mag, t_s) in zip(gather_all(binary), map(gather, binary), strict=True):
        for a, b in ((got[0], gyr), (got[1], acc), (got[3], t_s)):
            assert a.dtype == b.dtype and a.flags.c_contiguous == b.flags.c_contiguous and np.array_equal(a, b)
        assert (got[2] is None) == (mag is None) and (mag is None or np.array_equal(got[2], mag))


def test_swing_fields_are_the_per_message_formulas_of_the_packet_end_attitude() -> None:
    """Bearing and Φ, now computed for all Swings of a batch at once, equal the one-quaternion formulas on the
    attitude at the same packet end (every packet end published: intervals 0), with each hook's own reference."""
    pl = Pipeline(PipelineSettings(attitude_interval_s=0.0, swing_interval_s=0.0))
    atts: dict[tuple[str, int], schemas.Attitude] = {}
    swings: list[schemas.Swing] = []
    for k, batch in enumerate(mixed_batches(6.0)):
        out = pl.process(batch, T0_WALL_S + k * PERIOD_S)
        atts.update({(a.device_id, a.seq): a for a in out.attitudes if a.kind == "hook"})
        swings += out.swings
    assert len({s.device_id for s in swings}) == 2 and len(swings) > 100
    for s in swings:
        q = np.array(atts[(s.device_id, s.seq)].quat_wxyz)
        assert s.swing_angle_rad == float(hook_geo.swing_angle(q))
        assert s.swing_direction_rad == float(hook_geo.displacement_bearing(q))
        ref = s.rest_heading_rad
        assert math.isclose(s.swing_phi_rad or 0.0, float(hook_geo.swing_direction_paper(q, ref)), abs_tol=1e-12)
        assert math.isclose(s.torsion_rad, float(hook_geo.torsion(q, ref)), abs_tol=1e-12)
