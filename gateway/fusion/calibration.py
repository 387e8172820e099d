"""Sensor calibration, offline (whole arrays) and online (streaming accumulators fed sample by sample or by block).

- Gyro bias: mean rate over rest (seed 004: "gyro bias = mean at rest").
- Rest detection: over a trailing window, mean gyro norm below `gyr_th_rad_s` and accelerometer standard deviation
  (root of the summed per-axis variances) below `acc_th_m_s2`.
- Accelerometer offset and per-axis scale from rest poses: fit `|(a - offset) / scale| = g` by linear least
  squares on the axis-aligned quadric A x² + B y² + C z² + D x + E y + F z = 1 (six-position or many poses).
- Magnetometer hard/soft iron: seed 004's min/max method (offset = (max + min)/2, per-axis scale so the axes match)
  and a least-squares ellipsoid fit with a full symmetric soft-iron matrix:
  x·A·x + b·x = 1 fitted, centre c = -A⁻¹ b / 2, then W = sqrtm(A / (1 + c·A·c)) · r so |W (m - c)| = r.
Calibrated readings: `acc_cal = (acc - offset) / scale`, `mag_cal = W @ (mag - offset)`.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike, NDArray

from gateway.fusion.base import FloatArray
from gateway.fusion.quaternion import GRAVITY_M_S2

BoolArray = NDArray[np.bool_]


def _f64(a: ArrayLike) -> FloatArray:
    return np.asarray(a, dtype=np.float64)


# ---------------------------------------------------------------------------------------------------------------
# Rest detection and gyro bias
# ---------------------------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class RestSettings:
    """Rest = over the trailing `window_s`, mean |ω| < gyr_th and accel std < acc_th (VQF-like defaults)."""

    window_s: float = 0.5
    gyr_th_rad_s: float = np.deg2rad(2.0)
    acc_th_m_s2: float = 0.2


def _window(rate_hz: float, window_s: float) -> int:
    return max(2, int(round(window_s * rate_hz)))


def detect_rest(gyr_rad_s: ArrayLike, acc_m_s2: ArrayLike, rate_hz: float,
                settings: RestSettings | None = None) -> BoolArray:
    """Boolean rest mask (N,); a sample is at rest when the trailing window ending at it is (False until full)."""
    s = settings or RestSettings()
    gyr, acc = _f64(gyr_rad_s), _f64(acc_m_s2)
    n, w = gyr.shape[0], _window(rate_hz, s.window_s)
    out = np.zeros(n, dtype=bool)
    if n < w:
        return out

    def trailing_mean(x: FloatArray) -> FloatArray:
        c = np.cumsum(np.concatenate([np.zeros((1, *x.shape[1:])), x]), axis=0)
        res: FloatArray = (c[w:] - c[:-w]) / w
        return res

    gyr_mean_norm = trailing_mean(np.linalg.norm(gyr, axis=1))
    acc_mean = trailing_mean(acc)
    acc_var = np.sum(trailing_mean(acc * acc) - acc_mean**2, axis=1)
    out[w - 1:] = (gyr_mean_norm < s.gyr_th_rad_s) & (np.maximum(acc_var, 0.0) < s.acc_th_m_s2**2)
    return out


def gyro_bias_from_rest(gyr_rad_s: ArrayLike, rest: BoolArray | None = None) -> FloatArray:
    """Mean gyro reading (rad/s) over the rest samples (all samples if `rest` is None) — seed 004."""
    gyr = _f64(gyr_rad_s)
    sel = gyr if rest is None else gyr[np.asarray(rest, dtype=bool)]
    if sel.shape[0] == 0:
        raise ValueError("no rest samples to estimate the gyro bias from")
    bias: FloatArray = sel.mean(axis=0)
    return bias


class RestDetector:
    """Streaming `detect_rest`: same trailing window, fed one sample at a time; `update` returns the rest flag."""

    def __init__(self, rate_hz: float, settings: RestSettings | None = None) -> None:
        self.settings = settings or RestSettings()
        self._w = _window(rate_hz, self.settings.window_s)
        self._gyr_norm = np.zeros(self._w)
        self._acc = np.zeros((self._w, 3))
        self._count = 0

    def update(self, gyr_rad_s: ArrayLike, acc_m_s2: ArrayLike) -> bool:
        i = self._count % self._w
        self._gyr_norm[i] = float(np.linalg.norm(_f64(gyr_rad_s)))
        self._acc[i] = _f64(acc_m_s2)
        self._count += 1
        if self._count < self._w:
            return False
        acc_var = float(np.sum(self._acc.var(axis=0)))
        return bool(self._gyr_norm.mean() < self.settings.gyr_th_rad_s and acc_var < self.settings.acc_th_m_s2**2)


class GyroBiasEstimator:
    """Online gyro bias: running mean of the gyro over samples the rest detector flags (rad/s)."""

    def __init__(self, rate_hz: float, settings: RestSettings | None = None) -> None:
        self.rest = RestDetector(rate_hz, settings)
        self._sum = np.zeros(3)
        self._n = 0

    def update(self, gyr_rad_s: ArrayLike, acc_m_s2: ArrayLike) -> bool:
        """Feed one sample; returns whether it was counted as rest."""
        at_rest = self.rest.update(gyr_rad_s, acc_m_s2)
        if at_rest:
            self._sum += _f64(gyr_rad_s)
            self._n += 1
        return at_rest

    def update_block(self, gyr_rad_s: ArrayLike, acc_m_s2: ArrayLike) -> None:
        for g, a in zip(_f64(gyr_rad_s), _f64(acc_m_s2), strict=True):
            self.update(g, a)

    @property
    def n_rest(self) -> int:
        return self._n

    @property
    def bias_rad_s(self) -> FloatArray | None:
        """Current estimate, or None before any rest was seen."""
        return self._sum / self._n if self._n else None


# ---------------------------------------------------------------------------------------------------------------
# Accelerometer offset and scale from rest poses
# ---------------------------------------------------------------------------------------------------------------


class AxisQuadricAccumulator:
    """Normal equations of A x² + B y² + C z² + D x + E y + F z = 1 (axis-aligned ellipsoid), fed by samples/blocks.

    Used for accelerometer rest poses (radius g) and gives offset and per-axis scale with `solve(radius)`."""

    def __init__(self) -> None:
        self._ata = np.zeros((6, 6))
        self._atb = np.zeros(6)
        self.n = 0

    def add(self, v: ArrayLike) -> None:
        """Add one sample (3,) or a block (N, 3)."""
        x = np.atleast_2d(_f64(v))
        d = np.concatenate([x * x, x], axis=1)
        self._ata += d.T @ d
        self._atb += d.sum(axis=0)
        self.n += x.shape[0]

    def solve(self, radius: float) -> tuple[FloatArray, FloatArray]:
        """(offset, scale): `|(v - offset) / scale| = radius`; needs poses spanning all three axes."""
        p = np.linalg.solve(self._ata, self._atb)
        a, lin = p[:3], p[3:]
        if np.any(a <= 0):
            raise ValueError("poses do not span an ellipsoid; add poses with each axis up and down")
        offset = -lin / (2 * a)
        k = 1.0 + np.sum(a * offset**2)
        scale = np.sqrt(k / a) / radius
        return offset, scale


def fit_accel_offset_scale(pose_means_m_s2: ArrayLike, gravity_m_s2: float = GRAVITY_M_S2) -> tuple[FloatArray,
                                                                                                      FloatArray]:
    """Offset (m/s²) and dimensionless per-axis scale from mean accelerometer readings of ≥ 6 rest poses."""
    acc = AxisQuadricAccumulator()
    acc.add(pose_means_m_s2)
    return acc.solve(gravity_m_s2)


def apply_accel_calibration(acc_m_s2: ArrayLike, offset: FloatArray, scale: FloatArray) -> FloatArray:
    out: FloatArray = (_f64(acc_m_s2) - offset) / scale
    return out


# ---------------------------------------------------------------------------------------------------------------
# Magnetometer hard and soft iron
# ---------------------------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class MagCalibration:
    """`mag_cal = soft_iron @ (mag - offset_uT)`; soft_iron is 3×3 (diagonal for the min/max method)."""

    offset_uT: FloatArray
    soft_iron: FloatArray

    def apply(self, mag_uT: ArrayLike) -> FloatArray:
        out: FloatArray = (_f64(mag_uT) - self.offset_uT) @ self.soft_iron.T
        return out


class MinMaxMagCalibrator:
    """Seed 004: track per-axis min and max over a full rotation; offset = (max + min)/2, scale axes to match."""

    def __init__(self) -> None:
        self._lo = np.full(3, np.inf)
        self._hi = np.full(3, -np.inf)

    def add(self, mag_uT: ArrayLike) -> None:
        """Add one sample (3,) or a block (N, 3)."""
        m = np.atleast_2d(_f64(mag_uT))
        self._lo = np.minimum(self._lo, m.min(axis=0))
        self._hi = np.maximum(self._hi, m.max(axis=0))

    def solve(self) -> MagCalibration:
        radius = (self._hi - self._lo) / 2
        if not np.all(np.isfinite(radius)) or np.any(radius <= 0):
            raise ValueError("rotate the sensor through all orientations first")
        offset = (self._hi + self._lo) / 2
        return MagCalibration(offset, np.diag(radius.mean() / radius))


def calibrate_mag_minmax(mag_uT: ArrayLike) -> MagCalibration:
    """Offline form of `MinMaxMagCalibrator` (seed 004)."""
    c = MinMaxMagCalibrator()
    c.add(mag_uT)
    return c.solve()


class EllipsoidAccumulator:
    """Normal equations of the general quadric x·A·x + b·x = 1 (9 unknowns), fed by samples or blocks."""

    def __init__(self) -> None:
        self._ata = np.zeros((9, 9))
        self._atb = np.zeros(9)
        self.n = 0

    def add(self, v: ArrayLike) -> None:
        x = np.atleast_2d(_f64(v))
        px, py, pz = x[:, 0], x[:, 1], x[:, 2]
        d = np.stack([px * px, py * py, pz * pz, 2 * px * py, 2 * px * pz, 2 * py * pz, px, py, pz], axis=1)
        self._ata += d.T @ d
        self._atb += d.sum(axis=0)
        self.n += x.shape[0]

    def solve(self, radius: float | None = None) -> MagCalibration:
        """Hard-iron offset and symmetric soft-iron matrix mapping the ellipsoid onto a sphere of `radius`
        (default: the geometric mean of the ellipsoid's semi-axes, which keeps the field strength's scale)."""
        p = np.linalg.solve(self._ata, self._atb)
        a = np.array([[p[0], p[3], p[4]], [p[3], p[1], p[5]], [p[4], p[5], p[2]]])
        b = p[6:]
        centre = -0.5 * np.linalg.solve(a, b)
        k = 1.0 + centre @ a @ centre
        m = a / k  # (x - c)·M·(x - c) = 1
        evals, evecs = np.linalg.eigh(m)
        if np.any(evals <= 0):
            raise ValueError("samples do not lie on an ellipsoid; rotate through more orientations")
        semi_axes = 1.0 / np.sqrt(evals)
        r = float(np.prod(semi_axes) ** (1 / 3)) if radius is None else radius
        soft = evecs @ np.diag(np.sqrt(evals) * r) @ evecs.T
        return MagCalibration(centre, soft)


def calibrate_mag_ellipsoid(mag_uT: ArrayLike, radius_uT: float | None = None) -> MagCalibration:
    """Offline least-squares ellipsoid fit (full soft iron); needs samples spread over many orientations."""
    c = EllipsoidAccumulator()
    c.add(mag_uT)
    return c.solve(radius_uT)
