"""Turn real recordings into replayable `.rigrec` recordings: BROAD trials and phone sensor-app CSV logs.

BROAD (Laidig et al., Data 6(7):72, 2021, CC BY 4.0): the IMU becomes a device of kind `rod` (the generic IMU
device: the gateway fuses it with the rod's filter; its alarms are meaningless on this data) publishing
`rig/rod/{id}/imu` in blocks of `samples_per_packet` at the trial's rate (285.714 Hz), with the optical reference
as `rig/rod/{id}/reference` packets (gateway.recording.reference). Floats are written at full precision, so the
gateway fuses bit-identical samples.

CSV: a header row names each column with its unit, e.g. `time (s)`, `acc_x (m/s^2)`, `gyro_x [deg/s]`, `mag_x_uT`.
Values are converted to SI (time s, acc m/s², gyro rad/s, mag µT) and resampled (linear) onto a uniform grid at
the median sample rate, because ImuPacket assumes uniform sampling.
"""

from __future__ import annotations

import csv
import json
import math
import re
from collections.abc import Iterator, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from gateway import schemas
from gateway.fusion.base import FloatArray
from gateway.fusion.broad import Trial
from gateway.recording.format import Record
from gateway.recording.reference import ENCODING_REFERENCE, reference_key

G_M_S2 = 9.80665
DEFAULT_T0_US = 1_000_000  # device clock at the first sample: 1 s after "boot"
DEFAULT_WALL_START_US = 1_767_225_600_000_000  # 2026-01-01T00:00:00Z: imported recordings get a fixed wall clock


@dataclass(frozen=True)
class ImuStream:
    """Uniformly sampled IMU data of one device (SI units)."""

    rate_hz: float
    gyr_rad_s: FloatArray
    acc_m_s2: FloatArray
    mag_uT: FloatArray | None


def _rows(a: FloatArray) -> list[list[float]]:
    out: list[list[float]] = a.tolist()
    return out


def imu_records(
    stream: ImuStream, device_id: str, kind: str = "rod", samples_per_packet: int = 10, boot_id: int = 1,
    seq0: int = 0, t0_us: int = DEFAULT_T0_US, wall_start_us: int = DEFAULT_WALL_START_US,
    extras: dict[str, FloatArray] | None = None,
) -> Iterator[tuple[int, int, int, Record]]:  # fmt: skip
    """(first sample, n, packet t0_us, Record) per ImuPacket; record time = wall time of its last sample (the
    moment a device would send it). Packet k starts at sample k·n, t0_us + round(k·n·1e6/rate). `extras`
    (per-sample arrays named as `EXTRA_QUANTITIES`, NaN = none) fill `temp_c`, `depth_m` and `gnss` from the first
    sample of the packet that has them."""
    n_total = stream.gyr_rad_s.shape[0]
    key = schemas.imu_key(kind, device_id)
    for k, i0 in enumerate(range(0, n_total, samples_per_packet)):
        i1 = min(i0 + samples_per_packet, n_total)
        t_pkt = t0_us + int(round(i0 * 1e6 / stream.rate_hz))
        d: dict[str, Any] = {
            "v": 1, "device_id": device_id, "kind": kind, "boot_id": boot_id, "seq": (seq0 + k) % schemas.UINT32,
            "t0_us": t_pkt, "rate_hz": stream.rate_hz, "gyr_rad_s": _rows(stream.gyr_rad_s[i0:i1]),
            "acc_m_s2": _rows(stream.acc_m_s2[i0:i1]),
        }  # fmt: skip
        if stream.mag_uT is not None:
            d["mag_uT"] = _rows(stream.mag_uT[i0:i1])
        d["wall_t0_us"] = wall_start_us + (t_pkt - t0_us)
        if extras:
            d.update(packet_extras(extras, i0, i1))
        t_send = wall_start_us + int(round((i1 - 1) * 1e6 / stream.rate_hz))
        payload = json.dumps(d, separators=(",", ":"), allow_nan=False).encode()
        yield i0, i1 - i0, t_pkt, Record(key, payload, t_send, schemas.ENCODING_IMU)


