"""Hook simulator shell: packets decode with gateway.schemas, truth is consistent, chunks equal one shot."""

from __future__ import annotations

import math

import numpy as np

from devices import sim_hook
from devices.common import FleetSettings
from devices.hook_physics import HookPhysicsSettings, HookScenario, HookStream, simulate
from gateway import schemas
from gateway.fusion import hook


def test_streaming_in_chunks_equals_one_shot():
    settings = HookPhysicsSettings(internal_rate_hz=500.0)
    scenario = HookScenario(duration_s=3.0, initial_swing_rad=0.2, initial_torsion_rad=0.3)
    whole = simulate(settings, scenario)
    stream = HookStream(settings, scenario)
    parts = [stream.advance(n) for n in (7, 100, 93, 100)]
    np.testing.assert_allclose(np.concatenate([p.quat for p in parts]), whole.quat, atol=1e-12)
    np.testing.assert_allclose(np.concatenate([p.acc_m_s2 for p in parts]), whole.acc_m_s2, atol=1e-12)
    np.testing.assert_allclose(np.concatenate([p.t_s for p in parts]), whole.t_s, atol=1e-12)


def test_fleet_packets_decode_and_truth_matches_the_attitude():
    args = sim_hook.build_parser().parse_args(["--count", "2", "--seed", "4", "--swing-deg", "6", "--no-progress"])
    fleet = sim_hook.make_fleet(args, FleetSettings.from_args(args))
    imu: dict[str, list[schemas.ImuPacket]] = {}
    truth: dict[str, list[schemas.HookTruth]] = {}
    for k in range(20):
        data, extra = fleet.tick(k)
        for m in [m for msgs in data for m in msgs] + extra:
            packet = schemas.decode(m.key, m.payload)
            target = imu if isinstance(packet, schemas.ImuPacket) else truth
            target.setdefault(schemas.parse_key(m.key).device_id, []).append(packet)  # type: ignore[arg-type]
    assert sorted(imu) == sorted(truth) == ["hook-1", "hook-2"]
    for dev in imu:
        assert [p.seq for p in imu[dev]] == list(range(20))
        assert all(p.kind == "hook" and p.n == 10 and p.mag_uT is not None for p in imu[dev])
        q = np.array([s for p in truth[dev] for s in p.quat_wxyz])
        theta = np.array([s for p in truth[dev] for s in p.swing_angle_rad])
        np.testing.assert_allclose(hook.swing_angle(q), theta, atol=1e-6)
        assert abs(theta[0] - math.radians(6.0)) < 1e-6
        # the accelerometer sees tension along the rope (body z) plus sensor errors, not a tilted gravity
        acc = np.array([s for p in imu[dev] for s in p.acc_m_s2])
        assert np.all(np.abs(acc[:, :2]) < 1.0) and np.all(acc[:, 2] > 8.5)
    # two hooks get different weather and swing bearings
    assert imu["hook-1"][5].gyr_rad_s != imu["hook-2"][5].gyr_rad_s


def test_main_runs_briefly_without_a_gateway():
    """The whole CLI path with a real zenoh session (no peers): it starts, publishes and stops on --duration."""
    assert sim_hook.main(["--duration", "0.3", "--connect", "none", "--no-progress", "--seed", "1"]) == 0


def test_cli_pulls_hoists_and_slews_reach_the_physics():
    args = sim_hook.build_parser().parse_args(["--load-kg", "2000", "--pull", "10,3,200,90", "--hoist", "20,10,-0.5",
                                               "--slew", "40,20,60,25", "--no-progress", "--seed", "1"])  # fmt: skip
    fleet = sim_hook.make_fleet(args, FleetSettings.from_args(args))
    sc, physics = fleet.streams[0].scenario, fleet.streams[0].settings
    assert physics.hook_mass_kg == 2000.0
    (pull,) = sc.pulls
    assert pull.start_s == 10.0 and pull.duration_s == 3.0
    np.testing.assert_allclose(pull.force_n, (0.0, 200.0), atol=1e-9)
    assert sc.hoists[0].speed_m_s == -0.5
    assert sc.slews[0].angle_rad == math.radians(60.0) and sc.slews[0].radius_m == 25.0


def test_crane_feed_publishes_the_slews_tip_acceleration():
    """`--crane-feed`: one CraneMotion per IMU packet on rig/hook/{id}/crane, at the IMU's wall time and rate, with
    the boom tip's horizontal acceleration of the slew (here tangential + centripetal, about 0.07 m/s² 15 s in;
    0 before the slew starts)."""
    args = sim_hook.build_parser().parse_args(["--slew", "5,40,60,30", "--crane-feed", "--swing-deg", "0"])
    fleet = sim_hook.make_fleet(args, FleetSettings(count=1, seed=3, samples_per_packet=10, progress=False,
                                                    id_prefix="hook"))  # fmt: skip
    tips = []
    for k in range(200):  # 20 s
        data, _ = fleet.tick(k)
        imu_msg, crane_msg = data[0]
        assert crane_msg.key == schemas.crane_key("hook-1")
        imu, crane = schemas.decode(imu_msg.key, imu_msg.payload), schemas.decode(crane_msg.key, crane_msg.payload)
        assert isinstance(imu, schemas.ImuPacket) and isinstance(crane, schemas.CraneMotion)
        assert (crane.wall_t0_us, crane.rate_hz, crane.n) == (imu.wall_t0_us, imu.rate_hz, imu.n)
        tips.append(np.hypot(*np.asarray(crane.tip_acc_m_s2).T))
    mag = np.concatenate(tips)
    assert mag[:450].max() == 0.0
    assert 0.02 < mag[1500] < 0.2
