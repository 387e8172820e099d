"""Per-device sensor calibration from a recording of the device being turned: `python -m gateway.calibrate --help`.

Procedure (docs/calibration.md): record the device (`python -m gateway.recording.record`) while you hold it still
in at least six poses (each axis up and down, ≥ 2 s each) and, between and after them, turn it slowly through as
many orientations as you can. Then:

    python -m gateway.calibrate REC [--device ID] [--method fit|paper] [-o calib.json]
    python -m gateway.calibrate REC --compare       # both methods' fit figures side by side
    python -m gateway.calibrate REC --hook-mount    # a hook's IMU offset from the rope axis (below)

`--method fit` (default):
- Accelerometer offset and per-axis scale: rest segments (`rest_mask`) of at least `--min-pose-s`
  give one mean reading each; `fit_accel_offset_scale` fits |(a - offset) / scale| = g over those poses.
- Magnetometer hard iron and full soft-iron matrix: `calibrate_mag_ellipsoid` over every sample, scaled so the
  calibrated field keeps the ellipsoid's mean radius.
`--method paper` (seed 004's procedure as written):
- Accelerometer offsets = mean of the level rest pose (z up) minus (0, 0, g): "Z at 1 g"; scale 1.
- Magnetometer per-axis min/max over the turning: offset = (max + min)/2, diagonal scale so the axes match.
Both print the gyro bias (mean rate over the rest samples, seed 004) as `gyr_bias_rad_s`, for information: the
gateway's filters learn the bias live, so it is not applied.

The result (`DeviceCalibration`, JSON) is applied before fusion as `acc_cal = (acc - offset) / scale`,
`mag_cal = soft_iron @ (mag - offset)`.

`--hook-mount`: a crane hook's IMU offset from the rope axis, its tilt on the hook and its accelerometer's x/y
offset in the hook's axes (`gateway.fusion.hook_mount`), for the hook settings `imu_offset_m`, `imu_tilt_deg` and
`acc_bias_xy_m_s2` (measure near the working temperature: the offset drifts with it). Record the hook hanging still
on its rope, crane at rest, in calm air, for 30 s or more after you turned it by hand 45-90° and let go (turn it
again when it settles). Prints the settings and the command that sets them. Samples where the gyroscope or
accelerometer clipped are left out (refused without a magnetometer: turn it more gently), and the accelerometer's
offset is left out, with a line saying why, when its fit is less certain than 0.01 m/s². With a magnetometer it
also prints a device `calibration` that takes the magnetometer's offset in the hook's plane (its hard iron, from
the ellipse its x/y trace as the hook turns, along the twist the gyroscope integrates; the soft iron's in-plane part
too) out before fusion: an uncalibrated compass read the suite's torsion 2.2° off, 0.6° with it (docs/fusion.md). It
replaces a pose calibration the device may have.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import ArrayLike
from tqdm import tqdm

from gateway import schemas
from gateway.fusion.base import FloatArray
from gateway.fusion.calibration import (
    BoolArray,
    MagCalibration,
    RestSettings,
    apply_accel_calibration,
    calibrate_mag_ellipsoid,
    calibrate_mag_minmax,
    fit_accel_offset_scale,
)
from gateway.fusion.hook_mount import (
    MAX_BIAS_STD_M_S2,
    MAX_IRON_STD_UT,
    IronFit,
    fit_hard_iron,
    fit_hook_mount,
    hook_axes_fit,
)

METHODS: tuple[str, ...] = ("fit", "paper")
POSE_REST = RestSettings(gyr_th_rad_s=float(np.deg2rad(0.5)), acc_th_m_s2=0.1)
LEVEL_MAX_TILT_RAD = float(np.deg2rad(10.0))


@dataclass(frozen=True)
class DeviceCalibration:
    """Accelerometer offset (m/s²) and scale, magnetometer offset (µT) and soft-iron matrix, with fit figures."""

    acc_offset_m_s2: FloatArray
    acc_scale: FloatArray
    mag_offset_uT: FloatArray
    mag_soft_iron: FloatArray
    n_poses: int = 0
    acc_fit_rms_m_s2: float = 0.0  # rms of |calibrated pose mean| - g over the poses
    mag_fit_rms_uT: float = 0.0  # rms of |calibrated field| - its mean over the samples

    @staticmethod
    def identity() -> DeviceCalibration:
        """No correction."""
        return DeviceCalibration(np.zeros(3), np.ones(3), np.zeros(3), np.eye(3))

    def apply(self, acc_m_s2: ArrayLike, mag_uT: ArrayLike | None) -> tuple[FloatArray, FloatArray | None]:
        """Calibrated (acc, mag), shapes (..., 3)."""
        acc = apply_accel_calibration(acc_m_s2, self.acc_offset_m_s2, self.acc_scale)
        mag = None if mag_uT is None else MagCalibration(self.mag_offset_uT, self.mag_soft_iron).apply(mag_uT)
        return acc, mag

    def to_json(self) -> dict[str, Any]:
        """Plain dict (lists of floats), the form stored with the device's settings."""
        return {
            "acc_offset_m_s2": np.round(self.acc_offset_m_s2, 6).tolist(),
            "acc_scale": np.round(self.acc_scale, 7).tolist(),
            "mag_offset_uT": np.round(self.mag_offset_uT, 4).tolist(),
            "mag_soft_iron": np.round(self.mag_soft_iron, 6).tolist(),
            "n_poses": self.n_poses, "acc_fit_rms_m_s2": round(self.acc_fit_rms_m_s2, 6),
            "mag_fit_rms_uT": round(self.mag_fit_rms_uT, 4),
        }  # fmt: skip

    @staticmethod
    def from_json(d: Mapping[str, Any]) -> DeviceCalibration:
        """Inverse of `to_json` (extra keys such as `device_id` are ignored). Raises ValueError naming the field when
        a key is missing, a shape is wrong, a value is not finite, a scale is not in (0.5, 2) or the soft-iron matrix
        is singular: a bad calibration must not reach fusion."""

        def arr(key: str, shape: tuple[int, ...]) -> FloatArray:
            if key not in d:
                raise ValueError(f"{key}: missing")
            try:
                a = np.asarray(d[key], dtype=np.float64)
            except (TypeError, ValueError) as exc:
                raise ValueError(f"{key}: not numbers ({exc})") from None
            if a.shape != shape:
                raise ValueError(f"{key}: shape {a.shape}, need {shape}")
            if not np.isfinite(a).all():
                raise ValueError(f"{key}: not finite")
            return a

        acc_scale, soft = arr("acc_scale", (3,)), arr("mag_soft_iron", (3, 3))
        if not np.all((acc_scale > 0.5) & (acc_scale < 2.0)):
            raise ValueError(f"acc_scale: {acc_scale.tolist()} outside (0.5, 2)")
        if np.linalg.cond(soft) > 1e3:
            raise ValueError("mag_soft_iron: singular or near-singular matrix")
        try:
            extra = int(d.get("n_poses", 0)), float(d.get("acc_fit_rms_m_s2", 0.0)), float(d.get("mag_fit_rms_uT", 0.0))
        except (TypeError, ValueError) as exc:
            raise ValueError(f"fit figures: {exc}") from None
        return DeviceCalibration(arr("acc_offset_m_s2", (3,)), acc_scale, arr("mag_offset_uT", (3,)), soft, *extra)