def _first(a: FloatArray | None, i0: int, i1: int) -> int | None:
    """Index of the first finite value of a[i0:i1], None without one."""
    if a is None:
        return None
    ok = np.flatnonzero(np.isfinite(a[i0:i1]))
    return i0 + int(ok[0]) if ok.size else None


def packet_extras(extras: dict[str, FloatArray], i0: int, i1: int) -> dict[str, Any]:
    """`temp_c`, `depth_m` and `gnss` of the ImuPacket holding samples i0:i1 (only those present)."""
    out: dict[str, Any] = {}
    for q, name in (("temp", "temp_c"), ("depth", "depth_m")):
        j = _first(extras.get(q), i0, i1)
        if j is not None:
            out[name] = float(extras[q][j])
    lat, lon = extras.get("lat"), extras.get("lon")
    if lat is not None and lon is not None:
        j = _first(np.where(np.isfinite(lon), lat, np.nan), i0, i1)
        if j is not None:
            fix: dict[str, Any] = {"lat_deg": float(lat[j]), "lon_deg": float(lon[j])}
            for q, name in (("alt", "alt_m"), ("speed", "speed_m_s")):
                if q in extras and np.isfinite(extras[q][j]):
                    fix[name] = float(extras[q][j])
            if "fix" in extras and np.isfinite(extras["fix"][j]):
                fix["fix_quality"] = int(extras["fix"][j])
            out["gnss"] = fix
    return out


def _opt(a: FloatArray) -> list[list[float] | None]:
    return [None if not np.all(np.isfinite(r)) else r.tolist() for r in a]


def broad_records(
    trial: Trial, device_id: str = "broad-1", kind: str = "rod", samples_per_packet: int = 10, use_mag: bool = True,
    boot_id: int = 1, seq0: int = 0,
) -> Iterator[Record]:  # fmt: skip
    """IMU packets and, after each, the reference packet for the same samples."""
    stream = ImuStream(trial.rate_hz, trial.gyr_rad_s, trial.acc_m_s2, trial.mag_uT if use_mag else None)
    ref_key = reference_key(kind, device_id)
    for i0, n, t_pkt, rec in imu_records(stream, device_id, kind, samples_per_packet, boot_id, seq0):
        yield rec
        s = slice(i0, i0 + n)
        ref = {
            "v": 1, "device_id": device_id, "kind": kind, "boot_id": boot_id,
            "seq": json.loads(rec.payload)["seq"], "t0_us": t_pkt, "rate_hz": trial.rate_hz,
            "quat_wxyz": _opt(trial.quat_ref[s]), "pos_m": _opt(trial.pos_m[s]),
            "movement": [bool(m) for m in trial.movement[s]], "source": f"BROAD {trial.name}",
        }  # fmt: skip
        yield Record(ref_key, json.dumps(ref, separators=(",", ":")).encode(), rec.t_us, ENCODING_REFERENCE)


def broad_meta(trial: Trial, device_id: str, kind: str, samples_per_packet: int, use_mag: bool) -> dict[str, Any]:
    """Recording metadata of an imported BROAD trial."""
    return {
        "source": "broad", "trial": trial.name, "groups": list(trial.groups), "device_id": device_id, "kind": kind,
        "samples_per_packet": samples_per_packet, "mode": "9D" if use_mag else "6D", "rate_hz": trial.rate_hz,
        "samples": trial.n, "licence": "BROAD, Laidig et al. 2021, CC BY 4.0",
    }  # fmt: skip


# ---------------------------------------------------------------------------------------------------------------
# Phone sensor-app CSV
# ---------------------------------------------------------------------------------------------------------------

_TIME_UNITS = {"s": 1.0, "sec": 1.0, "ms": 1e-3, "us": 1e-6, "µs": 1e-6, "ns": 1e-9}
_ACC_UNITS = {"m/s^2": 1.0, "m/s2": 1.0, "m/s²": 1.0, "ms^-2": 1.0, "g": G_M_S2, "mg": G_M_S2 * 1e-3}
_GYR_UNITS = {"rad/s": 1.0, "deg/s": math.pi / 180.0, "°/s": math.pi / 180.0, "dps": math.pi / 180.0,
              "mrad/s": 1e-3}  # fmt: skip
