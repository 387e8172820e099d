"""The hook through `gateway.pipeline.Pipeline` in process (the packets bench.hook_e2e sends, no zenoh): free-swing
accuracy, a hook already swinging at start, and the per-device rope length / rest heading settings."""

from __future__ import annotations

import dataclasses
import math
import time
from pathlib import Path

import numpy as np

from bench.hook_e2e import Case, HookFleet, _scenario_t_s, analyse, fleet_settings, make_case, run_in_process
from gateway import schemas
from gateway.config import DeviceSettings
from gateway.fusion import hook as hook_geo
from gateway.fusion.hook_mount import TiltedHookFilter
from gateway.pipeline import Pipeline


def test_free_swing_through_the_pipeline_meets_the_target() -> None:
    """Free swing from 12 s after a violent 1.6 m/s² trolley kick, through the pipeline (9D, legacy sensor model):
    swing RMSE < 0.35° (measured 0.29° on seed 2; 0.038° before issue 11, see test_hook_filter's free-swing test for
    why such kicks now cost more); bearing relative to the start heading and torsion within 16° (measured 13.4° and
    5°; 6.0° and 6.4° before)."""
    case = make_case("free", 30.0, 1.0, 2, None)
    rec, _, _ = run_in_process(case, 30.0, 2)
    r = analyse(rec, case.excitation_end_s, 12.0)["free"]
    assert r["n"] > 250
    assert r["swing_angle_max_deg"] > 3.0
    assert r["swing_angle_rmse_deg"] < 0.35, r
    assert r["direction_rel_rmse_deg"] < 16.0, r
    assert r["torsion_rmse_deg"] < 16.0, r


def test_hook_swinging_at_start_converges() -> None:
    """5° swing from the first sample (python -m devices.sim_hook's default start): the warm-up is not at rest, so
    the filter must not assume plumb; Θ within 0.15° RMSE from 10 s on (measured 0.05°; with the rest prior it
    was 0.09° and 0.12° over 5-40 s)."""
    base = make_case("free", 22.0, 1.0, 4, None)
    sc = dataclasses.replace(base.scenario, trolley_moves=(), initial_swing_rad=math.radians(5.0),
                             initial_swing_bearing_rad=math.radians(30.0))  # fmt: skip
    rec, _, _ = run_in_process(Case(sc, 0.0), 22.0, 4)
    r = analyse(rec, 0.0, 10.0)["free"]
    assert r["swing_angle_max_deg"] > 4.0
    assert r["swing_angle_rmse_deg"] < 0.15, r


def _packets(n: int, seed: int = 5) -> list[schemas.ImuPacket]:
    fleet = HookFleet(fleet_settings(n * 0.05, seed), make_case("free", n * 0.05, 100.0, seed, 0.0), seed)
    out = []
    for k in range(n):
        data, _ = fleet.tick(k)
        p = schemas.decode(data[0][0].key, data[0][0].payload)
        assert isinstance(p, schemas.ImuPacket)
        out.append(p)
    return out


def test_rope_length_setting_reaches_the_filter_and_a_change_restarts_fusion() -> None:
    """A configured length is told to the filter (a tight prior); none configured (the default) leaves the filter
    to find it (wide prior from its 10 m): telling it 10 m regardless diverged on short ropes. Each change, to or
    from none included, restarts the device's fusion; the same setting again does not."""
    pipe = Pipeline()
    pkts = _packets(60)
    dev_id = pkts[0].device_id

    def told() -> float | None:
        s = pipe.devices[dev_id].filt.settings  # type: ignore[union-attr]
        return s.rope_length_m if s.rope_length_known else None

    assert Pipeline().defaults["hook"].rope_length_m is None  # type: ignore[union-attr]
    pipe.process(pkts[:15], now_wall_s=1e9)
    assert told() is None, "no configured length: the filter is not told one"
    pipe.set_device_settings(dev_id, "hook", DeviceSettings(thresholds={"rope_length_m": 25.0}))
    assert dev_id not in pipe.devices, "configuring a length restarts the device's fusion"
    pipe.process(pkts[15:30], now_wall_s=1e9)
    assert told() == 25.0
    pipe.set_device_settings(dev_id, "hook", DeviceSettings(thresholds={"rope_length_m": 25.0}))
    assert dev_id in pipe.devices, "the same length again changes nothing"
    pipe.set_device_settings(dev_id, "hook", DeviceSettings(thresholds={"rope_length_m": 12.0}))
    assert dev_id not in pipe.devices, "a new rope length restarts the device's fusion"
    pipe.process(pkts[30:45], now_wall_s=1e9)
    assert told() == 12.0
    pipe.set_device_settings(dev_id, "hook", DeviceSettings(thresholds={"rope_length_m": None}))
    assert dev_id not in pipe.devices, "clearing the length restarts the device's fusion"
    pipe.process(pkts[45:], now_wall_s=1e9)
    assert told() is None