def rest_mask(gyr_rad_s: ArrayLike, acc_m_s2: ArrayLike, rate_hz: float, rest: RestSettings | None = None) -> BoolArray:
    """Rest samples: over the trailing window the gyro's and accelerometer's spread (root of summed per-axis
    variances) are below the thresholds. Unlike `calibration.detect_rest` it ignores the gyro's mean, so an
    uncalibrated gyro bias of a few °/s does not hide the poses."""
    s = rest or RestSettings()
    gyr, acc = np.asarray(gyr_rad_s, dtype=np.float64), np.asarray(acc_m_s2, dtype=np.float64)
    w = max(2, int(round(s.window_s * rate_hz)))
    out = np.zeros(gyr.shape[0], dtype=bool)
    if gyr.shape[0] < w:
        return out

    def spread2(x: FloatArray) -> FloatArray:
        c1 = np.cumsum(np.vstack([np.zeros((1, 3)), x]), axis=0)
        c2 = np.cumsum(np.vstack([np.zeros((1, 3)), x * x]), axis=0)
        m1, m2 = (c1[w:] - c1[:-w]) / w, (c2[w:] - c2[:-w]) / w
        v: FloatArray = np.maximum(np.sum(m2 - m1 * m1, axis=1), 0.0)
        return v

    out[w - 1 :] = (spread2(gyr) < s.gyr_th_rad_s**2) & (spread2(acc) < s.acc_th_m_s2**2)
    return out


