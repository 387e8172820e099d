"""BROAD recordings: load a trial, start a filter from its rest window, and score it the dataset's way.

Dataset: D. Laidig, M. Caruso, A. Cereatti, T. Seel, "BROAD — A Benchmark for Robust Inertial Orientation
Estimation", Data 6(7):72, 2021 (CC BY 4.0). Format and scoring: ../shared/data/broad/README.md.

Scoring (README): q_err = q_est ⊗ q_ref* (earth frame); total 2·acos|w|, heading 2·atan(|z|/|w|), inclination
2·acos√(w² + z²); RMSE over the `movement` samples, NaN reference ignored; a group's figure is the plain mean of its
trials' RMSEs. 6D: one constant heading offset per trial is removed before total and heading are scored.
"""

from __future__ import annotations

import json
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Literal

import numpy as np
import scipy.io
from numpy.typing import NDArray

from gateway.fusion import quaternion as quat
from gateway.fusion.base import AttitudeFilter, FloatArray

BoolArray = NDArray[np.bool_]

Mode = Literal["6D", "9D"]
REST_WINDOW_S = 0.5
"""Every BROAD trial starts at rest; filters are initialised from this many seconds of acc (+ mag)."""
GROUPS = ("undisturbed", "disturbed")


@dataclass(frozen=True)
class Trial:
    """One BROAD trial. Arrays have N rows; `quat_ref` is the optical reference (w, x, y, z, NaN where lost)."""

    name: str
    rate_hz: float
    gyr_rad_s: FloatArray
    acc_m_s2: FloatArray
    mag_uT: FloatArray
    quat_ref: FloatArray
    pos_m: FloatArray
    movement: BoolArray
    groups: tuple[str, ...] = field(default=())
    info: str = ""

    @property
    def dt_s(self) -> float:
        return 1.0 / self.rate_hz

    @property
    def n(self) -> int:
        return int(self.gyr_rad_s.shape[0])

    def slice(self, start: int, stop: int) -> Trial:
        """A shorter copy (samples start:stop), e.g. for quick tests; the slice should begin at rest."""
        s = np.s_[start:stop]
        return Trial(self.name, self.rate_hz, self.gyr_rad_s[s], self.acc_m_s2[s], self.mag_uT[s],
                     self.quat_ref[s], self.pos_m[s], self.movement[s], self.groups, self.info)


def groups_from_name(name: str) -> tuple[str, ...]:
    """Groups guessed from a trial's file name, for folders without trials.json ("disturbed" checked last)."""
    lower = name.lower()
    groups = ["all_trials"]
    if "undisturbed" in lower:
        groups.append("undisturbed")
    elif "disturbed" in lower:
        groups.append("disturbed")
    for key in ("rotation", "translation", "combined", "slow", "fast"):
        if key in lower:
            groups.append(key)
    groups.append("with_breaks" if "with_breaks" in lower else "no_breaks")
    return tuple(groups)


def _trial_groups(path: Path) -> tuple[str, ...]:
    index = path.parent / "trials.json"
    if index.is_file():
        trials = json.loads(index.read_text()).get("trials", {})
        if path.stem in trials:
            return tuple(trials[path.stem]["groups"])
    return groups_from_name(path.stem)


def load_trial(path: str | Path) -> Trial:
    """Read a BROAD `.mat` file; groups come from trials.json beside it, else from the file name."""
    path = Path(path)
    d = scipy.io.loadmat(str(path))
    info = d.get("info")
    info_text = str(np.asarray(info).ravel()[0]) if info is not None and np.asarray(info).size else ""
    n = d["imu_gyr"].shape[0]
    pos = np.asarray(d["opt_pos"], dtype=np.float64) if "opt_pos" in d else np.full((n, 3), np.nan)
    return Trial(
        name=path.stem,
        rate_hz=float(np.asarray(d["sampling_rate"]).ravel()[0]),
        gyr_rad_s=np.ascontiguousarray(d["imu_gyr"], dtype=np.float64),
        acc_m_s2=np.ascontiguousarray(d["imu_acc"], dtype=np.float64),
        mag_uT=np.ascontiguousarray(d["imu_mag"], dtype=np.float64),
        quat_ref=np.ascontiguousarray(d["opt_quat"], dtype=np.float64),
        pos_m=pos,
        movement=np.asarray(d["movement"]).ravel().astype(bool),
        groups=_trial_groups(path),
        info=info_text,
    )


def find_trials(data_dir: str | Path, pattern: str = "*.mat") -> list[Path]:
    """Sorted `.mat` files in `data_dir` matching the glob `pattern`."""
    return sorted(p for p in Path(data_dir).glob(pattern) if p.suffix == ".mat")


# ---------------------------------------------------------------------------------------------------------------
# Initialisation and running
# ---------------------------------------------------------------------------------------------------------------


def rest_means(trial: Trial, duration_s: float = REST_WINDOW_S) -> tuple[FloatArray, FloatArray]:
    """Mean accelerometer (m/s²) and magnetometer (µT) over the first `duration_s` (rest in every trial)."""
    k = max(1, int(round(duration_s * trial.rate_hz)))
    return trial.acc_m_s2[:k].mean(axis=0), trial.mag_uT[:k].mean(axis=0)


