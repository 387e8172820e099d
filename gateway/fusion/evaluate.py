"""Score registered attitude filters on a folder of BROAD `.mat` recordings, the dataset's way (see `broad`).

    python -m gateway.fusion.evaluate ../shared/data/broad --filter default --filter mahony --mode both --vqf
    python -m gateway.fusion.evaluate DATA_DIR --json > results.json
    python -m gateway.fusion.evaluate ../shared/data/broad --cv --vqf --cache /tmp/cv.json   # honest figures

Prints per trial and per group (undisturbed / disturbed / all) the RMSE in degrees of total, heading and
inclination error, and the throughput of each filter's `run()` in samples/s (wall time of the run only, after a
short warm-up so numba compilation is not counted). Data: BROAD (Laidig et al., Data 6(7):72, 2021, CC BY 4.0).

`--cv` reports leave-one-trial-out figures instead (`gateway.fusion.tuning`): each filter's gains are chosen from its
candidate table on all trials but one and scored on that one; these are the figures to quote, since every tuned
filter's defaults were chosen on these same trials. The in-sample figure is printed beside it, labelled.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from tqdm import tqdm

from gateway.fusion import broad, tuning
from gateway.fusion.base import FloatArray
from gateway.fusion.registry import FILTERS, make_filter

MODES: tuple[broad.Mode, ...] = ("9D", "6D")
VQF_NAME = "vqf"
WARMUP_SAMPLES = 300

# A runner takes (trial, mode) and returns (q_est (N, 4), seconds spent in the filter), or None if the mode is
# not supported.
Runner = Callable[[broad.Trial, broad.Mode], "tuple[FloatArray, float] | None"]


@dataclass(frozen=True)
class TrialResult:
    """One filter on one trial in one mode."""

    trial: str
    groups: tuple[str, ...]
    score: broad.Score
    samples: int
    seconds: float

    @property
    def samples_per_s(self) -> float:
        return self.samples / self.seconds if self.seconds > 0 else float("inf")


def registered_runner(name: str) -> Runner:
    """Runner for a filter from the registry; a mode the filter rejects (NotImplementedError/ValueError on
    construction or initialisation, or not listed in an optional `modes` attribute) is reported as unsupported."""

    def run(trial: broad.Trial, mode: broad.Mode) -> tuple[FloatArray, float] | None:
        try:
            filt = make_filter(name, use_mag=mode == "9D")
            if mode not in getattr(filt, "modes", MODES):
                return None
            warm = trial.slice(0, min(WARMUP_SAMPLES, trial.n))
            broad.run_filter(filt, warm, mode)  # compile / warm caches; the filter is re-initialised below
            acc, mag = broad.rest_means(trial)
            filt.initialise(acc, mag if mode == "9D" else None)
        except (NotImplementedError, ValueError):
            return None
        t0 = time.perf_counter()
        q = filt.run(trial.gyr_rad_s, trial.acc_m_s2, trial.mag_uT if mode == "9D" else None, trial.dt_s)
        return q, time.perf_counter() - t0

    return run


def vqf_runner() -> Runner:
    """Reference row: pip `vqf`, defaults, `VQF(dt).updateBatch` (how the README's figures were made)."""
    from vqf import VQF  # optional dev dependency, imported only when asked for

    def run(trial: broad.Trial, mode: broad.Mode) -> tuple[FloatArray, float]:
        t0 = time.perf_counter()
        v = VQF(trial.dt_s)
        if mode == "9D":
            q = v.updateBatch(trial.gyr_rad_s, trial.acc_m_s2, trial.mag_uT)["quat9D"]
        else:
            q = v.updateBatch(trial.gyr_rad_s, trial.acc_m_s2)["quat6D"]
        return np.asarray(q, dtype=np.float64), time.perf_counter() - t0

    return run


def evaluate(
    trials: Sequence[broad.Trial],
    runners: dict[str, Runner],
    modes: Sequence[broad.Mode] = MODES,
    progress: bool = True,
) -> dict[str, dict[str, list[TrialResult]]]:
    """Run every runner on every trial in every mode; `{filter: {mode: [TrialResult, ...]}}` (unsupported modes
    are left out)."""
    results: dict[str, dict[str, list[TrialResult]]] = {}
    jobs = [(name, mode, t) for name in runners for mode in modes for t in trials]
    bar = tqdm(jobs, desc="evaluate", unit="run", file=sys.stderr, disable=not progress)
    for name, mode, trial in bar:
        bar.set_postfix_str(f"{name} {mode} {trial.name[:24]}")
        out = runners[name](trial, mode)
        if out is None:
            continue
        q, seconds = out
        res = TrialResult(trial.name, trial.groups, broad.score(q, trial, mode), trial.n, seconds)
        results.setdefault(name, {}).setdefault(mode, []).append(res)
    return results


def summarise(rows: Sequence[TrialResult]) -> dict[str, dict[str, float]]:
    """Group figures: plain mean of trial RMSEs; samples/s = total samples / total filter time."""
    out: dict[str, dict[str, float]] = {}
    for group in ("all", *broad.GROUPS):
        members = [r for r in rows if group == "all" or group in r.groups]
        if not members:
            continue
        fig = broad.mean_score(r.score for r in members).as_dict()
        seconds = sum(r.seconds for r in members)
        fig["samples_per_s"] = sum(r.samples for r in members) / seconds if seconds > 0 else float("inf")
        out[group] = fig
    return out


def to_json(results: dict[str, dict[str, list[TrialResult]]]) -> dict[str, Any]:
    """`{"filters": {name: {mode: {group: {...}}}}, "trials": {name: {mode: {trial: {...}}}}}` (degrees)."""
    filters: dict[str, Any] = {}
    trials: dict[str, Any] = {}
    for name, by_mode in results.items():
        filters[name] = {mode: summarise(rows) for mode, rows in by_mode.items()}
        trials[name] = {
            mode: {r.trial: {**r.score.as_dict(), "samples_per_s": r.samples_per_s} for r in rows}
            for mode, rows in by_mode.items()
        }
    return {"filters": filters, "trials": trials, "units": {"angles": "deg RMSE", "speed": "samples/s"}}


def format_table(results: dict[str, dict[str, list[TrialResult]]], per_trial: bool = True) -> str:
    """Aligned text table: per-trial rows (optional) then group rows for each filter and mode."""
    header = ("filter", "mode", "trial / group", "total", "heading", "incl", "samples/s")
    rows: list[tuple[str, ...]] = []
    for name, by_mode in results.items():
        for mode, trial_rows in by_mode.items():
            if per_trial:
                for r in trial_rows:
                    s = r.score
                    rows.append((name, mode, r.trial, f"{s.total_deg:.2f}", f"{s.heading_deg:.2f}",
                                 f"{s.inclination_deg:.2f}", f"{r.samples_per_s:,.0f}"))
            for group, fig in summarise(trial_rows).items():
                rows.append((name, mode, f"[{group}]", f"{fig['total']:.2f}", f"{fig['heading']:.2f}",
                             f"{fig['inclination']:.2f}", f"{fig['samples_per_s']:,.0f}"))
    widths = [max(len(r[i]) for r in (header, *rows)) for i in range(len(header))]
    left = {0, 1, 2}

    def fmt(r: tuple[str, ...]) -> str:
        cells = zip(r, widths, strict=True)
        return "  ".join(c.ljust(w) if i in left else c.rjust(w) for i, (c, w) in enumerate(cells))

    lines = [fmt(header), "  ".join("-" * w for w in widths)]
    lines += [fmt(r) for r in rows]
    return "\n".join(lines)


CvTable = dict[str, dict[str, "tuning.CvResult | np.ndarray"]]


def run_cv(
    trials: Sequence[broad.Trial],
    names: Sequence[str],
    modes: Sequence[broad.Mode],
    with_vqf: bool,
    cache: tuning.ScoreCache,
    progress: bool = True,
) -> CvTable:
    """`{filter: {mode: CvResult}}` for tuned filters, plus `{"vqf": {mode: (n_trials, 3) scores}}` if asked."""
    out: CvTable = {}
    bar = tqdm(total=len(names) * len(modes), desc="cv", unit="filter", file=sys.stderr, disable=not progress)
    for name in names:
        for mode in modes:
            out.setdefault(name, {})[mode] = tuning.cross_validate(
                name, trials, mode, cache=cache, progress=bar.set_postfix_str if progress else None)
            bar.update()
    bar.close()
    if with_vqf:
        runner = vqf_runner()
        for mode in modes:

            def run_one(t: broad.Trial, m: broad.Mode = mode) -> FloatArray:
                res = runner(t, m)
                assert res is not None
                return res[0]

            out.setdefault(VQF_NAME, {})[mode] = tuning.untuned_scores(run_one, trials, mode)
    return out


def _rows(res: tuning.CvResult | np.ndarray, which: str) -> np.ndarray:
    if isinstance(res, np.ndarray):
        return res
    return res.loo if which == "loo" else res.in_sample


def _group_mean(rows: np.ndarray, groups: Sequence[tuple[str, ...]], group: str) -> np.ndarray:
    sel = [rows[j] for j, gs in enumerate(groups) if group == "all" or group in gs]
    return np.mean(sel, axis=0) if sel else np.full(3, np.nan)


def cv_to_json(cv: CvTable, trials: Sequence[broad.Trial]) -> dict[str, Any]:
    """`{"loo"|"in_sample": {filter: {mode: {group|trial: {total, heading, inclination}}}}, "choices": ...}`."""
    groups = [t.groups for t in trials]
    body: dict[str, Any] = {"loo": {}, "in_sample": {}, "choices": {}}
    for name, by_mode in cv.items():
        for mode, res in by_mode.items():
            for which in ("loo", "in_sample"):
                rows = _rows(res, which)
                d: dict[str, Any] = {}
                for g in ("all", *broad.GROUPS):
                    d[g] = dict(zip(("total", "heading", "inclination"), map(float, _group_mean(rows, groups, g)),
                                    strict=True))
                d["trials"] = {t.name: dict(zip(("total", "heading", "inclination"), map(float, r), strict=True))
                               for t, r in zip(trials, rows, strict=True)}
                body[which].setdefault(name, {})[mode] = d
            if isinstance(res, tuning.CvResult):
                body["choices"].setdefault(name, {})[mode] = {
                    "per_fold": [res.candidates[c] for c in res.loo_choice],
                    "in_sample": res.candidates[res.in_sample_choice],
                }
    body["units"] = {"angles": "deg RMSE"}
    return body


def format_cv(cv: CvTable, trials: Sequence[broad.Trial], per_trial: bool = True) -> str:
    """Group table (LOO and in-sample) per filter and mode; then, per trial, LOO total / inclination against VQF."""
    groups = [t.groups for t in trials]
    lines = ["leave-one-trial-out (gains chosen on the other trials; the figure to quote) and in-sample (chosen on all",
             "trials, scored on the same trials): mean RMSE in degrees over the trials",
             "",
             f"{'filter':14s} {'mode':4s}  {'LOO total':>9s} {'undist':>6s} {'dist':>6s} {'heading':>7s} {'incl':>6s}"
             f"  {'in-sample total':>15s} {'incl':>6s}  candidates"]
    for name, by_mode in cv.items():
        for mode, res in by_mode.items():
            loo, ins = _rows(res, "loo"), _rows(res, "in_sample")
            a, u, d = (_group_mean(loo, groups, g) for g in ("all", "undisturbed", "disturbed"))
            ia = _group_mean(ins, groups, "all")
            n_cand = len(res.candidates) if isinstance(res, tuning.CvResult) else 1
            lines.append(f"{name:14s} {mode:4s}  {a[0]:9.2f} {u[0]:6.2f} {d[0]:6.2f} {a[1]:7.2f} {a[2]:6.2f}"
                         f"  {ia[0]:15.2f} {ia[2]:6.2f}  {n_cand}")
    if per_trial and VQF_NAME in cv:
        for name, by_mode in cv.items():
            if name == VQF_NAME:
                continue
            for mode, res in by_mode.items():
                if mode not in cv[VQF_NAME]:
                    continue
                ref, loo = _rows(cv[VQF_NAME][mode], "loo"), _rows(res, "loo")
                lines += ["", f"{name} {mode}, LOO per trial against {VQF_NAME} (total, inclination; ratio of totals)"]
                for t, r, v in zip(trials, loo, ref, strict=True):
                    flag = "" if r[0] <= 1.1 * v[0] and r[2] < v[2] else "  <-"
                    lines.append(f"  {t.name[:44]:44s} {r[0]:6.2f} {r[2]:5.2f} | {v[0]:6.2f} {v[2]:5.2f}"
                                 f"  {r[0] / v[0]:5.2f}{flag}")
    return "\n".join(lines)


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="python -m gateway.fusion.evaluate",
        description="Score registered attitude filters on BROAD .mat recordings (RMSE in degrees over movement "
        "samples; groups are plain means of trial RMSEs). Data: BROAD, Laidig et al. 2021, CC BY 4.0.",
    )
    p.add_argument("data_dir", type=Path, help="folder of BROAD .mat files (trials.json beside them is optional)")
    p.add_argument("--filter", dest="filters", action="append", metavar="NAME",
                   help=f"registered filter to run (repeatable; default: all registered: {', '.join(sorted(FILTERS))})")
    p.add_argument("--mode", choices=("6D", "9D", "both"), default="both", help="6D (no magnetometer), 9D or both")
    p.add_argument("--trials", default="*.mat", metavar="GLOB", help="glob of trial files inside DATA_DIR")
    p.add_argument("--vqf", action="store_true", help="add pip vqf (defaults) as a reference row")
    p.add_argument("--json", action="store_true", help="print JSON instead of the table")
    p.add_argument("--groups-only", action="store_true", help="table: group rows only")
    p.add_argument("--no-progress", action="store_true", help="no progress bar on stderr")
    p.add_argument("--cv", action="store_true",
                   help="leave-one-trial-out figures for the tuned filters (default: all of "
                   f"{', '.join(tuning.SPECS)}); with --vqf, a per-trial comparison against VQF")
    p.add_argument("--cache", type=Path, metavar="FILE", help="--cv: keep candidate scores in this JSON file")
    return p


