"""Leave-one-trial-out (LOO) tuning: the honest BROAD figure for a filter whose gains were chosen on BROAD.

Every tuned filter has a small, fixed table of candidate settings (`SPECS`). Each candidate is run once on every trial
(`score_matrix`); for each held-out trial the candidate with the lowest mean total error over the *other* trials is
chosen and scored on the held-out one (`leave_one_out`). Choosing from precomputed scores is exactly the same as
re-tuning inside each fold, because a candidate's score on a trial does not depend on which trials are in the fold;
only the choice does, and it never sees the held-out trial. The in-sample figure (one choice on all trials, scored on
the same trials) is reported beside it and labelled as such.

The candidate tables were written once, around the gains the docs give; they are not re-chosen per fold. In 6D the
magnetometer-only parameters of a candidate are dropped (they cannot change the result), so fewer runs are needed.
"""

from __future__ import annotations

import hashlib
import importlib
import itertools
import json
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from gateway.fusion import broad
from gateway.fusion.base import AttitudeFilter

Params = dict[str, float]


def product(**grid: Sequence[float]) -> tuple[Params, ...]:
    """Every combination of the given values (full grid)."""
    keys = list(grid)
    return tuple(dict(zip(keys, values, strict=True)) for values in itertools.product(*(grid[k] for k in keys)))


def star(base: Mapping[str, float], **alternatives: Sequence[float]) -> tuple[Params, ...]:
    """`base` plus each parameter moved alone to each alternative value (one-at-a-time grid, for slow filters)."""
    out: list[Params] = [dict(base)]
    for key, values in alternatives.items():
        out += [{**base, key: v} for v in values if v != base[key]]
    return tuple(out)


@dataclass(frozen=True)
class TuningSpec:
    """A filter class, its settings class ("module:Name"), the candidate settings and the 9D-only parameters."""

    filter_path: str
    settings_path: str
    candidates: tuple[Params, ...]
    mag_only: frozenset[str] = field(default_factory=frozenset)

    def for_mode(self, mode: broad.Mode) -> tuple[Params, ...]:
        """Candidates for a mode; in 6D the magnetometer parameters are dropped and duplicates removed."""
        if mode == "9D":
            return self.candidates
        seen: dict[str, Params] = {}
        for c in self.candidates:
            reduced = {k: v for k, v in c.items() if k not in self.mag_only}
            seen.setdefault(json.dumps(reduced, sort_keys=True), reduced)
        return tuple(seen.values())

    def settings(self, params: Params) -> Any:
        """The settings object for a candidate (all other settings at their defaults)."""
        return _load(self.settings_path)(**params)

    def make(self, params: Params, mode: broad.Mode) -> AttitudeFilter:
        """A fresh filter with these settings."""
        instance: AttitudeFilter = _load(self.filter_path)(self.settings(params), use_mag=mode == "9D")
        return instance


def _load(path: str) -> Any:
    module, name = path.split(":")
    return getattr(importlib.import_module(module), name)