def rest_segments(
    gyr_rad_s: ArrayLike, acc_m_s2: ArrayLike, rate_hz: float, min_pose_s: float = 1.0,
    rest: RestSettings | None = None,
) -> list[tuple[int, int]]:
    """(start, stop) sample ranges of the rest segments lasting at least `min_pose_s`."""
    mask = rest_mask(gyr_rad_s, acc_m_s2, rate_hz, rest or POSE_REST)
    edges = np.flatnonzero(np.diff(np.concatenate(([0], mask.astype(np.int8), [0]))))
    n_min = max(2, int(round(min_pose_s * rate_hz)))
    return [(int(a), int(b)) for a, b in zip(edges[::2], edges[1::2], strict=True) if b - a >= n_min]


def rest_pose_means(
    gyr_rad_s: ArrayLike, acc_m_s2: ArrayLike, rate_hz: float, min_pose_s: float = 1.0,
    rest: RestSettings | None = None,
) -> FloatArray:
    """Mean accelerometer reading (m/s²) of every rest segment lasting at least `min_pose_s`, shape (P, 3)."""
    acc = np.asarray(acc_m_s2, dtype=np.float64)
    means = [acc[a:b].mean(axis=0) for a, b in rest_segments(gyr_rad_s, acc, rate_hz, min_pose_s, rest)]
    return np.array(means, dtype=np.float64).reshape(-1, 3)


def gyro_bias_at_rest(gyr_rad_s: ArrayLike, acc_m_s2: ArrayLike, rate_hz: float, min_pose_s: float = 1.0) -> FloatArray:
    """Seed 004's gyro bias: the mean rate (rad/s) over every rest segment of at least `min_pose_s`."""
    gyr = np.asarray(gyr_rad_s, dtype=np.float64)
    segs = rest_segments(gyr, acc_m_s2, rate_hz, min_pose_s)
    if not segs:
        raise ValueError(f"no rest segment of ≥ {min_pose_s:g} s for the gyro bias")
    bias: FloatArray = np.concatenate([gyr[a:b] for a, b in segs]).mean(axis=0)
    return bias


def paper_accel_offset(pose_means_m_s2: FloatArray, gravity_m_s2: float = 9.80665) -> FloatArray:
    """Seed 004: offsets = the level (z-up) rest mean minus (0, 0, g). The level pose is the one nearest z-up, and it
    must be within 10° of it; raises ValueError otherwise."""
    if pose_means_m_s2.shape[0] == 0:
        raise ValueError("no rest pose")
    tilt = np.arccos(np.clip(pose_means_m_s2[:, 2] / np.linalg.norm(pose_means_m_s2, axis=1), -1.0, 1.0))
    i = int(np.argmin(tilt))
    if tilt[i] > LEVEL_MAX_TILT_RAD:
        raise ValueError(f"no level rest pose (z up within 10°; nearest {np.degrees(tilt[i]):.0f}°): seed 004's "
                         "procedure starts lying flat")  # fmt: skip
    offset: FloatArray = pose_means_m_s2[i] - np.array([0.0, 0.0, gravity_m_s2])
    return offset


