"""The pure pipeline: bites alarm and distractors do not (simulated rod, no transport), yaw unwrapping, spot
ranking, live settings changes, attitude decimation."""

from __future__ import annotations

import json
import math

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from gateway import schemas
from gateway.config import DeviceSettings, RodThresholds
from gateway.pipeline import Output, Pipeline, PipelineSettings, _unwrap
from tests.gateway.conftest import rod_messages


def run(p: Pipeline, messages: list[tuple[str, bytes]], per_batch: int = 1) -> list[Output]:
    packets = [schemas.decode(k, v) for k, v in messages]
    return [p.process(packets[i : i + per_batch], now_wall_s=1e9 + 0.05 * i) for i in range(0, len(packets), per_batch)]


def raised(outs: list[Output]) -> list[tuple[str, float]]:
    return [(c.alarm.type, c.alarm.started_at) for o in outs for _, c, _, _ in o.alarms if c.kind == "raised"]


def test_a_bite_alarms_once_near_its_start_and_handling_or_wind_do_not() -> None:
    script = [
        {"type": "handling", "t_s": 2.0, "duration_s": 3.0, "roll_deg": 30.0, "yaw_deg": 25.0},
        {"type": "wind", "t_s": 6.0, "duration_s": 4.0, "strength": 1.0},
        {"type": "bite", "t_s": 12.0, "depth_deg": 15.0, "duration_s": 1.5},
    ]
    messages = rod_messages(16.0, script)
    start_wall_s = json.loads(messages[0][1])["wall_t0_us"] * 1e-6
    alarms = raised(run(Pipeline(), messages))
    assert [a for a, _ in alarms] == ["bite"], alarms
    assert 12.0 <= alarms[0][1] - start_wall_s <= 12.5  # device wall time of the triggering sample


def test_batches_give_the_same_alarms_as_single_packets() -> None:
    messages = rod_messages(8.0, [{"type": "bite", "t_s": 4.0, "depth_deg": 15.0, "duration_s": 1.5}])
    one = raised(run(Pipeline(), messages, per_batch=1))
    many = raised(run(Pipeline(), messages, per_batch=25))
    assert [a for a, _ in one] == [a for a, _ in many] == ["bite"]
    assert abs(one[0][1] - many[0][1]) < 1e-6


def test_attitude_is_published_per_packet_and_decimated() -> None:
    messages = [m for m in rod_messages(3.0) if m[0].endswith("/imu")]
    outs = run(Pipeline(), messages, per_batch=10)
    atts = [a for o in outs for a in o.attitudes]
    # the filter starts once 0.5 s (10 packets) arrived and then runs over those samples too
    assert [a.seq for a in atts] == list(range(len(messages)))
    slow = [a for o in run(Pipeline(PipelineSettings(attitude_interval_s=0.1)), messages, 10) for a in o.attitudes]
    assert [a.seq for a in slow] == list(range(0, len(messages), 2))
    pitch = np.degrees([a.pitch_rad for a in atts])
    assert np.all(np.abs(pitch - 31.0) < 2.5), "the rod rests at about 31 deg"


def test_a_new_filter_choice_restarts_that_device_only() -> None:
    p = Pipeline()
    run(p, rod_messages(1.0))
    assert p.devices["rod-1"].filter_name == "default"
    p.set_device_settings("rod-1", "rod", DeviceSettings(filter_name="mahony"))
    assert "rod-1" not in p.devices
    run(p, rod_messages(1.0, seed=1))
    assert p.devices["rod-1"].filter_name == "mahony"


def test_thresholds_change_live() -> None:
    p = Pipeline()
    run(p, rod_messages(1.0))
    p.set_defaults("rod", RodThresholds(bite_deviation_deg=15.0))
    rod = p.devices["rod-1"].rod
    assert rod is not None and rod.thresholds.bite_deviation_deg == 15.0