_MAG_UNITS = {"ut": 1.0, "µt": 1.0, "microtesla": 1.0, "nt": 1e-3, "mt": 1e3, "t": 1e6, "g": 100.0, "gauss": 100.0,
              "mg": 0.1}  # fmt: skip
_QUANTITIES = (
    ("time", ("timestamp", "time", "t"), _TIME_UNITS),
    ("acc", ("accelerometer", "acceleration", "accel", "acc", "a"), _ACC_UNITS),
    ("gyr", ("gyroscope", "gyro", "gyr", "w"), _GYR_UNITS),
    ("mag", ("magnetometer", "magnetic", "mag", "m"), _MAG_UNITS),
)


# Optional one-value columns (the logger of seed 004 and `gateway.recording.export`): (quantity, names, units); a
# column whose unit is not listed is ignored rather than refused, so phone logs with odd extra columns still import.
_EXTRAS: tuple[tuple[str, tuple[str, ...], dict[str, float]], ...] = (
    ("temp", ("temperature", "temp"), {"c": 1.0, "°c": 1.0, "degc": 1.0}),
    ("depth", ("depth",), {"m": 1.0}),
    ("lat", ("latitude", "lat"), {"deg": 1.0, "°": 1.0}),
    ("lon", ("longitude", "lon", "lng"), {"deg": 1.0, "°": 1.0}),
    ("alt", ("altitude", "alt"), {"m": 1.0}),
    ("speed", ("speed",), {"m/s": 1.0, "km/h": 1.0 / 3.6}),
    ("fix", ("fixquality",), {"nmea": 1.0}),
)
EXTRA_QUANTITIES: tuple[str, ...] = tuple(q for q, _, _ in _EXTRAS)


class CsvFormatError(ValueError):
    """A column header without a recognisable quantity or unit."""


@dataclass(frozen=True)
class Column:
    quantity: str  # time, acc, gyr, mag
    axis: int  # 0, 1, 2 (-1 for time)
    scale: float  # multiply to get SI (s, m/s², rad/s, µT)


_UNIT_RE = re.compile(r"^(?P<name>.*?)\s*(?:[\(\[](?P<unit>[^\)\]]+)[\)\]])\s*$")


def parse_header(name: str) -> Column | None:
    """Quantity, axis and SI scale of one header cell, e.g. `gyro_x (deg/s)`, `acc z [g]`, `mag_y_uT`, `time_ms`;
    None for columns to ignore. Raises CsvFormatError when a known quantity has no known unit."""
    raw = name.strip()
    m = _UNIT_RE.match(raw)
    if m:
        base, unit = m.group("name"), m.group("unit").strip()
    else:
        parts = re.split(r"[_\s]+", raw)
        base, unit = " ".join(parts[:-1]), parts[-1] if len(parts) > 1 else ""
    tokens = [t for t in re.split(r"[_\s.:-]+", base.lower()) if t]
    axis = -1
    if tokens and tokens[-1] in ("x", "y", "z"):
        axis = "xyz".index(tokens.pop())
    word = "".join(tokens)
    for quantity, names, units in _QUANTITIES:
        if word in names and (quantity == "time") == (axis == -1):
            key = unit.lower().replace(" ", "") if quantity == "mag" else unit.replace(" ", "")
            if key not in units:
                raise CsvFormatError(f"column {name!r}: unknown {quantity} unit {unit!r}; known: {', '.join(units)}")
            return Column(quantity, axis, units[key])
    if axis == -1:
        unit_key = unit.lower().replace(" ", "")
        for extra, extra_names, extra_units in _EXTRAS:
            if word in extra_names and unit_key in extra_units:
                return Column(extra, -1, extra_units[unit_key])
    return None


@dataclass(frozen=True)
class CsvImport:
    stream: ImuStream
    t_s: FloatArray  # uniform grid, from the first sample
    raw_rate_hz: float
    max_gap_s: float
    extras: dict[str, FloatArray] = field(default_factory=dict)
    """Optional columns (`EXTRA_QUANTITIES`) on the grid: each raw value at its nearest grid sample, NaN between."""