def test_imu_offset_setting_reaches_the_filter_and_a_change_restarts_fusion() -> None:
    """`imu_offset_m` (the IMU's measured offset from the rope axis) becomes the hook filter's lever arm with the
    told prior; each change (to or from none) restarts the device's fusion, the same offset again does not."""
    pipe = Pipeline()
    pkts = _packets(60)
    dev_id = pkts[0].device_id

    def lever() -> tuple[float, float, float] | None:
        return pipe.devices[dev_id].filt.settings.imu_offset_told  # type: ignore[union-attr]

    pipe.process(pkts[:15], now_wall_s=1e9)
    assert lever() is None, "none configured: the filter's own mount (0.1 m on x, learnt)"
    pipe.set_device_settings(dev_id, "hook", DeviceSettings(thresholds={"imu_offset_m": [0.25, -0.01, 0.0]}))
    assert dev_id not in pipe.devices, "configuring the mount restarts the device's fusion"
    pipe.process(pkts[15:30], now_wall_s=1e9)
    assert lever() == (0.25, -0.01, 0.0)
    filt = pipe.devices[dev_id].filt
    assert filt.settings.lever_arm_m == (0.25, -0.01, 0.0)  # type: ignore[union-attr]
    pipe.set_device_settings(dev_id, "hook", DeviceSettings(thresholds={"imu_offset_m": [0.25, -0.01, 0.0]}))
    assert dev_id in pipe.devices, "the same offset again changes nothing"
    pipe.set_device_settings(dev_id, "hook", DeviceSettings(thresholds={"imu_offset_m": None}))
    assert dev_id not in pipe.devices, "clearing it restarts the device's fusion"
    pipe.process(pkts[30:45], now_wall_s=1e9)
    assert lever() is None
    assert not isinstance(pipe.devices[dev_id].filt, TiltedHookFilter)
    pipe.set_device_settings(dev_id, "hook", DeviceSettings(thresholds={"imu_tilt_deg": [1.5, -0.5]}))
    assert dev_id not in pipe.devices, "a tilt restarts the device's fusion"
    pipe.process(pkts[45:], now_wall_s=1e9)
    filt = pipe.devices[dev_id].filt
    assert isinstance(filt, TiltedHookFilter) and filt.imu_tilt_told == (1.5, -0.5)
    assert pipe.devices[dev_id].quat is not None and np.isfinite(pipe.devices[dev_id].quat).all()
    pipe.set_device_settings(dev_id, "hook", DeviceSettings(thresholds={"imu_tilt_deg": [1.5, -0.5]}))
    assert dev_id in pipe.devices, "the same tilt again changes nothing"
    pipe.set_device_settings(dev_id, "hook", DeviceSettings(thresholds={"imu_tilt_deg": [1.5, -0.5],
                                                                        "acc_bias_xy_m_s2": [0.03, -0.01]}))
    assert dev_id not in pipe.devices, "the accelerometer's measured offset restarts the device's fusion"
    pipe.process(pkts[45:], now_wall_s=1e9)
    assert pipe.devices[dev_id].filt.settings.acc_bias_xy_told == (0.03, -0.01)  # type: ignore[union-attr]


def test_torsion_is_measured_from_the_configured_rest_heading() -> None:
    """Hanging still (no torque): torsion ≈ 0 (< 2°) from the first fused heading; with rest_heading_deg set,
    torsion is the twist heading minus that setting."""
    pkts = _packets(30)
    dev_id = pkts[0].device_id
    pipe = Pipeline()
    out = pipe.process(pkts[:20], now_wall_s=1e9)
    assert abs(out.swings[-1].torsion_rad) < math.radians(2.0)  # the mag-weighted heading settles by ~1°
    pipe.set_device_settings(dev_id, "hook", DeviceSettings(thresholds={"rest_heading_deg": 40.0}))
    out = pipe.process(pkts[20:], now_wall_s=1e9)
    alpha = hook_geo.twist_heading(np.array(out.attitudes[-1].quat_wxyz))
    expected = math.remainder(float(alpha) - math.radians(40.0), 2 * math.pi)
    assert out.swings[-1].seq == out.attitudes[-1].seq
    assert abs(math.remainder(out.swings[-1].torsion_rad - expected, 2 * math.pi)) < 1e-9