def env(device_id: str, spot: str, oxygen: float, seq: int = 0) -> schemas.EnvPacket:
    return schemas.EnvPacket(
        v=1, device_id=device_id, boot_id=1, seq=seq, t_us=seq * 1_000_000, wall_t_us=1_700_000_000_000_000 + seq,
        spot=spot, air_temp_c=20.0, humidity_pct=60.0, light_lux=5000.0, water_temp_c=22.0, oxygen_mg_l=oxygen,
        probe_depth_m=2.0,
    )  # fmt: skip


def test_spots_rank_low_oxygen_last_and_are_rate_limited() -> None:
    p = Pipeline()
    out = p.process([env("ball-1", "reeds", 1.5), env("ball-2", "bay", 8.0)], now_wall_s=1e9)
    assert out.spots is not None
    assert [s.spot for s in out.spots.spots] == ["bay", "reeds"]
    assert [s.rank for s in out.spots.spots] == [1, 2]
    assert out.spots.spots[0].score > out.spots.spots[1].score
    assert p.process([env("ball-1", "reeds", 9.0, 1)], now_wall_s=1e9 + 0.5).spots is None  # < 1 s later
    later = p.process([], now_wall_s=1e9 + 1.5).spots
    assert later is not None and len(later.spots) == 2


@settings(max_examples=200, deadline=None)
@given(
    steps=st.lists(st.floats(-3.0, 3.0), min_size=2, max_size=60),
    start=st.floats(-math.pi, math.pi),
    split=st.integers(1, 59),
)
def test_unwrap_is_continuous_and_agrees_with_the_wrapped_yaw(steps: list[float], start: float, split: int) -> None:
    true = start + np.cumsum(steps)
    wrapped = np.angle(np.exp(1j * true))
    split = min(split, len(wrapped) - 1)
    a, turns = _unwrap(math.nan, 0, wrapped[:split])
    b, _ = _unwrap(float(wrapped[split - 1]), turns, wrapped[split:])
    u = np.concatenate([a, b])
    assert np.allclose(np.diff(u), np.diff(true), atol=1e-9)  # steps below pi are kept exactly
    assert np.allclose(np.angle(np.exp(1j * (u - wrapped))), 0.0, atol=1e-9)


def test_one_big_first_batch_gives_the_same_alarms_as_streaming() -> None:
    messages = rod_messages(6.0, [{"type": "bite", "t_s": 3.0, "depth_deg": 15.0, "duration_s": 1.5}])
    streamed = raised(run(Pipeline(), messages, per_batch=1))
    at_once = raised(run(Pipeline(), messages, per_batch=len(messages)))
    assert [a for a, _ in at_once] == [a for a, _ in streamed] == ["bite"]


