"""Logger export (seed 004): a recording -> time-named CSV/text files -> `import_csv` gives the same samples, and
temperature, depth and GNSS fixes come back on the same packets; files rotate when a device gains a field."""

from __future__ import annotations

import csv
from pathlib import Path

import numpy as np
import pytest

from gateway import schemas
from gateway.recording import export
from gateway.recording.format import write_recording
from gateway.recording.importers import ImuStream, csv_records, imu_records, read_sensor_csv

RATE_HZ = 100.0
N = 250  # 25 packets of 10


def _stream(seed: int = 1) -> tuple[ImuStream, dict[str, np.ndarray]]:
    rng = np.random.default_rng(seed)
    stream = ImuStream(RATE_HZ, rng.normal(0, 0.3, (N, 3)), rng.normal([0, 0, 9.81], 0.5, (N, 3)),
                       rng.normal([10, 20, -40], 2.0, (N, 3)))  # fmt: skip
    extras = {q: np.full(N, np.nan) for q in ("temp", "depth", "lat", "lon", "alt", "speed", "fix")}
    extras["temp"][:] = np.repeat(20.0 + np.arange(N // 10) * 0.25, 10)  # one value per packet
    for k, i in enumerate(range(0, N, 50)):  # a fix every 5th packet, at its first sample
        extras["lat"][i], extras["lon"][i] = 30.27 + k * 1e-5, 120.15 - k * 1e-5
        extras["alt"][i], extras["speed"][i], extras["fix"][i] = 7.5 + k, 1.25 * k, 1 + k % 2
    for i in range(0, N, 10):
        extras["depth"][i] = 0.5 + i * 0.01
    return stream, extras


def _recording(tmp_path: Path, extras: dict[str, np.ndarray] | None) -> tuple[Path, ImuStream]:
    stream, ex = _stream()
    recs = [r for *_, r in imu_records(stream, "log-1", "rod", 10, extras=ex if extras is None else extras)]
    path = tmp_path / "rec.rigrec"
    write_recording(path, recs)
    return path, stream


@pytest.mark.parametrize("fmt", ["csv", "txt"])
def test_export_then_import_csv_round_trips_samples_and_extras(tmp_path: Path, fmt: export.Format) -> None:
    path, stream = _recording(tmp_path, None)
    original = [schemas.decode(r.key, r.payload) for *_, r in imu_records(stream, "log-1", "rod", 10,
                                                                            extras=_stream()[1])]  # fmt: skip
    with export.CsvExporter(tmp_path / "out", fmt) as ex:
        rejected, _ = export.export_recording(path, ex)
    assert rejected == 0 and len(ex.files) == 1 and ex.rows == N
    # named by the first sample's UTC wall time (importers' fixed 2026-01-01 start)
    assert ex.files[0].name == f"log-1-20260101T000000.000000Z.{fmt}"
    imp = read_sensor_csv(ex.files[0])
    assert imp.stream.rate_hz == pytest.approx(RATE_HZ, rel=1e-9)
    for got, want in ((imp.stream.gyr_rad_s, stream.gyr_rad_s), (imp.stream.acc_m_s2, stream.acc_m_s2),
                      (imp.stream.mag_uT, stream.mag_uT)):  # fmt: skip
        np.testing.assert_allclose(got, want, rtol=0, atol=1e-9)  # grid vs stored times differ by float rounding
    back = [schemas.decode(r.key, r.payload) for r in csv_records(imp, "log-1", "rod", 10)]
    assert len(back) == len(original)
    for a, b in zip(back, original, strict=True):
        assert isinstance(a, schemas.ImuPacket) and isinstance(b, schemas.ImuPacket)
        assert (a.temp_c, a.depth_m, a.gnss) == (b.temp_c, b.depth_m, b.gnss)
    assert sum(p.gnss is not None for p in back) == 5  # type: ignore[union-attr]


def test_columns_follow_what_the_device_sends_and_a_new_field_starts_a_new_file(tmp_path: Path) -> None:
    stream, ex = _stream()
    ex_late = {k: v.copy() for k, v in ex.items() if k != "depth"}
    for q in ("lat", "lon", "alt", "speed", "fix"):
        ex_late[q][:100] = np.nan  # the receiver's first fix arrives at sample 100
    path, _ = _recording(tmp_path, ex_late)
    with export.CsvExporter(tmp_path / "out") as exp:
        export.export_recording(path, exp)
    assert len(exp.files) == 2
    headers = [next(csv.reader(open(f))) for f in exp.files]
    assert tuple(headers[0]) == export.BASE_COLUMNS
    assert tuple(headers[1]) == export.BASE_COLUMNS + export.GNSS_COLUMNS
    rows = [sum(1 for _ in open(f)) - 1 for f in exp.files]
    assert rows == [100, N - 100]


def test_rotation_by_device_time(tmp_path: Path) -> None:
    path, _ = _recording(tmp_path, {})
    with export.CsvExporter(tmp_path / "out", rotate_s=1.0) as exp:
        export.export_recording(path, exp)
    assert [sum(1 for _ in open(f)) - 1 for f in exp.files] == [100, 100, 50]
    assert [f.name for f in exp.files] == sorted(f.name for f in exp.files)


def test_command_help_and_argument_check(capsys: pytest.CaptureFixture[str]) -> None:
    with pytest.raises(SystemExit) as e:
        export.main(["--help"])
    assert e.value.code == 0 and "time-named" in capsys.readouterr().out
    with pytest.raises(SystemExit) as e:
        export.main(["-o", "x"])  # neither a recording nor --live
    assert e.value.code == 2


def test_command_writes_files(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    path, _ = _recording(tmp_path, None)
    assert export.main([str(path), "-o", str(tmp_path / "o"), "--no-progress"]) == 0
    assert f"{N} samples" in capsys.readouterr().err


@pytest.mark.timeout(90)
def test_live_export_from_zenoh(tmp_path: Path) -> None:
    """Two processes on loopback: the exporter listens, a simulated rod connects; 30 packets (5 samples each at
    100 Hz) land in one time-named CSV that reads back with the rod's rate."""
    import os
    import subprocess
    import sys

    from tests.test_zenoh_processes import REPO, free_port

    endpoint = f"tcp/127.0.0.1:{free_port()}"
    env = {**os.environ, "PYTHONUNBUFFERED": "1"}
    exp = subprocess.Popen([sys.executable, "-m", "gateway.recording.export", "--live", "-o", str(tmp_path),
                            "--listen", endpoint, "--connect", "none", "--count", "30", "--duration", "60",
                            "--no-progress"], cwd=REPO, env=env, stderr=subprocess.PIPE)  # fmt: skip
    rod = subprocess.Popen([sys.executable, "-m", "devices.sim_rod", "--connect", endpoint, "--duration", "20",
                            "--no-progress"], cwd=REPO, env=env, stdout=subprocess.DEVNULL,
                           stderr=subprocess.DEVNULL)  # fmt: skip
    try:
        _, err = exp.communicate(timeout=75)
    finally:
        rod.terminate()
        rod.wait(timeout=20)
        if exp.poll() is None:
            exp.kill()
    assert exp.returncode == 0, err.decode()[-2000:]
    files = sorted(tmp_path.glob("rod-1-*.csv"))
    assert len(files) == 1, err.decode()[-2000:]
    imp = read_sensor_csv(files[0])
    assert imp.stream.gyr_rad_s.shape[0] >= 140  # 30 packets of 5, minus at most a lost one or two
    assert imp.stream.rate_hz == pytest.approx(100.0, rel=1e-3)


def test_import_csv_command_reads_an_exported_log_as_its_device(tmp_path: Path) -> None:
    """`python -m gateway.recording.import_csv LOG -o DIR` on an exported log: the device id comes from the file
    name, and the packets decode with their GNSS fixes."""
    from gateway.recording import import_csv
    from gateway.recording.format import read_recording

    path, _ = _recording(tmp_path, None)
    with export.CsvExporter(tmp_path / "out") as ex:
        export.export_recording(path, ex)
    assert import_csv.device_id_from_name(ex.files[0]) == "log-1"
    assert import_csv.device_id_from_name(Path("phone.csv")) is None
    assert import_csv.main([str(ex.files[0]), "-o", str(tmp_path / "rec"), "--no-progress"]) == 0
    recs = list(read_recording(next((tmp_path / "rec").iterdir())))
    pkts = [schemas.decode(r.key, r.payload) for r in recs]
    assert {r.key for r in recs} == {"rig/rod/log-1/imu"}
    assert sum(isinstance(p, schemas.ImuPacket) and p.gnss is not None for p in pkts) == 5