def test_rope_length_and_rest_heading_over_rest(tmp_path: Path) -> None:
    """The existing settings endpoints carry the hook settings: validated (422 with a readable message), stored per
    device, and the device's hook filter is built with the rope length once its packets arrive."""
    from fastapi.testclient import TestClient

    from gateway.app import create_app
    from gateway.config import Settings
    from gateway.ingest.bus import MemoryBus

    settings = Settings(data_dir=tmp_path / "data", zenoh_listen=[])
    bus = MemoryBus()
    with TestClient(create_app(settings, lambda _: bus, warm_up=False)) as client:
        auth = {"Authorization": f"Bearer {(settings.data_dir / 'api_token').read_text().strip()}"}
        bad = client.put("/api/thresholds/hook", json={"rope_length_m": 0.1}, headers=auth)
        assert bad.status_code == 422 and "rope_length_m" in str(bad.json()["detail"])
        bad = client.put("/api/thresholds/hook", json={"imu_offset_m": [0.1, 0.0, 2.0]}, headers=auth)
        assert bad.status_code == 422 and "imu_offset_m" in str(bad.json()["detail"])
        pkts = _packets(20)
        dev_id = pkts[0].device_id
        r = client.put(f"/api/devices/{dev_id}/settings", headers=auth,
                       json={"kind": "hook", "thresholds": {"rope_length_m": 18.0, "rest_heading_deg": -30.0,
                                                            "imu_offset_m": [0.2, 0.0, 0.05]}})
        assert r.status_code == 200, r.text
        assert r.json()["effective"]["thresholds"]["rope_length_m"] == 18.0
        assert r.json()["effective"]["thresholds"]["rest_heading_deg"] == -30.0
        service = client.app.state.service  # type: ignore[attr-defined]
        for p in pkts:
            bus.put(schemas.imu_key("hook", dev_id), p.model_dump_json().encode(), encoding=schemas.ENCODING_IMU)
        deadline = time.monotonic() + 30.0
        while dev_id not in service.pipeline.devices:
            assert time.monotonic() < deadline, "the hook's fusion did not start"
            time.sleep(0.05)
        filt = service.pipeline.devices[dev_id].filt
        assert filt.settings.rope_length_m == 18.0
        assert filt.settings.lever_arm_m == (0.2, 0.0, 0.05)
        assert service.pipeline.devices[dev_id].rest_heading_set_rad == math.radians(-30.0)


def test_a_hook_not_told_its_rope_and_swinging_at_start_is_redone_through_the_pipeline() -> None:
    """Suite crane 1696 (15 m, swinging 6.3° and twisting at start) through the pipeline as bench.hook_e2e's device
    sends it (5-sample packets), no rope length configured: the filter starts again told the length it found, and
    the hook's torsion reference is retaken from its redone start and follows the filter's North (`north_turn_rad`);
    direction within 7° and torsion within 2° RMSE from 12 s (measured 4.7° / 0.86°; without the re-start 11.6° /
    8.3°; re-started, the reference neither retaken nor following: 4.7° / 4.4°; retaken only: 4.7° / 4.1°)."""
    case = make_case("suite:1696", 60.0, 3.0, 1, None)
    rec, _, _ = run_in_process(case, 60.0, 1, tell_length=False)
    r = analyse(rec, 0.0, 12.0)["all"]
    assert r["n"] > 1000
    assert r["direction_rmse_deg"] < 7.0, r
    assert r["torsion_rmse_deg"] < 2.0, r


def test_a_told_hooks_torsion_reference_follows_the_filters_north() -> None:
    """Suite crane 1721 (5.4 m, told its rope length) through the pipeline, 60 s: the torsion reference, the heading
    read at the first fused sample, follows the turn the filter's output takes as it learns the compass's hard iron
    (`HookFilter.north_turn_rad`), so that turn is not reported as twist: torsion within 1.5° RMSE from 12 s
    (measured 0.54°; 2.97° with the reference fixed at the first sample)."""
    case = make_case("suite:1721", 60.0, 3.0, 1, None)
    rec, _, _ = run_in_process(case, 60.0, 1)
    r = analyse(rec, 0.0, 12.0)["all"]
    assert r["n"] > 1000
    assert r["torsion_rmse_deg"] < 1.5, r