def test_auto_reel_sends_controller_commands_only_while_on() -> None:
    p = Pipeline()
    messages = rod_messages(3.0, [{"type": "bite", "t_s": 1.5, "depth_deg": 15.0, "duration_s": 1.0}])
    assert p.set_auto_reel("rod-1", True)
    outs = run(p, messages[: len(messages) // 2])
    cmds = [c for o in outs for c in o.reel_commands]
    assert cmds and all(dev == "rod-1" and f["action"] in ("speed", "stop") for dev, f in cmds)
    p.set_auto_reel("rod-1", False)
    assert not [c for o in run(p, messages[len(messages) // 2 :]) for c in o.reel_commands]


def test_warm_up_leaves_no_state_behind() -> None:
    p = Pipeline()
    p.warm_up()
    assert p.devices == {} and p.kinds == {} and p._batch is None
    assert raised(run(p, rod_messages(6.0, [{"type": "bite", "t_s": 3.0, "depth_deg": 15.0}]))) != []


def test_a_big_first_batch_alarms_like_streaming() -> None:
    """One 6 s batch (filter and bite warm-ups, then a bite at 3 s) raises the bite at the same sample as
    packet-by-packet streaming: the rod rules decide sample by sample (tests/alarm/test_packetization.py)."""
    messages = rod_messages(6.0, [{"type": "bite", "t_s": 3.0, "depth_deg": 15.0, "duration_s": 1.5}])
    start_wall_s = json.loads(messages[0][1])["wall_t0_us"] * 1e-6
    streamed = raised(run(Pipeline(), messages, per_batch=1))
    whole = raised(run(Pipeline(), messages, per_batch=len(messages)))
    assert [a for a, _ in whole] == [a for a, _ in streamed] == ["bite"]
    assert 3.0 <= whole[0][1] - start_wall_s <= 3.5
    assert whole[0][1] == streamed[0][1]


def test_alarm_times_are_device_time_and_device_wall_only_when_the_device_sends_one() -> None:
    messages = rod_messages(6.0, [{"type": "bite", "t_s": 3.0, "depth_deg": 15.0, "duration_s": 1.5}])
    first = json.loads(messages[0][1])
    outs = run(Pipeline(), messages)
    (bite,) = [a for o in outs for a in o.alarms if a.change.kind == "raised"]
    assert 3.0 <= (bite.t_us - first["t0_us"]) * 1e-6 <= 3.5  # device clock, not wall
    assert bite.source_wall_us == bite.t_us + first["wall_t0_us"] - first["t0_us"]
    assert abs(bite.change.alarm.started_at - bite.source_wall_us * 1e-6) < 1e-6  # the store keeps wall time

    def no_wall(payload: bytes) -> bytes:
        d = json.loads(payload)
        d.pop("wall_t0_us", None)
        d.pop("wall_t_us", None)
        return json.dumps(d).encode()

    bare = [(k, no_wall(v)) for k, v in messages]
    outs = run(Pipeline(), bare)  # arrival times 1e9 + 0.05 i stand in for the wall clock
    (bite2,) = [a for o in outs for a in o.alarms if a.change.kind == "raised"]
    assert bite2.t_us == bite.t_us and bite2.source_wall_us is None
    assert 1e9 < bite2.change.alarm.started_at < 1e9 + 7.0


def test_attitude_blocks_carry_every_sample_whatever_the_batching() -> None:
    messages = [m for m in rod_messages(2.0) if m[0].endswith("/imu")]
    packets = [schemas.decode(k, v) for k, v in messages]
    s = PipelineSettings(attitude_blocks=True, attitude_interval_s=0.0)
    one, many = run(Pipeline(s), messages, per_batch=1), run(Pipeline(s), messages, per_batch=7)
    blocks = [b for o in one for b in o.attitude_blocks]
    assert [b.seq for b in blocks] == [p.seq for p in packets]  # the warm-up packets too
    for b, p in zip(blocks, packets, strict=True):
        assert isinstance(p, schemas.ImuPacket)
        assert (b.boot_id, b.t0_us, b.rate_hz, len(b.quat_wxyz)) == (p.boot_id, p.t0_us, p.rate_hz, p.n)
        assert b.wall_t0_us == p.wall_t0_us and b.filter == "default"
        assert b.t_us()[-1] == p.t0_us + round((p.n - 1) * 1e6 / p.rate_hz)
    # the packet-end Attitude is the block's last sample
    ends = {a.seq: a.quat_wxyz for o in one for a in o.attitudes}
    assert all(ends[b.seq] == b.quat_wxyz[-1] for b in blocks)
    q1 = np.array([q for b in blocks for q in b.quat_wxyz])
    q7 = np.array([q for o in many for b in o.attitude_blocks for q in b.quat_wxyz])
    np.testing.assert_allclose(q7, q1, rtol=0, atol=1e-12)  # batching does not change the estimate
    assert len(np.unique(q1.round(6), axis=0)) > len(packets), "per-sample attitudes, not one repeated per packet"
    assert not [b for o in run(Pipeline(), messages, per_batch=7) for b in o.attitude_blocks], "opt-in"


def test_warmup_bias_seed_can_be_turned_off() -> None:
    packets = [schemas.decode(k, v) for k, v in rod_messages(1.0) if k.endswith("/imu")][:10]  # one resting window
    gyr_mean = np.mean([s for p in packets for s in p.gyr_rad_s], axis=0)  # type: ignore[union-attr]
    bias = {}
    for seed in (True, False):
        p = Pipeline(PipelineSettings(warmup_bias_seed=seed))
        p.process(packets, now_wall_s=1e9)
        bias[seed] = np.array(p.bias_rad_s("rod-1"))
    assert np.linalg.norm(gyr_mean) > 0.03  # the simulated gyro bias, rad/s
    np.testing.assert_allclose(bias[True], gyr_mean, atol=0.002)  # seeded, then barely moved in 0.5 s
    assert np.linalg.norm(bias[False]) < 0.1 * np.linalg.norm(gyr_mean)  # from zero


def _hoist_packets(with_depth: bool) -> list[schemas.ImuPacket]:
    """A level hook lifted 2 m in 4 s between 3 s rests (analytic acceleration), 10 samples per packet at 100 Hz;
    with_depth: the packets carry depth = 5 m − height at their first sample."""
    from tests.fusion.test_heave import hoist_profile

    z, a = hoist_profile()
    n = (z.shape[0] // 10) * 10
    acc = np.zeros((n, 3))
    acc[:, 2] = 9.81 + a[:n]
    pkts = []
    for k in range(n // 10):
        s = slice(10 * k, 10 * k + 10)
        extra = {"depth_m": float(5.0 - z[10 * k])} if with_depth else {}
        pkts.append(schemas.ImuPacket(v=1, device_id="hook-7", kind="hook", boot_id=1, seq=k, t0_us=100_000 * k,
                                      rate_hz=100.0, gyr_rad_s=[(0.0, 0.0, 0.0)] * 10,
                                      acc_m_s2=[tuple(r) for r in acc[s]], **extra))  # fmt: skip
    return pkts


def test_height_is_published_per_device_at_10_hz_and_follows_a_hoist() -> None:
    """Through the real pipeline (hook, default hook filter): a Height every 0.1 s of device time, at rest before and
    after, ending at the 2 m lift within 5 cm; with a depth sensor the height is −depth (−3 m at the end) and says
    it is depth-aided."""
    for with_depth in (False, True):
        pkts = _hoist_packets(with_depth)
        p = Pipeline(PipelineSettings(attitude_interval_s=0.0))
        hs = [h for i in range(len(pkts)) for h in p.process([pkts[i]], now_wall_s=1e9 + 0.1 * i).heights]
        assert len(hs) == len(pkts)  # the 0.5 s warm-up packets are fused (and get heights) with the fifth
        assert np.allclose(np.diff([h.t_us for h in hs]), 100_000)
        want = -3.0 if with_depth else 2.0
        assert abs(hs[-1].height_m - want) < 0.05, hs[-1]
        assert hs[-1].at_rest and abs(hs[-1].vz_m_s) < 1e-9
        assert hs[-1].aided == ("depth" if with_depth else "rest")
        assert max(h.vz_m_s for h in hs) > 0.9  # the lift's 1 m/s peak
        assert schemas.Height.model_validate_json(hs[-1].to_json()) == hs[-1]


def test_spots_carry_the_position_of_their_ball_and_scores_are_0_to_1() -> None:
    fix = schemas.GnssFix(lat_deg=30.2468, lon_deg=120.1473, fix_quality=1)
    no_fix = schemas.GnssFix(lat_deg=0.0, lon_deg=0.0, fix_quality=0)
    a = env("ball-1", "deep", 8.0).model_copy(update={"gnss": fix})
    b = env("ball-2", "bay", 8.0).model_copy(update={"gnss": no_fix})
    out = Pipeline().process([a, b, env("ball-3", "reeds", 8.0)], now_wall_s=1e9)
    assert out.spots is not None
    by = {s.spot: s for s in out.spots.spots}
    assert (by["deep"].lat_deg, by["deep"].lon_deg) == (30.2468, 120.1473)
    assert by["bay"].lat_deg is None and by["reeds"].lat_deg is None  # invalid fix, no receiver
    assert all(0.0 <= s.score <= 1.0 for s in out.spots.spots) and by["deep"].score > 0.5
