"""3-D view: rod and hook geometry against closed-form references, and the viser scene fed like the hub feeds it."""

from __future__ import annotations

import json
import math
import socket
import time
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from gateway import schemas
from gateway.config import Settings
from gateway.fusion import broad
from gateway.fusion import quaternion as quat
from gateway.fusion.registry import make_filter
from gateway.replay_view import euler_deg, load, replay_data, run, sensor_columns
from gateway.replay_view import main as replay_main
from gateway.view3d import (
    ALL,
    WATER_Z_M,
    View3D,
    cone_mesh,
    hook_geometry,
    raw_attitude,
    rod_curve,
    segments,
    torsion_arc,
)

angles = st.floats(-1.2, 1.2)


def test_straight_rod_reference() -> None:
    """Tip pitch = butt pitch = 30°, heading 0: a straight rod, tip at L(cos 30°, 0, sin 30°)."""
    pts = rod_curve(quat.from_euler(0.0, math.radians(30), 0.0), math.radians(30), length_m=3.0, n=5)
    assert pts[-1] == pytest.approx([3 * math.cos(math.radians(30)), 0.0, 1.5], abs=1e-12)
    assert pts[0] == pytest.approx([0.0, 0.0, 0.0])


def test_bent_rod_matches_numeric_integration() -> None:
    """Butt at +30°, tip pulled to −10° (a bite), heading 90° (North): the closed form equals a fine trapezoid
    integration of (cos θ(s), sin θ(s)) with θ linear in arc length."""
    L, tb, tt = 3.0, math.radians(30), math.radians(-10)
    pts = rod_curve(quat.from_euler(0.0, tt, math.pi / 2), tb, length_m=L, n=11)
    s = np.linspace(0.0, L, 100_001)
    th = tb + (tt - tb) * s / L
    h = np.concatenate(([0.0], np.cumsum((np.cos(th[1:]) + np.cos(th[:-1])) / 2 * np.diff(s))))
    z = np.concatenate(([0.0], np.cumsum((np.sin(th[1:]) + np.sin(th[:-1])) / 2 * np.diff(s))))
    idx = np.linspace(0, 100_000, 11).astype(int)
    assert pts[:, 0] == pytest.approx(np.zeros(11), abs=1e-12)  # heading North: no East component
    assert pts[:, 1] == pytest.approx(h[idx], abs=1e-8)
    assert pts[:, 2] == pytest.approx(z[idx], abs=1e-8)


@settings(max_examples=60, deadline=None)
@given(roll=angles, pitch=angles, yaw=st.floats(-3.1, 3.1), butt=angles)
def test_rod_length_and_tip_tangent(roll: float, pitch: float, yaw: float, butt: float) -> None:
    """The polyline is (nearly) the rod's length and its last segment points along the tip's body x."""
    q = quat.from_euler(roll, pitch, yaw)
    pts = rod_curve(q, butt, length_m=2.0, n=400)
    assert float(np.linalg.norm(np.diff(pts, axis=0), axis=1).sum()) == pytest.approx(2.0, rel=1e-4)
    tangent = (pts[-1] - pts[-2]) / np.linalg.norm(pts[-1] - pts[-2])
    x_tip = quat.rotate(q, np.array([1.0, 0.0, 0.0]))
    assert float(tangent @ x_tip) > math.cos(math.radians(1.0))


def test_hook_swing_reference() -> None:
    """Rope 8 m swung 10° about East: the hook moves 8 sin 10° horizontally and rises 8 (1 − cos 10°)."""
    a = math.radians(10)
    top, hook = hook_geometry(quat.from_axis_angle([1.0, 0.0, 0.0], a), rope_m=8.0)
    assert top == pytest.approx([0.0, 0.0, 8.0])
    assert abs(hook[1]) == pytest.approx(8 * math.sin(a), abs=1e-12)
    assert hook[2] == pytest.approx(8 * (1 - math.cos(a)), abs=1e-12)


@given(torsion=st.floats(-math.pi, math.pi), swing=st.floats(0.0, 1.0), bearing=st.floats(-math.pi, math.pi))
def test_torsion_does_not_move_the_hook(torsion: float, swing: float, bearing: float) -> None:
    """Turning the hook about its own rope (body z) leaves its position alone; the rope keeps its length."""
    axis = [math.cos(bearing), math.sin(bearing), 0.0]
    q_swing = quat.from_axis_angle(axis, swing)
    q = quat.multiply(q_swing, quat.from_axis_angle([0.0, 0.0, 1.0], torsion))
    top, hook = hook_geometry(q_swing, 5.0)
    _, hook_twisted = hook_geometry(q, 5.0)
    assert hook_twisted == pytest.approx(hook, abs=1e-9)
    assert float(np.linalg.norm(top - hook)) == pytest.approx(5.0)