def initial_attitude(trial: Trial, mode: Mode) -> FloatArray:
    """Start attitude: from acc (6D, yaw 0) or acc + mag (9D) over the rest window. No use of the reference."""
    acc, mag = rest_means(trial)
    return quat.from_acc(acc) if mode == "6D" else quat.from_acc_mag(acc, mag)


def run_filter(filt: AttitudeFilter, trial: Trial, mode: Mode) -> FloatArray:
    """Initialise `filt` from the rest window and run it over the whole trial; returns (N, 4)."""
    acc, mag = rest_means(trial)
    mag_in = trial.mag_uT if mode == "9D" else None
    filt.initialise(acc, mag if mode == "9D" else None)
    return filt.run(trial.gyr_rad_s, trial.acc_m_s2, mag_in, trial.dt_s)


# ---------------------------------------------------------------------------------------------------------------
# Scoring
# ---------------------------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class Score:
    """RMSE in degrees over the movement samples of one trial (or a group mean)."""

    total_deg: float
    heading_deg: float
    inclination_deg: float

    def as_dict(self) -> dict[str, float]:
        return {"total": self.total_deg, "heading": self.heading_deg, "inclination": self.inclination_deg}


def error_quaternion(q_est: FloatArray, q_ref: FloatArray) -> FloatArray:
    """`q_est ⊗ q_ref*`, the error expressed in the earth frame (both inputs normalised first)."""
    return quat.normalise(quat.multiply(quat.normalise(q_est), quat.conjugate(quat.normalise(q_ref))))


def error_angles(q_err: FloatArray) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Total, heading and inclination error in rad per sample (README definitions)."""
    w, z = q_err[..., 0], q_err[..., 3]
    total = 2.0 * np.arccos(np.clip(np.abs(w), 0.0, 1.0))
    with np.errstate(divide="ignore", invalid="ignore"):
        heading = 2.0 * np.arctan(np.abs(z) / np.abs(w))
    inclination = 2.0 * np.arccos(np.clip(np.sqrt(w * w + z * z), 0.0, 1.0))
    return total, heading, inclination


def heading_offset_rad(q_err: FloatArray, mask: BoolArray) -> float:
    """The constant rotation about earth Up that best explains the heading error over `mask` (circular mean).

    The signed heading of each error quaternion is 2·atan2(z, w) (sign-normalised so w >= 0); the offset is
    the direction of the mean of their unit vectors.
    """
    e = quat.canonical(q_err[mask])
    e = e[np.all(np.isfinite(e), axis=-1)]
    if e.shape[0] == 0:
        return 0.0
    psi = 2.0 * np.arctan2(e[:, 3], e[:, 0])
    return float(np.arctan2(np.sin(psi).mean(), np.cos(psi).mean()))


def remove_heading_offset(q_est: FloatArray, offset_rad: float) -> FloatArray:
    """Rotate the estimate about earth Up by `-offset_rad` (pre-multiplication)."""
    qz = quat.from_axis_angle(np.array([0.0, 0.0, 1.0]), np.array(-offset_rad))
    return quat.multiply(qz, q_est)


def _rmse_deg(err_rad: FloatArray) -> float:
    finite = err_rad[np.isfinite(err_rad)]
    return float(np.rad2deg(np.sqrt(np.mean(finite**2)))) if finite.size else float("nan")


def score(q_est: FloatArray, trial: Trial, mode: Mode) -> Score:
    """RMSE of total, heading and inclination over the trial's movement samples; 6D removes one heading offset."""
    mask = trial.movement & np.all(np.isfinite(trial.quat_ref), axis=-1)
    q_err = error_quaternion(q_est, trial.quat_ref)
    if mode == "6D":
        q_err = error_quaternion(remove_heading_offset(q_est, heading_offset_rad(q_err, mask)), trial.quat_ref)
    total, heading, incl = (a[mask] for a in error_angles(q_err))
    return Score(_rmse_deg(total), _rmse_deg(heading), _rmse_deg(incl))


def mean_score(scores: Iterable[Score]) -> Score:
    """Group figure: plain mean of the trials' RMSEs."""
    s = list(scores)
    if not s:
        nan = float("nan")
        return Score(nan, nan, nan)
    return Score(
        float(np.mean([x.total_deg for x in s])),
        float(np.mean([x.heading_deg for x in s])),
        float(np.mean([x.inclination_deg for x in s])),
    )


def group_scores(trials: Sequence[Trial], scores: Sequence[Score], groups: Sequence[str] = GROUPS) -> dict[str, Score]:
    """`{"all": mean, "undisturbed": mean, "disturbed": mean}` (groups with no trials are left out)."""
    out = {"all": mean_score(scores)}
    for g in groups:
        members = [s for t, s in zip(trials, scores, strict=True) if g in t.groups]
        if members:
            out[g] = mean_score(members)
    return out


def evaluate_trial(make: Callable[[], AttitudeFilter], trial: Trial, mode: Mode) -> tuple[FloatArray, Score]:
    """Build a fresh filter, run it on the trial and score it; returns (q_est, score)."""
    q = run_filter(make(), trial, mode)
    return q, score(q, trial, mode)