# Candidate tables: each holds the documented defaults. Full grids where a pass over BROAD takes seconds, one-at-a-time
# grids for the Kalman filters (about 30 s per pass of 15 trials).
SPECS: dict[str, TuningSpec] = {
    "default": TuningSpec(
        "gateway.fusion.default:DefaultFilter",
        "gateway.fusion.default:DefaultSettings",
        product(tau_acc_s=(2.0, 2.5, 3.1), bias_sigma_motion_deg_s=(0.08, 0.1, 0.125), tau_mag_s=(9.0, 15.0, 20.0)),
        frozenset({"tau_mag_s"}),
    ),
    "mahony": TuningSpec(
        "gateway.fusion.mahony:MahonyFilter",
        "gateway.fusion.mahony:MahonySettings",
        product(kp=(0.1, 0.2, 0.4), ki=(0.00025, 0.0005, 0.001), kp_mag=(0.05, 0.1, 0.2)),
        frozenset({"kp_mag"}),
    ),
    "complementary": TuningSpec(
        "gateway.fusion.complementary:ComplementaryFilter",
        "gateway.fusion.complementary:ComplementarySettings",
        product(k_rad_s=(0.1, 0.2, 0.4), k_mag_rad_s=(0.05, 0.1, 0.2)),
        frozenset({"k_mag_rad_s"}),
    ),
    "adaptive": TuningSpec(
        "gateway.fusion.complementary:AdaptiveComplementaryFilter",
        "gateway.fusion.complementary:AdaptiveSettings",
        product(kp_still_rad_s=(0.5, 1.0, 2.0), kp_moving_rad_s=(0.01, 0.02, 0.04), k_mag_rad_s=(0.05, 0.1, 0.2)),
        frozenset({"k_mag_rad_s"}),
    ),
    "kf": TuningSpec(
        "gateway.fusion.kf:KalmanAngleFilter",
        "gateway.fusion.kf:KfSettings",
        star({"gyr_noise_rad_s": 0.005, "r_window_s": 2.0}, gyr_noise_rad_s=(0.0025, 0.01), r_window_s=(1.0, 4.0)),
    ),
    "ekf": TuningSpec(
        "gateway.fusion.ekf:QuaternionEkf",
        "gateway.fusion.ekf:EkfSettings",
        star({"gyr_noise_rad_s": 0.01, "acc_noise": 0.05, "mag_noise": 0.03},
             gyr_noise_rad_s=(0.005, 0.02), acc_noise=(0.025, 0.1), mag_noise=(0.015, 0.06)),
        frozenset({"mag_noise"}),
    ),
}


# ---------------------------------------------------------------------------------------------------------------
# Scores of every candidate on every trial (optionally cached in a JSON file)
# ---------------------------------------------------------------------------------------------------------------


def trial_key(trial: broad.Trial) -> str:
    """Identifies a trial's data (name plus a digest of its inputs), so a cache never mixes folders."""
    h = hashlib.sha1()
    for a in (trial.gyr_rad_s, trial.acc_m_s2, trial.mag_uT):
        h.update(np.ascontiguousarray(a).tobytes())
    return f"{trial.name}:{h.hexdigest()[:12]}"


class ScoreCache:
    """Scores keyed by (filter, mode, full settings, trial data); `path=None` keeps them in memory only.

    The key holds every setting, so changed defaults are new entries; a change of the filter's *code* is not seen:
    delete the file after one."""

    def __init__(self, path: Path | None = None) -> None:
        self.path = path
        self._data: dict[str, list[float]] = {}
        if path is not None and path.is_file():
            self._data = json.loads(path.read_text())

    @staticmethod
    def key(name: str, mode: str, settings: object, trial: str) -> str:
        return json.dumps([name, mode, repr(settings), trial])

    def get(self, key: str) -> broad.Score | None:
        v = self._data.get(key)
        return None if v is None else broad.Score(*v)

    def put(self, key: str, s: broad.Score) -> None:
        self._data[key] = [s.total_deg, s.heading_deg, s.inclination_deg]

    def save(self) -> None:
        if self.path is not None:
            self.path.write_text(json.dumps(self._data))


def score_matrix(
    name: str,
    spec: TuningSpec,
    trials: Sequence[broad.Trial],
    mode: broad.Mode,
    cache: ScoreCache | None = None,
    progress: Callable[[str], None] | None = None,
) -> tuple[tuple[Params, ...], np.ndarray]:
    """(candidates, scores (n_candidates, n_trials, 3)): total, heading, inclination RMSE in degrees."""
    cache = cache or ScoreCache()
    candidates = spec.for_mode(mode)
    keys = [trial_key(t) for t in trials]
    out = np.empty((len(candidates), len(trials), 3))
    for i, params in enumerate(candidates):
        for j, (trial, tk) in enumerate(zip(trials, keys, strict=True)):
            key = ScoreCache.key(name, mode, spec.settings(params), tk)
            s = cache.get(key)
            if s is None:
                if progress is not None:
                    progress(f"{name} {mode} {i + 1}/{len(candidates)} {trial.name[:24]}")
                s = broad.score(broad.run_filter(spec.make(params, mode), trial, mode), trial, mode)
                cache.put(key, s)
            out[i, j] = (s.total_deg, s.heading_deg, s.inclination_deg)
        cache.save()
    return candidates, out