def read_sensor_csv(path: str | Path, rate_hz: float | None = None, flip_acc: bool = False) -> CsvImport:
    """Read a phone sensor log (header row with units), convert to SI and resample onto a uniform grid."""
    with open(path, newline="") as f:
        sample = f.read(4096)
        f.seek(0)
        dialect = csv.Sniffer().sniff(sample, delimiters=",;\t")
        reader = csv.reader(f, dialect)
        header = next(reader)
        cols = [parse_header(h) for h in header]
        rows = [[float(c) if c.strip() else math.nan for c in r] for r in reader if r]
    data = np.asarray(rows, dtype=np.float64)
    found = {(c.quantity, c.axis): (i, c.scale) for i, c in enumerate(cols) if c is not None}
    for need in (("time", -1), *[(q, a) for q in ("acc", "gyr") for a in range(3)]):
        if need not in found:
            raise CsvFormatError(f"missing column for {need[0]}{'' if need[1] < 0 else ' ' + 'xyz'[need[1]]}")
    i_t, s_t = found[("time", -1)]
    t = data[:, i_t] * s_t
    order = np.argsort(t, kind="stable")
    data, t = data[order], t[order]
    dt = np.diff(t)
    dt = dt[dt > 0]
    raw_rate = 1.0 / float(np.median(dt))
    rate = rate_hz or raw_rate
    grid = t[0] + np.arange(int(math.floor((t[-1] - t[0]) * rate + 1e-6)) + 1) / rate  # last sample kept

    def vec(q: str) -> FloatArray | None:
        if not all((q, a) in found for a in range(3)):
            return None
        out = np.empty((grid.shape[0], 3))
        for a in range(3):
            i, s = found[(q, a)]
            v = data[:, i] * s
            ok = np.isfinite(v)
            out[:, a] = np.interp(grid, t[ok], v[ok])
        return out

    acc, gyr = vec("acc"), vec("gyr")
    assert acc is not None and gyr is not None
    if flip_acc:
        acc = -acc
    extras = {}
    for q in EXTRA_QUANTITIES:
        if (q, -1) in found:
            i, sc = found[(q, -1)]
            extras[q] = nearest_on_grid(t, data[:, i] * sc, grid[0], rate, grid.shape[0])
    stream = ImuStream(float(rate), gyr, acc, vec("mag"))
    return CsvImport(stream, grid - grid[0], raw_rate, float(dt.max()) if dt.size else 0.0, extras)


def nearest_on_grid(t_s: FloatArray, values: FloatArray, t0_s: float, rate_hz: float, n: int) -> FloatArray:
    """Each finite value placed at its nearest grid sample (later values win), NaN elsewhere; sparse columns such as
    GNSS fixes stay sparse instead of being interpolated."""
    out = np.full(n, np.nan)
    ok = np.isfinite(values)
    idx = np.rint((t_s[ok] - t0_s) * rate_hz).astype(np.int64)
    keep = (idx >= 0) & (idx < n)
    out[idx[keep]] = values[ok][keep]
    return out


def csv_meta(path: str | Path, imp: CsvImport, device_id: str, kind: str, samples_per_packet: int) -> dict[str, Any]:
    return {
        "source": "csv", "file": Path(path).name, "device_id": device_id, "kind": kind,
        "samples_per_packet": samples_per_packet, "rate_hz": imp.stream.rate_hz, "raw_rate_hz": imp.raw_rate_hz,
        "samples": int(imp.stream.gyr_rad_s.shape[0]), "mode": "9D" if imp.stream.mag_uT is not None else "6D",
    }  # fmt: skip


def csv_records(imp: CsvImport, device_id: str, kind: str = "rod", samples_per_packet: int = 10,
                boot_id: int = 1) -> Iterator[Record]:  # fmt: skip
    for _, _, _, rec in imu_records(imp.stream, device_id, kind, samples_per_packet, boot_id, extras=imp.extras):
        yield rec


def check_packets(records: Sequence[Record]) -> None:
    """Every IMU record must decode with the gateway's own decoder (raises schemas.DecodeError)."""
    for r in records:
        if r.key.endswith("/imu"):
            schemas.decode(r.key, r.payload)
