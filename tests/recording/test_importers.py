"""Importers: BROAD packets decode with the gateway's decoder and rebuild the trial bit for bit; CSV units are
converted to SI and irregular phone timing is resampled onto a uniform grid."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest

from gateway import schemas
from gateway.fusion import broad
from gateway.recording import import_csv
from gateway.recording.format import read_meta, read_recording
from gateway.recording.import_broad import import_trial
from gateway.recording.importers import CsvFormatError, broad_records, parse_header, read_sensor_csv
from gateway.recording.score import recorded_trial

G = 9.80665


@pytest.mark.parametrize("spp", [1, 7, 10])
def test_broad_import_rebuilds_the_trial_exactly(tmp_path: Path, broad_dir: Path, spp: int) -> None:
    trial = broad.load_trial(broad_dir / "15_undisturbed_fast_translation_A.mat").slice(11_500, 11_500 + 503)
    path = import_trial(trial, tmp_path, "b-1", "rod", spp)
    recs = list(read_recording(path))
    imu = [schemas.decode(r.key, r.payload) for r in recs if r.key.endswith("/imu")]
    assert len(imu) == math.ceil(503 / spp) and all(isinstance(p, schemas.ImuPacket) for p in imu)
    assert [p.seq for p in imu] == list(range(len(imu)))
    assert [r.t_us for r in recs] == sorted(r.t_us for r in recs)
    rt = recorded_trial(recs)
    t = rt.trial
    for a, b in ((t.gyr_rad_s, trial.gyr_rad_s), (t.acc_m_s2, trial.acc_m_s2), (t.mag_uT, trial.mag_uT),
                 (t.quat_ref, trial.quat_ref), (t.pos_m, trial.pos_m)):  # fmt: skip
        np.testing.assert_array_equal(a, b)  # bit-identical, NaN where the optical reference was lost
    np.testing.assert_array_equal(t.movement, trial.movement)
    assert t.rate_hz == trial.rate_hz
    assert read_meta(path)["samples_per_packet"] == spp
    # every sample's device time maps back to its index
    idx = [rt.index(p.t0_us + round(i * 1e6 / p.rate_hz)) for p in imu for i in range(p.n)]
    assert idx == list(range(503))


def test_broad_import_without_mag_is_6d(broad_dir: Path) -> None:
    trial = broad.load_trial(broad_dir / "15_undisturbed_fast_translation_A.mat").slice(0, 30)
    recs = list(broad_records(trial, use_mag=False))
    p = schemas.decode(recs[0].key, recs[0].payload)
    assert isinstance(p, schemas.ImuPacket) and p.mag_uT is None


def write_csv(path: Path, header: list[str], rows: np.ndarray, sep: str = ",") -> None:
    lines = [sep.join(header)] + [sep.join(repr(float(v)) if np.isfinite(v) else "" for v in r) for r in rows]
    path.write_text("\n".join(lines) + "\n")


def test_csv_units_are_converted_to_si(tmp_path: Path) -> None:
    n = 200
    t_ms = np.arange(n) * 10.0  # 100 Hz, in ms
    acc_g = np.column_stack([np.full(n, 0.1), np.full(n, -0.2), np.full(n, 1.0)])
    gyr_dps = np.column_stack([np.full(n, 90.0), np.full(n, -45.0), np.linspace(0.0, 180.0, n)])
    mag_ut = np.column_stack([np.full(n, 20.0), np.full(n, -5.0), np.full(n, -40.0)])
    header = ["time (ms)", "acc_x (g)", "acc_y (g)", "acc_z (g)", "gyro_x [deg/s]", "gyro_y [deg/s]",
              "gyro_z [deg/s]", "mag_x (nT)", "mag_y (nT)", "mag_z (nT)", "label"]  # fmt: skip
    rows = np.column_stack([t_ms, acc_g, gyr_dps, mag_ut * 1000.0, np.zeros(n)])
    write_csv(tmp_path / "p.csv", header, rows, sep=";")
    imp = read_sensor_csv(tmp_path / "p.csv")
    s = imp.stream
    assert s.rate_hz == pytest.approx(100.0, rel=1e-9)
    np.testing.assert_allclose(s.acc_m_s2, acc_g * G, rtol=1e-8)
    np.testing.assert_allclose(s.gyr_rad_s, np.deg2rad(gyr_dps), rtol=1e-8, atol=1e-12)
    assert s.mag_uT is not None
    np.testing.assert_allclose(s.mag_uT, mag_ut, rtol=1e-8)


def test_csv_irregular_timing_is_resampled_linearly(tmp_path: Path) -> None:
    rng = np.random.default_rng(3)
    t = np.cumsum(rng.uniform(0.018, 0.022, 300))  # a phone at ~50 Hz with jitter, seconds
    gx = 0.5 * t  # a ramp survives linear interpolation exactly
    rows = np.column_stack([t, np.zeros(300), np.zeros(300), np.full(300, 9.81), gx, np.zeros(300), np.zeros(300)])
    rows[10, 1] = np.nan  # a blank cell
    header = ["t (s)", "accel_x (m/s^2)", "accel_y (m/s^2)", "accel_z (m/s^2)", "gyr_x (rad/s)", "gyr_y (rad/s)",
              "gyr_z (rad/s)"]  # fmt: skip
    write_csv(tmp_path / "j.csv", header, rows)
    imp = read_sensor_csv(tmp_path / "j.csv", rate_hz=50.0)
    grid = t[0] + imp.t_s
    np.testing.assert_allclose(np.diff(imp.t_s), 0.02, rtol=1e-9)
    np.testing.assert_allclose(imp.stream.gyr_rad_s[:, 0], 0.5 * grid, rtol=1e-9)
    assert imp.stream.mag_uT is None and np.all(np.isfinite(imp.stream.acc_m_s2))


def test_csv_header_errors_are_clear(tmp_path: Path) -> None:
    with pytest.raises(CsvFormatError, match="unknown gyr unit"):
        parse_header("gyro_x (furlongs/s)")
    assert parse_header("battery (%)") is None
    write_csv(tmp_path / "bad.csv", ["time (s)", "acc_x (g)"], np.zeros((3, 2)))
    assert import_csv.main([str(tmp_path / "bad.csv"), "-o", str(tmp_path), "--no-progress"]) == 2


def test_import_csv_command_writes_decodable_packets(tmp_path: Path) -> None:
    n = 95
    rows = np.column_stack([np.arange(n) * 0.01, np.zeros((n, 2)), np.full(n, 1.0), np.zeros((n, 3))])
    header = ["time (s)", "acc_x (g)", "acc_y (g)", "acc_z (g)", "gyro_x (dps)", "gyro_y (dps)", "gyro_z (dps)"]
    write_csv(tmp_path / "phone.csv", header, rows)
    assert import_csv.main([str(tmp_path / "phone.csv"), "-o", str(tmp_path / "o"), "--no-progress"]) == 0
    pkts = [schemas.decode(r.key, r.payload) for r in read_recording(tmp_path / "o" / "phone.rigrec")]
    assert len(pkts) == 10 and all(isinstance(p, schemas.ImuPacket) for p in pkts)
    acc = np.concatenate([p.arrays()[1] for p in pkts if isinstance(p, schemas.ImuPacket)])
    np.testing.assert_allclose(acc[:, 2], G)