# ---------------------------------------------------------------------------------------------------------------
# Selection
# ---------------------------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class CvResult:
    """LOO and in-sample outcome of one filter in one mode; scores are (n_trials, 3) in degrees."""

    trials: tuple[str, ...]
    groups: tuple[tuple[str, ...], ...]
    candidates: tuple[Params, ...]
    loo_choice: tuple[int, ...]  # candidate chosen without trial j
    loo: np.ndarray  # trial j scored with loo_choice[j]
    in_sample_choice: int  # candidate chosen on all trials
    in_sample: np.ndarray

    def group_means(self, which: str = "loo") -> dict[str, broad.Score]:
        """`{"all", "undisturbed", "disturbed"}` plain means of trial RMSEs (the dataset's group figure)."""
        scores = self.loo if which == "loo" else self.in_sample
        out: dict[str, broad.Score] = {}
        for g in ("all", *broad.GROUPS):
            rows = [scores[j] for j, gs in enumerate(self.groups) if g == "all" or g in gs]
            if rows:
                m = np.mean(rows, axis=0)
                out[g] = broad.Score(float(m[0]), float(m[1]), float(m[2]))
        return out


def leave_one_out(scores: np.ndarray, criterion: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """For each trial j: the candidate with the lowest mean `criterion` column over the other trials, and its score
    on trial j. `scores` is (n_candidates, n_trials, k); returns (choice (n_trials,), held-out scores (n_trials, k)).
    Ties go to the earlier candidate."""
    n_trials = scores.shape[1]
    crit = scores[:, :, criterion]
    choice = np.empty(n_trials, dtype=int)
    for j in range(n_trials):  # the mean over the other trials only (no "sum minus own", which rounds)
        choice[j] = int(np.argmin(np.delete(crit, j, axis=1).mean(axis=1)))
    return choice, scores[choice, np.arange(n_trials)]


def cross_validate(
    name: str,
    trials: Sequence[broad.Trial],
    mode: broad.Mode,
    spec: TuningSpec | None = None,
    cache: ScoreCache | None = None,
    progress: Callable[[str], None] | None = None,
) -> CvResult:
    """LOO and in-sample figures of a filter in `SPECS` (or an explicit spec) on `trials`; criterion: total RMSE."""
    spec = spec or SPECS[name]
    candidates, scores = score_matrix(name, spec, trials, mode, cache, progress)
    choice, loo = leave_one_out(scores)
    best = int(np.argmin(scores[:, :, 0].mean(axis=1)))
    return CvResult(
        tuple(t.name for t in trials), tuple(t.groups for t in trials), candidates, tuple(int(c) for c in choice),
        loo, best, scores[best],
    )


def choice_counts(result: CvResult) -> list[tuple[Params, int]]:
    """How often each candidate was chosen across the folds, most frequent first."""
    counts: dict[int, int] = {}
    for c in result.loo_choice:
        counts[c] = counts.get(c, 0) + 1
    return [(result.candidates[c], n) for c, n in sorted(counts.items(), key=lambda kv: -kv[1])]


def untuned_scores(run: Callable[[broad.Trial], np.ndarray], trials: Iterable[broad.Trial],
                   mode: broad.Mode) -> np.ndarray:
    """(n_trials, 3) scores of a filter with nothing to tune (e.g. VQF's defaults): its LOO equals its in-sample."""
    return np.array([list(broad.score(run(t), t, mode).as_dict().values()) for t in trials])