def fit_device(
    gyr_rad_s: ArrayLike, acc_m_s2: ArrayLike, mag_uT: ArrayLike | None, rate_hz: float, min_pose_s: float = 1.0,
    method: str = "fit",
) -> DeviceCalibration:
    """Calibration from one recording of the device held in rest poses and turned (see the module docstring).

    `method` "fit": pose fit of offset and scale, ellipsoid fit of the magnetometer; "paper": seed 004's level-pose
    offsets and min/max magnetometer. Raises ValueError when the poses do not span all axes (fit) or there is no
    level pose (paper), or the field samples do not span an ellipsoid; without `mag_uT` the magnetometer part is
    the identity. The accelerometer rms is taken over every pose found, for both methods, so they compare.
    """
    if method not in METHODS:
        raise ValueError(f"unknown method {method!r}; known: {', '.join(METHODS)}")
    poses = rest_pose_means(gyr_rad_s, acc_m_s2, rate_hz, min_pose_s)
    if method == "paper":
        offset, scale = paper_accel_offset(poses), np.ones(3)
    else:
        if poses.shape[0] < 6:
            raise ValueError(f"found {poses.shape[0]} rest poses of ≥ {min_pose_s:g} s; need 6 or more (each axis "
                             "up/down)")  # fmt: skip
        offset, scale = fit_accel_offset_scale(poses)
    acc_rms = float(np.sqrt(np.mean((np.linalg.norm((poses - offset) / scale, axis=1) - 9.80665) ** 2)))
    if mag_uT is None:
        return DeviceCalibration(offset, scale, np.zeros(3), np.eye(3), poses.shape[0], acc_rms)
    mag = np.asarray(mag_uT, dtype=np.float64)
    cal = calibrate_mag_minmax(mag) if method == "paper" else calibrate_mag_ellipsoid(mag)
    norms = np.linalg.norm(cal.apply(mag), axis=1)
    mag_rms = float(np.sqrt(np.mean((norms - norms.mean()) ** 2)))
    return DeviceCalibration(offset, scale, cal.offset_uT, cal.soft_iron, poses.shape[0], acc_rms, mag_rms)


@dataclass(frozen=True)
class ImuSeries:
    """The IMU samples of one device in a recording, in packet order."""

    device_id: str
    rate_hz: float
    gyr_rad_s: FloatArray
    acc_m_s2: FloatArray
    mag_uT: FloatArray | None


def load_imu(path: str | Path, device_id: str | None = None, progress: bool = False) -> ImuSeries:
    """IMU packets of `device_id` (default: the first IMU device in the recording) from a `.rigrec` file or dir."""
    from gateway.recording.format import read_recording

    gyr: list[Sequence[float]] = []
    acc: list[Sequence[float]] = []
    mag: list[Sequence[float]] = []
    rate, has_mag = 0.0, True
    for rec in tqdm(read_recording(path), unit="rec", desc="reading", disable=not progress, file=sys.stderr):
        if not rec.key.endswith("/imu"):
            continue
        try:
            p = schemas.decode(rec.key, rec.payload)
        except schemas.DecodeError:
            continue
        if not isinstance(p, schemas.ImuPacket):
            continue
        if device_id is None:
            device_id = p.device_id
        if p.device_id != device_id:
            continue
        rate = p.rate_hz
        gyr += p.gyr_rad_s
        acc += p.acc_m_s2
        has_mag = has_mag and p.mag_uT is not None
        mag += p.mag_uT or []
    if device_id is None or not gyr:
        raise ValueError(f"no IMU packets{'' if device_id is None else ' of ' + device_id} in {path}")
    return ImuSeries(device_id, rate, np.array(gyr, dtype=np.float64), np.array(acc, dtype=np.float64),
                     np.array(mag, dtype=np.float64) if has_mag else None)  # fmt: skip