def _swing_alarm_times(seed: int, duration_s: float) -> tuple[list[float], list[float]]:
    """Device seconds of the `hook_swing` alarms raised for suite crane `seed` through the pipeline, not told its
    rope length (the default), as bench.hook_e2e's device sends it; and of its Swing messages marked provisional."""
    case = make_case(f"suite:{seed}", duration_s, 3.0, 1, None)
    hooks = HookFleet(fleet_settings(duration_s, 1), case, 1)
    pipe = Pipeline()
    times, provisional = [], []
    for k in range(int(duration_s * 20)):
        data, _ = hooks.tick(k)
        out = pipe.process([schemas.decode(data[0][0].key, data[0][0].payload)], now_wall_s=1e9)
        times += [k * 0.05 for a in out.alarms if a.change.alarm.type == "hook_swing"]
        provisional += [k * 0.05 for sw in out.swings if sw.provisional]
    return times, provisional


def test_a_hook_not_told_its_rope_and_swinging_at_start_raises_no_alarm_before_its_start_is_redone(
        monkeypatch) -> None:  # fmt: skip
    """Tuning crane 29 (2.3 m, swinging 3.6° at start, at most 4.1° over these 12 s): not told its rope length, the
    filter starts at plumb on a length it does not know and read up to 12° until it started again told the length it
    found (at 3 s), and the swing warning (5°) rose at the first fused sample. A hook whose start may still be redone
    (`HookFilter.start_pending`) is not judged until it is: no swing alarm, and its Swing messages are marked
    `provisional` meanwhile; with the hold off, the warning at 0.45 s. (5 of 33 tuning cranes swinging at start
    raised such a warning.)"""
    from gateway.fusion.hook_filter import HookFilter

    alarms, provisional = _swing_alarm_times(29, 12.0)
    assert alarms == []
    # its Swing messages said so until the start was redone (measured: the last at 2.9 s)
    assert provisional and provisional[0] < 1.0 and 2.5 < provisional[-1] < 4.0, provisional
    monkeypatch.setattr(HookFilter, "start_pending", property(lambda self: False))
    early, provisional = _swing_alarm_times(29, 12.0)
    assert early and early[0] < 1.0, early
    assert provisional == []


def test_a_configured_rest_heading_brings_an_honest_torsion_sigma_to_every_swing() -> None:
    """Fresh crane 2863 (2.4 m, MPU-6050-class board, the e2e device's) through the pipeline with its rope length and
    true rest heading configured, 60 s: every Swing carries `torsion_std_rad`; it reads 25° at the first one (the
    compass's hard iron not learnt yet) and 0.5° at the last, and the absolute torsion error (1.17° RMS from 1 s) is
    within 2σ on 98.8 % of them (measured; bound 95 %). Without the rest heading no Swing carries a σ (the torsion is
    then the twist since the first fused heading)."""
    case = make_case("suite:2863", 60.0, 3.0, 1, None, "legacy")
    rec = run_in_process(case, 60.0, 1, rest_heading=True)[0]
    r = analyse(rec, 0.0, 12.0, rest_heading=True)["all"]
    std = [s["torsion_std_rad"] for _, s in rec.decoded("/swing")]
    assert r["n"] > 1000 and r["n_sigma"] == r["n"] and None not in std
    assert r["torsion_within_2sigma"] >= 0.95, r
    assert math.degrees(std[0]) > 10.0 and 0.5 <= math.degrees(std[-1]) < 1.5, (std[0], std[-1])
    plain = run_in_process(case, 10.0, 1)[0]
    assert all(s.get("torsion_std_rad") is None for _, s in plain.decoded("/swing"))


def test_after_a_compass_drop_the_torsion_sigma_holds_the_heading_it_cannot_check() -> None:
    """Crane 3357 (3.1 m, swinging 7.4° and twisting at start; the e2e's 121-s draw on its device's board, whose
    hard iron the filter learns mirrored) with its true rest heading configured: the compass test drops the compass
    at 6 s with the published torsion 55° off, which the covariance alone put at 2.3° (1σ). The heading the dropped
    compass left and the gyroscope's since the start (the twin's) disagreed there by 37°: σ holds that from the drop
    on (measured 36.6°), so the error is within 2σ again."""
    case = make_case("suite:3357", 120.0, 3.0, 1, None, "legacy")
    rec = run_in_process(case, 12.0, 1, rest_heading=True)[0]
    truth = {p.seq: p for _, p in rec.decoded("/truth") if isinstance(p, schemas.HookTruth)}
    after = [(math.remainder(s["torsion_rad"] - truth[s["seq"]].torsion_rad[-1], 2 * math.pi), s["torsion_std_rad"])
             for _, s in rec.decoded("/swing") if _scenario_t_s(truth[s["seq"]]) > 7.0]  # fmt: skip
    assert len(after) > 50
    assert min(abs(e) for e, _ in after) > math.radians(30.0)  # the case is real: the heading kept is far off
    assert all(abs(e) <= 2.0 * s for e, s in after), [(math.degrees(e), math.degrees(s)) for e, s in after[:3]]