@given(roll=st.floats(-1.0, 1.0), pitch=st.floats(-1.0, 1.0))
def test_raw_attitude_recovers_tilt(roll: float, pitch: float) -> None:
    """At rest the accelerometer reads R(q)ᵀ·(0, 0, g): the raw attitude gives back roll and pitch."""
    q = quat.from_euler(roll, pitch, 0.3)
    acc = quat.rotate_inverse(q, np.array([0.0, 0.0, 9.81]))
    e = quat.to_euler(raw_attitude(acc, None))
    assert e[:2] == pytest.approx([roll, pitch], abs=1e-9)


def test_segments_shape() -> None:
    pts = np.arange(12.0).reshape(4, 3)
    seg = segments(pts)
    assert seg.shape == (3, 2, 3)
    assert (seg[1] == pts[1:3]).all()


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def test_scene_follows_attitude_truth_and_picker(tmp_path: Path) -> None:
    """Feed the view like the hub (outputs, decoded packets) and the bus (truth) do; one step() draws the picked
    rod from the fused quaternion and the truth ghost from the truth packet; the picker lists the devices; raw appears
    when switched on."""
    view = View3D(Settings(viser_port=_free_port(), data_dir=tmp_path))
    try:
        q = quat.from_euler(0.0, math.radians(20), 0.5)
        att = schemas.Attitude(device_id="rod-1", kind="rod", seq=1, t_us=1, quat_wxyz=tuple(q), roll_rad=0.0,
                               pitch_rad=math.radians(20), yaw_rad=0.5, yaw_unwrapped_rad=0.5)  # fmt: skip
        view.on_hub("attitude", att)
        q_truth = quat.from_euler(0.0, math.radians(25), 0.4)
        view.on_truth("rig/rod/rod-1/truth", json.dumps({"quat_wxyz": [list(q_truth)]}).encode())
        view.on_packet(schemas.ImuPacket(v=1, device_id="rod-1", kind="rod", boot_id=1, seq=1, t0_us=0, rate_hz=100.0,
                                         gyr_rad_s=[(0.0, 0.0, 0.0)], acc_m_s2=[(0.0, 0.0, 9.81)]))  # fmt: skip
        view.step()
        assert tuple(view.pick.options) == (ALL, "rod-1") and view.pick.value == ALL  # every device shown
        nodes = view._nodes["rod-1"]
        expected = segments(rod_curve(q, math.radians(20)))
        assert np.asarray(nodes["fused_line"].points) == pytest.approx(expected, abs=1e-5)
        assert np.asarray(nodes["fused_frame"].wxyz) == pytest.approx(q, abs=1e-6)
        assert np.asarray(nodes["truth_frame"].wxyz) == pytest.approx(q_truth, abs=1e-6)
        assert nodes["truth_line"].visible and not nodes["raw_line"].visible  # raw off by default
        view.show_raw.value = True
        view.step()
        assert nodes["raw_line"].visible
        assert "rod-1" in view.status.content and "pitch 20.0" in view.status.content
        line = np.asarray(nodes["fishline"].points)
        assert line[0, 0] == pytest.approx(expected[-1, 1], abs=1e-6)  # the line leaves the rod tip
        assert line[-1, 1, 2] < WATER_Z_M  # ... and ends under water
    finally:
        view.stop()


def test_scene_shows_every_device_in_its_slot_and_the_picker_isolates_one(tmp_path: Path) -> None:
    view = View3D(Settings(viser_port=_free_port(), data_dir=tmp_path))
    try:
        for dev in ("rod-1", "hook-1"):
            kind = dev.split("-")[0]
            att = schemas.Attitude(device_id=dev, kind=kind, seq=1, t_us=1, quat_wxyz=(1.0, 0.0, 0.0, 0.0),  # type: ignore[arg-type]
                                   roll_rad=0.0, pitch_rad=0.0, yaw_rad=0.0, yaw_unwrapped_rad=0.0)  # fmt: skip
            view.on_hub("attitude", att)
        view.on_hub("swing", schemas.Swing(device_id="hook-1", seq=1, t_us=1, swing_angle_rad=0.1,
                                           swing_direction_rad=0.0, torsion_rad=math.radians(40.0)))  # fmt: skip
        view.step()
        rod, hook = view._nodes["rod-1"], view._nodes["hook-1"]
        assert rod["root"].visible and hook["root"].visible
        assert abs(rod["root"].position[1] - hook["root"].position[1]) >= 5.0  # side by side, not on top
        assert hook["cone"].visible and hook["torsion"].visible
        arc = np.asarray(hook["torsion"].points)
        assert math.degrees(math.atan2(arc[22, 1, 1], arc[22, 1, 0])) == pytest.approx(40.0, abs=0.5)  # arc ends at φ
        view.pick.value = "hook-1"
        view.step()
        assert not rod["root"].visible and hook["root"].visible
    finally:
        view.stop()


