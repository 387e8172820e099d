"""The rod fleet without zenoh: packets validate, truth aligns with data, commands are obeyed."""

from __future__ import annotations

import math

import numpy as np
import pytest

from devices import _quat, common, sim_rod
from devices.common import FleetSettings, ImuErrorModel
from gateway import schemas


def fleet(count: int = 2, script: list | None = None, **kw: object) -> sim_rod.RodFleet:
    return sim_rod.RodFleet(FleetSettings(count=count, seed=11, samples_per_packet=5, id_prefix="rod"),
                            script=script or [], **kw)  # type: ignore[arg-type]


def decoded(f: sim_rod.RodFleet, k: int) -> tuple[list, list]:
    data, extra = f.tick(k)
    return ([schemas.decode(m.key, m.payload) for msgs in data for m in msgs],
            [schemas.decode(m.key, m.payload) for m in extra])


def test_imu_and_truth_share_seq_time_and_samples() -> None:
    f = fleet()
    for k in range(3):
        data, truth = decoded(f, k)
        imus = [p for p in data if isinstance(p, schemas.ImuPacket)]
        assert [p.device_id for p in imus] == ["rod-1", "rod-2"]
        for imu, tr in zip(imus, truth, strict=True):
            assert isinstance(tr, schemas.RodTruth)
            assert (imu.seq, imu.t0_us, imu.n, imu.boot_id) == (tr.seq, tr.t0_us, len(tr.quat_wxyz), tr.boot_id)
            assert imu.seq == k and imu.wall_t0_us == tr.wall_t0_us
    # the two devices have distinct boot ids and clocks
    assert imus[0].boot_id != imus[1].boot_id and imus[0].t0_us != imus[1].t0_us


def test_measured_gravity_agrees_with_the_truth_attitude() -> None:
    f = fleet(count=1, error_model=ImuErrorModel.ideal())
    data, truth = decoded(f, 0)
    imu = next(p for p in data if isinstance(p, schemas.ImuPacket))
    q = np.array(truth[0].quat_wxyz)
    expect = common.specific_force_body(q, np.zeros((len(q), 3)))
    np.testing.assert_allclose(np.array(imu.acc_m_s2), expect, atol=1e-4)
    pitch = _quat.to_euler(q)[:, 1]
    np.testing.assert_allclose(pitch, truth[0].rest_pitch_rad, atol=1e-6)


def test_scripted_bite_on_one_device_is_labelled_in_its_truth_only() -> None:
    f = fleet(script=[{"type": "bite", "t_s": 0.06, "depth_deg": 20, "duration_s": 1.0, "device": "rod-2"}])
    labels: dict[str, list[str]] = {"rod-1": [], "rod-2": []}
    pitch: dict[str, list[float]] = {"rod-1": [], "rod-2": []}
    for k in range(30):  # 1.5 s
        _, truth = decoded(f, k)
        for t in truth:
            labels[t.device_id] += [f"{e.label}:{e.phase}" for e in t.events]
            pitch[t.device_id] += _quat.to_euler(np.array(t.quat_wxyz))[:, 1].tolist()
    assert labels == {"rod-1": [], "rod-2": ["bite:start", "bite:end"]}
    drop2 = math.degrees(pitch["rod-2"][0] - min(pitch["rod-2"]))
    drop1 = math.degrees(pitch["rod-1"][0] - min(pitch["rod-1"]))
    assert drop2 > 15.0 and drop1 < 0.1


def test_reel_command_is_obeyed_and_acknowledged() -> None:
    f = fleet()
    cmd = schemas.ReelCommand(v=1, cmd_id=42, action="in", speed_m_s=0.5, drag_n=20.0, sent_wall_us=1)
    f.on_command(schemas.reel_cmd_key("rod-2"), cmd.to_json())
    f.on_command(schemas.reel_cmd_key("rod-2"), b"garbage")  # ignored, logged
    statuses = []
    for k in range(40):  # 2 s
        data, _ = decoded(f, k)
        statuses += [p for p in data if isinstance(p, schemas.ReelStatus) and p.device_id == "rod-2"]
    first, last = statuses[0], statuses[-1]
    assert first.last_cmd_id == 42 and first.mode == "in" and first.drag_n == 20.0
    assert last.motor == "reeling_in" and last.line_in_speed_m_s == pytest.approx(0.5, abs=0.01)
    assert first.line_out_m - last.line_out_m == pytest.approx(0.5 * 1.8, abs=0.15)
    assert [s.seq for s in statuses] == list(range(len(statuses)))
    assert f.cmd_speed[0] == 0.0  # rod-1 untouched