def compare_table(imu: ImuSeries, mag_uT: FloatArray | None, min_pose_s: float = 1.0) -> str:
    """Markdown table of both methods on one recording: accel |pose| − g rms (mm/s²) over all poses, mag |field|
    spread rms (µT, relative to its mean), offsets; a method that cannot run shows its reason."""
    rows = ["| method | poses | accel rms mm/s² | mag rms µT (% of |m|) | acc offset m/s² | mag offset µT |",
            "|---|---|---|---|---|---|"]
    for method in METHODS:
        try:
            c = fit_device(imu.gyr_rad_s, imu.acc_m_s2, mag_uT, imu.rate_hz, min_pose_s, method)
        except ValueError as exc:
            rows.append(f"| {method} | failed: {exc} | | | | |")
            continue
        mag_cal = c.apply(imu.acc_m_s2, mag_uT)[1]
        mean_norm = float(np.linalg.norm(mag_cal, axis=1).mean()) if mag_cal is not None else 0.0
        rel = f" ({100 * c.mag_fit_rms_uT / mean_norm:.2f} %)" if mean_norm else ""
        rows.append(f"| {method} | {c.n_poses} | {c.acc_fit_rms_m_s2 * 1e3:.1f} | {c.mag_fit_rms_uT:.2f}{rel} | "
                    f"{np.round(c.acc_offset_m_s2, 3).tolist()} | {np.round(c.mag_offset_uT, 2).tolist()} |")
    return "\n".join(rows)


def build_parser() -> argparse.ArgumentParser:
    """CLI."""
    p = argparse.ArgumentParser(prog="python -m gateway.calibrate", description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)  # fmt: skip
    p.add_argument("recording", help=".rigrec file or directory of the device being posed and turned")
    p.add_argument("--device", default=None, help="device id (default: the first IMU device in the recording)")
    p.add_argument("--min-pose-s", type=float, default=1.0, help="shortest rest segment used as a pose, s (default 1)")
    p.add_argument("--no-mag", action="store_true", help="calibrate the accelerometer only")
    p.add_argument("--method", choices=METHODS, default="fit",
                   help="fit: pose and ellipsoid fits (default); paper: seed 004's level pose and min/max")
    p.add_argument("--compare", action="store_true", help="print both methods' fit figures instead of the JSON")
    p.add_argument("-o", "--output", default=None, help="write the calibration JSON here (default: stdout)")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.add_argument("--hook-mount", action="store_true",
                   help="fit a hook's IMU offset from the rope axis instead (a recording of the hanging hook twisting)")
    p.add_argument("--mount-z", type=float, default=0.0, metavar="M",
                   help="with --hook-mount: the IMU's height above the hook and load's centre, m, as measured (a "
                   "twist does not show it; default 0)")
    p.add_argument("--api", default="http://127.0.0.1:8000", metavar="URL",
                   help="with --hook-mount: the gateway's address in the printed command (default http://127.0.0.1:8000)")
    return p


def hook_compass_calibration(iron: IronFit, tilt_xy_rad: Sequence[float]) -> dict[str, Any] | None:
    """The device calibration (`DeviceCalibration.to_json`) that takes a hook's compass offset and in-plane soft iron
    (`IronFit.mag_correction`) out before fusion, the accelerometer as it is; None when the fit is too uncertain."""
    correction = iron.mag_correction(tilt_xy_rad)
    if correction is None:
        return None
    offset, soft = correction
    # to 0.01 µT and 1e-5 (far below the fit's own error), so the tilt's trace on z reads 0
    return DeviceCalibration(np.zeros(3), np.ones(3), np.round(offset, 2), np.round(soft, 5),
                             mag_fit_rms_uT=iron.residual_uT).to_json()