def test_a_plain_imu_is_drawn_as_its_board_frame_with_its_z_axis(tmp_path: Path) -> None:
    """An `imu` device (no rod, no hook): its fused frame above its slot, the line along its body z (a 90° roll
    about x turns body z to -y)."""
    view = View3D(Settings(viser_port=_free_port(), data_dir=tmp_path))
    try:
        c = math.cos(math.pi / 4)
        att = schemas.Attitude(device_id="imu-1", kind="imu", seq=1, t_us=1, quat_wxyz=(c, c, 0.0, 0.0), roll_rad=0.0,
                               pitch_rad=0.0, yaw_rad=0.0, yaw_unwrapped_rad=0.0)  # fmt: skip
        view.on_hub("attitude", att)
        view.step()
        nodes = view._nodes["imu-1"]
        assert "fused_hook" not in nodes and "bait" not in nodes
        line = np.asarray(nodes["fused_line"].points)[0]
        np.testing.assert_allclose(line[1] - line[0], [0.0, -0.6, 0.0], atol=1e-9)
        np.testing.assert_allclose(nodes["fused_frame"].position, line[0])
    finally:
        view.stop()


def test_cone_and_torsion_arc_reference_values() -> None:
    verts, faces = cone_mesh(np.array([0.0, 0.0, 4.0]), 4.0, math.radians(10.0), n=16)
    radii = np.hypot(verts[1:, 0], verts[1:, 1])
    assert radii == pytest.approx(4.0 * math.sin(math.radians(10.0)))  # every rope direction at the limit
    assert verts[1:, 2] == pytest.approx(4.0 - 4.0 * math.cos(math.radians(10.0)))
    assert faces.shape == (16, 3) and faces.max() == 16
    arc = torsion_arc(np.zeros(3), math.radians(-90.0), radius_m=1.0, n=10)
    assert arc[0, 0] == pytest.approx([1.0, 0.0, 0.0]) and arc[8, 1] == pytest.approx([0.0, -1.0, 0.0], abs=1e-9)
    assert arc.shape == (9 + 2, 2, 3)  # 9 arc segments + a two-stroke head
    assert torsion_arc(np.zeros(3), 0.0).shape[0] == 23  # no head when there is no twist


# -- replay view ----------------------------------------------------------------------------------------------------


def test_euler_deg_unwraps_yaw_and_keeps_gaps() -> None:
    """Yaw 170° -> 190° (wrapped to -170°) is shown continuous; a lost reference row stays NaN."""
    yaw = np.radians([170.0, 180.0, 190.0])
    q = quat.from_euler(np.zeros(3), np.radians([5.0, 5.0, 5.0]), yaw)
    q = np.vstack([q, np.full((1, 4), np.nan)])
    e = euler_deg(q)
    assert e[:3, 2] == pytest.approx([170.0, 180.0, 190.0], abs=1e-9)
    assert e[:3, 1] == pytest.approx([5.0, 5.0, 5.0], abs=1e-9)
    assert np.isnan(e[3]).all()


def _trial(q_ref: np.ndarray, rate_hz: float = 100.0) -> broad.Trial:
    n = q_ref.shape[0]
    z = np.zeros((n, 3))
    return broad.Trial("t", rate_hz, z, z, z, q_ref, z, np.zeros(n, dtype=bool))


def test_replay_data_error_is_the_rotation_between_estimate_and_reference() -> None:
    """Estimate = reference turned 5° about body x: error 5° everywhere the reference exists."""
    q_ref = quat.from_euler(np.zeros(4), np.linspace(0.0, 0.5, 4), np.linspace(-1.0, 1.0, 4))
    q_est = quat.multiply(q_ref, quat.from_axis_angle([1.0, 0.0, 0.0], math.radians(5.0)))
    q_ref[2] = np.nan
    d = replay_data(_trial(q_ref), q_est)
    assert d.error_deg[[0, 1, 3]] == pytest.approx([5.0, 5.0, 5.0], abs=1e-9)
    assert np.isnan(d.error_deg[2])
    assert d.t_s == pytest.approx([0.0, 0.01, 0.02, 0.03])
    assert d.index(0.016) == 2 and d.index(-1.0) == 0 and d.index(99.0) == 3
    w = d.window(0.015, 0.006)
    assert (w.start, w.stop) == (1, 3)