def test_cli_help_and_script_loading(capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit):
        sim_rod.main(["--help"])
    assert "--random-events" in capsys.readouterr().out
    assert sim_rod.load_script('[{"type": "bite", "t_s": 1}]') == [{"type": "bite", "t_s": 1}]
    with pytest.raises(ValueError):
        sim_rod.load_script('{"type": "bite"}')


@pytest.mark.parametrize("count", [2, 20])
def test_command_selectors_are_valid_key_expressions_matching_every_device(count: int) -> None:
    import zenoh

    from devices.sim_env_ball import BallFleet

    rods = fleet(count=count)
    balls = BallFleet(FleetSettings(count=count, seed=1, rate_hz=1.0, samples_per_packet=1, id_prefix="ball"))
    for f, key_of in ((rods, schemas.reel_cmd_key), (balls, schemas.ball_cmd_key)):
        sels = [zenoh.KeyExpr(s) for s in f.command_selectors]  # raises on an invalid expression
        for dev in f.ids:
            assert any(s.intersects(zenoh.KeyExpr(key_of(dev))) for s in sels)


def test_scenario_fleet_plays_the_recordings_with_labelled_truth_then_falls_silent() -> None:
    from devices.rod_scenarios import make_scenario
    from devices.sim_rod import ScenarioFleet

    fleet = ScenarioFleet(FleetSettings(count=2, seed=0, samples_per_packet=50, progress=False, id_prefix="rod"), 3)
    ticks = [fleet.tick(k) for k in range(601)]  # 600 packets = the whole 5 min, then one more
    for i, seed in enumerate((3, 4)):
        sc = make_scenario(seed)
        imu = [schemas.decode(m.key, m.payload) for data, _ in ticks for m in data[i]]
        assert all(isinstance(p, schemas.ImuPacket) for p in imu) and len(imu) == 600
        acc = np.concatenate([np.asarray(p.acc_m_s2) for p in imu if isinstance(p, schemas.ImuPacket)])
        np.testing.assert_allclose(acc, sc.acc_m_s2, atol=1e-5)  # the payload rounds to 10 µm/s²
        truths = [schemas.decode(m.key, m.payload) for _, extra in ticks for m in extra if f"/rod-{i + 1}/" in m.key]
        labels = [(e.label, e.phase) for p in truths if isinstance(p, schemas.RodTruth) for e in p.events]
        assert labels == [(e.family, ph) for e in sc.events for ph in ("start", "end")]
        first = imu[0]
        assert isinstance(first, schemas.ImuPacket) and isinstance(truths[0], schemas.RodTruth)
        assert truths[0].t0_us == first.t0_us and truths[0].seq == first.seq == 0
    assert ticks[-1] == ([[], []], [])


def test_binary_encoding_sends_the_same_packets_at_float32() -> None:
    """`--encoding binary`: the same rods with the same seed send protocol v2 packets that decode to the JSON
    packets' values rounded to float32, with the v2 zenoh encoding."""
    args = sim_rod.build_parser().parse_args(["--encoding", "binary"])
    assert common.FleetSettings.from_args(args).imu_encoding == "binary"
    settings = FleetSettings(count=2, seed=11, samples_per_packet=5, id_prefix="rod")
    as_json = sim_rod.RodFleet(settings, script=[])
    as_binary = sim_rod.RodFleet(FleetSettings(**{**settings.__dict__, "imu_encoding": "binary"}), script=[])
    for k in range(3):
        imu_j = [m for msgs in as_json.tick(k)[0] for m in msgs if m.key.endswith("/imu")]
        imu_b = [m for msgs in as_binary.tick(k)[0] for m in msgs if m.key.endswith("/imu")]
        for mj, mb in zip(imu_j, imu_b, strict=True):
            assert mb.payload[0] == schemas.IMU_BINARY_MAGIC and mb.encoding == schemas.ENCODING_IMU_BINARY
            pj, pb = schemas.decode(mj.key, mj.payload), schemas.decode(mb.key, mb.payload)
            assert isinstance(pj, schemas.ImuPacket) and isinstance(pb, schemas.ImuPacket)
            assert (pb.seq, pb.t0_us, pb.boot_id) == (pj.seq, pj.t0_us, pj.boot_id)
            assert pb.wall_t0_us is not None  # the wall clock is read at each tick, so not compared
            for a, b in zip(pj.arrays(), pb.arrays(), strict=True):
                assert a is not None and b is not None
                np.testing.assert_array_equal(a.astype(np.float32), b)
            assert len(mb.payload) < 0.6 * len(mj.payload)