def hook_mount_report(imu: ImuSeries, mag_uT: FloatArray | None, z_m: float, api: str = "http://127.0.0.1:8000"
                      ) -> str:  # fmt: skip
    """`--hook-mount`: the fit as JSON (the `imu_offset_m` setting first) and how to set it; ValueError if it cannot."""
    dt_s = 1.0 / imu.rate_hz
    fit = fit_hook_mount(imu.gyr_rad_s, imu.acc_m_s2, dt_s, mag_uT)
    tilt_deg = fit.tilt_setting()
    tilt_rad = [math.radians(a) for a in tilt_deg]  # as the filter will turn the samples: the setting, rounded
    axes = hook_axes_fit(imu.gyr_rad_s, imu.acc_m_s2, dt_s, mag_uT, tilt_rad)
    bias = axes.bias_setting()
    settings = {"imu_offset_m": fit.setting(z_m), "imu_tilt_deg": tilt_deg}
    if bias is not None:
        settings["acc_bias_xy_m_s2"] = bias
    iron, cal, iron_note = None, None, ""
    if mag_uT is not None:
        try:
            iron = fit_hard_iron(mag_uT, tilt_rad, imu.gyr_rad_s, dt_s)
            cal = hook_compass_calibration(iron, tilt_rad)
        except ValueError as exc:
            iron_note = f"\n# calibration left out: {exc}"
    figures = {"std_m": round(fit.std_m, 4), "twist_accel_rms_rad_s2": round(fit.twist_accel_rms_rad_s2, 3),
               "residual_m_s2": round(fit.residual_m_s2, 4), "acc_bias_std_m_s2": round(axes.bias_std_m_s2, 4)}
    if iron is not None:
        figures |= {"mag_offset_std_uT": round(iron.std_uT, 3), "mag_turned_deg": round(math.degrees(iron.span_rad)),
                    "mag_horizontal_uT": round(iron.radius_uT, 2)}  # fmt: skip
        if cal is None:
            iron_note = (f"\n# calibration left out: the magnetometer's offset fits to "
                         f"{np.round(iron.offset_xy_uT, 2).tolist()} ± {iron.std_uT:.2f} µT, less certain than "
                         f"{MAX_IRON_STD_UT:g} (steel moving near it, or a swinging hook)")
    text = json.dumps({"device_id": imu.device_id, **settings, **({"calibration": cal} if cal else {}), **figures},
                      indent=2)  # fmt: skip
    if bias is None:
        text += (f"\n# acc_bias_xy_m_s2 left out: the accelerometer's offset fits to "
                 f"{np.round(axes.bias_xy_m_s2, 3).tolist()} ± {axes.bias_std_m_s2:.3f} m/s², less certain than "
                 f"{MAX_BIAS_STD_M_S2:g} (a twist too fast, or the hook swung or was pushed while it twisted); told "
                 "wrong it would lean the rope wrong. The offset and tilt stand. To have it, twist the hook again, "
                 "less hard, hanging still in calm air")
    text += iron_note
    if cal is not None:
        text += ("\n# calibration: the magnetometer's offset in the hook's plane (hard iron), taken out before fusion."
                 " It replaces the device's calibration: if it has one from poses (`python -m gateway.calibrate REC`),"
                 " leave `calibration` out of the body")
    body = json.dumps({"kind": "hook", "thresholds": settings, **({"calibration": cal} if cal else {})})
    return (f"{text}\n# set it (with the operator token):\n# curl -X PUT -H 'Authorization: Bearer $TOKEN' -H "
            f"'Content-Type: application/json' -d '{body}' {api.rstrip('/')}/api/devices/{imu.device_id}/settings")


def main(argv: Sequence[str] | None = None) -> int:
    """Fit and print (or write) the device's calibration; exit 1 with a message when the recording is not enough."""
    args = build_parser().parse_args(argv)
    try:
        imu = load_imu(args.recording, args.device, progress=not args.no_progress)
        mag = None if args.no_mag else imu.mag_uT
        if args.hook_mount:
            print(hook_mount_report(imu, mag, args.mount_z, args.api))
            return 0
        if args.compare:
            print(compare_table(imu, mag, args.min_pose_s))
            return 0
        cal = fit_device(imu.gyr_rad_s, imu.acc_m_s2, mag, imu.rate_hz, args.min_pose_s, args.method)
        bias = gyro_bias_at_rest(imu.gyr_rad_s, imu.acc_m_s2, imu.rate_hz, args.min_pose_s)
    except ValueError as exc:
        print(f"calibration failed: {exc}", file=sys.stderr)
        return 1
    text = json.dumps({"device_id": imu.device_id, "method": args.method, **cal.to_json(),
                       "gyr_bias_rad_s": np.round(bias, 6).tolist()}, indent=2)  # fmt: skip
    if args.output:
        Path(args.output).write_text(text + "\n")
        print(f"wrote {args.output}: {cal.n_poses} poses, accel fit rms {cal.acc_fit_rms_m_s2 * 1e3:.1f} mm/s², "
              f"mag fit rms {cal.mag_fit_rms_uT:.2f} µT", file=sys.stderr)  # fmt: skip
    else:
        print(text)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