def test_replay_loads_a_gateway_recording(tmp_path: Path) -> None:
    """A .rigrec of a simulated rod (imu + reel records): the rod's IMU samples become the trial, the filter runs,
    the estimate has unit norm; no optical reference, so no error."""
    from gateway.recording.format import Record, write_recording
    from tests.gateway.conftest import rod_messages

    msgs = rod_messages(1.0)
    path = tmp_path / "rod.rigrec"
    write_recording(path, [Record(k, p, i * 1000) for i, (k, p) in enumerate(msgs)], {"source": "test"})
    n_imu = sum(1 for k, _ in msgs if k.endswith("/imu"))
    data = run(path, "mahony", "6D")
    assert data.q_est.shape == (5 * n_imu, 4)
    assert np.linalg.norm(data.q_est, axis=1) == pytest.approx(np.ones(5 * n_imu), abs=1e-9)
    assert np.isnan(data.error_deg).all()
    assert abs(data.euler_est_deg[-1, 1]) > 5.0  # the rod rests tip-up in its holder: pitch well above 0


def test_replay_on_broad_matches_the_filter_run(broad_dir: Path) -> None:
    """First 4 s of a BROAD trial: the replay's estimate error is the evaluate error (same filter, same start)."""
    path = sorted(broad_dir.glob("01_*.mat"))[0]
    trial = broad.load_trial(path).slice(0, 1144)
    q_est = broad.run_filter(make_filter("mahony", use_mag=True), trial, "9D")
    d = replay_data(trial, q_est)
    ok = np.isfinite(d.error_deg)
    expected = np.degrees(quat.angle_between(q_est[ok], trial.quat_ref[ok]))
    assert d.error_deg[ok] == pytest.approx(expected, abs=1e-12)
    assert np.nanmedian(d.error_deg) < 20.0  # a sane filter on BROAD (heading offset included)