def main(argv: Sequence[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    paths = broad.find_trials(args.data_dir, args.trials)
    if not paths:
        print(f"no .mat files matching {args.trials!r} in {args.data_dir}", file=sys.stderr)
        return 2
    known = tuning.SPECS if args.cv else FILTERS
    names: list[str] = args.filters or list(known)
    unknown = [n for n in names if n not in known]
    if unknown:
        what = "tuned filter(s)" if args.cv else "filter(s)"
        print(f"unknown {what} {', '.join(unknown)}; known: {', '.join(sorted(known))}", file=sys.stderr)
        return 2
    runners: dict[str, Runner] = {n: registered_runner(n) for n in names}
    if args.vqf:
        runners[VQF_NAME] = vqf_runner()
    modes: tuple[broad.Mode, ...] = MODES if args.mode == "both" else (args.mode,)
    trials = [broad.load_trial(p) for p in tqdm(paths, desc="load", unit="trial", file=sys.stderr,
                                                disable=args.no_progress)]
    if args.cv:
        cv = run_cv(trials, names, modes, args.vqf, tuning.ScoreCache(args.cache), progress=not args.no_progress)
        print(json.dumps(cv_to_json(cv, trials), indent=1) if args.json else
              format_cv(cv, trials, per_trial=not args.groups_only))
        return 0
    results = evaluate(trials, runners, modes, progress=not args.no_progress)
    if args.json:
        print(json.dumps(to_json(results), indent=1))
    else:
        print(format_table(results, per_trial=not args.groups_only))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