def test_replay_cli_help_and_missing_file(capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as exc:
        replay_main(["--help"])
    assert exc.value.code == 0 and "BROAD" in capsys.readouterr().out
    assert replay_main(["/nonexistent/file.mat"]) == 2


def test_replay_raw_sensor_curves_beside_the_attitude() -> None:
    """Seed 004's curves: gyro in °/s, acc in m/s², mag in µT, x/y/z columns around the slider time, decimated to
    about max_points; a recording without a magnetometer (all NaN) has no mag curves."""
    n = 1000
    rng = np.random.default_rng(1)
    gyr, acc = rng.normal(0, 1, (n, 3)), rng.normal(0, 9, (n, 3))
    q = np.tile([1.0, 0.0, 0.0, 0.0], (n, 1))
    trial = broad.Trial("t", 100.0, gyr, acc, np.full((n, 3), np.nan), q, np.zeros((n, 3)), np.ones(n, dtype=bool))
    d = replay_data(trial, q)
    t, x, y, z = sensor_columns(d, "gyr_deg_s", 5.0, 1.0)  # type: ignore[misc]
    w = d.window(5.0, 1.0)
    assert t == pytest.approx(d.t_s[w]) and x == pytest.approx(np.degrees(gyr[w, 0]), abs=1e-12)
    assert z == pytest.approx(np.degrees(gyr[w, 2]), abs=1e-12)
    t2, ax, *_ = sensor_columns(d, "acc_m_s2", 5.0, 100.0, max_points=100)  # type: ignore[misc]
    assert 100 <= len(t2) <= 200 and ax == pytest.approx(acc[:: n // 100, 0][: len(ax)])
    assert sensor_columns(d, "mag_uT", 5.0, 1.0) is None


def test_replay_opens_an_exported_logger_file(tmp_path: Path) -> None:
    """A recording exported by `gateway.recording.export` (CSV) replays: same samples, filter run, curves there."""
    from gateway.recording.export import CsvExporter, export_recording
    from gateway.recording.format import Record, write_recording
    from tests.gateway.conftest import rod_messages

    msgs = rod_messages(1.0)
    path = tmp_path / "rod.rigrec"
    write_recording(path, [Record(k, p, i * 1000) for i, (k, p) in enumerate(msgs)], {"source": "test"})
    with CsvExporter(tmp_path / "csv") as ex:
        export_recording(path, ex)
    from_rec, from_csv = run(path, "mahony", "6D"), run(ex.files[0], "mahony", "6D")
    assert from_csv.q_est.shape == from_rec.q_est.shape
    assert from_csv.gyr_deg_s == pytest.approx(from_rec.gyr_deg_s, abs=1e-6)
    assert from_csv.euler_est_deg[-1] == pytest.approx(from_rec.euler_est_deg[-1], abs=1e-3)


def test_replay_of_a_simulator_recording_uses_its_truth_and_the_rod_model(tmp_path: Path) -> None:
    """Issue 17: a simulator recording (imu + truth) said "no reference" and drew a generic board."""
    from devices.common import FleetSettings
    from devices.sim_rod import RodFleet
    from gateway.recording.format import Record, write_recording

    fleet = RodFleet(FleetSettings(count=1, seed=3, samples_per_packet=5, progress=False, id_prefix="rod", truth=True))
    records, n_imu = [], 0
    for k in range(100):  # 5 s
        data, extra = fleet.tick(k)
        for m in data[0] + extra:
            records.append(Record(m.key, m.payload, len(records) * 1000))
            n_imu += m.key.endswith("/imu")
    assert any(r.key.endswith("/truth") for r in records)
    path = tmp_path / "sim.rigrec"
    write_recording(path, records, {"source": "test"})
    loaded = load(path)
    assert (loaded.kind, loaded.reference) == ("rod", "simulator truth")
    assert np.isfinite(loaded.trial.quat_ref).all() and loaded.trial.n == 5 * n_imu
    data = run(path, "default", "6D")
    assert data.kind == "rod" and data.reference == "simulator truth"
    # 6D: heading is free, so compare the tilt: after 2.5 s pitch and roll follow the truth within 2°
    tilt = np.abs(data.euler_est_deg[250:, :2] - data.euler_ref_deg[250:, :2])
    assert np.median(tilt, axis=0) == pytest.approx([0.0, 0.0], abs=2.0)


def test_replay_of_a_simulated_hook_uses_the_hook_filter_and_model(tmp_path: Path) -> None:
    """A hook recording replays with the gateway's hook filter (rope-aware) against the simulator's truth."""
    from bench.hook_e2e import HookFleet, fleet_settings, make_case
    from gateway.pipeline import HOOK_FILTER
    from gateway.recording.format import Record, write_recording
    from gateway.replay_view import KIND_FILTERS

    assert KIND_FILTERS["hook"] == HOOK_FILTER  # the replay runs what the gateway runs
    fleet = HookFleet(fleet_settings(8.0, 5), make_case("free", 8.0, 100.0, 5, 0.0), 5)
    records = []
    for k in range(160):  # 8 s at 20 packets/s
        data, extra = fleet.tick(k)
        for m in data[0] + extra:
            records.append(Record(m.key, m.payload, len(records) * 1000))
    path = tmp_path / "hook.rigrec"
    write_recording(path, records, {"source": "test"})
    data = run(path, None, "9D")
    assert (data.kind, data.reference) == ("hook", "simulator truth")
    tilt = np.abs(data.euler_est_deg[400:, :2] - data.euler_ref_deg[400:, :2])
    assert np.median(tilt, axis=0) == pytest.approx([0.0, 0.0], abs=2.0)  # after 4 s the hook follows the truth


def test_view_keeps_nothing_while_no_browser_watches(tmp_path: Path) -> None:
    """Started without a client, the drawing thread marks the view unwatched within a frame: the hub's outputs
    and packets then cost nothing there (before, every attitude was converted and kept whether or not anyone
    looked); once watched they are kept again."""
    view = View3D(Settings(viser_port=_free_port(), data_dir=tmp_path), rate_hz=50.0)
    view.start()
    try:
        deadline = time.monotonic() + 5.0
        while view.watched and time.monotonic() < deadline:
            time.sleep(0.01)
        assert not view.watched
        att = schemas.Attitude(device_id="rod-1", kind="rod", seq=1, t_us=1, quat_wxyz=(1.0, 0.0, 0.0, 0.0),
                               roll_rad=0.0, pitch_rad=0.0, yaw_rad=0.0, yaw_unwrapped_rad=0.0)  # fmt: skip
        view.on_hub("attitude", att)
        assert view.devices == {}
        view.watched = True  # as the thread sets it when a browser connects
        view.on_hub("attitude", att)
        assert list(view.devices) == ["rod-1"]
    finally:
        view.stop()
