"""Height over short windows on BROAD translation trials (seed 002 eq. 6-8): plain vs adaptive complementary filter.

    python -m gateway.recording.height_eval ../shared/data/broad                   # translation trials, 2 s windows
    python -m gateway.recording.height_eval rec/15_undisturbed_fast_translation_A.rigrec --window-s 1

Each filter runs 6D (gyro + accelerometer, as in the paper) from the first 0.5 s; the vertical position is then
integrated over consecutive windows of --window-s inside the movement samples, each started from the reference
height and vertical velocity (`gateway.fusion.height.window_errors`), and compared with `opt_pos` z at the
window's end. g is taken as the accelerometer sees it at rest (`gravity_from_rest`). Prints per trial and overall
the RMS and mean absolute end-of-window error (m) and the adaptive filter's cut of the RMS error.
Accepts BROAD .mat files, a folder of them, or imported .rigrec recordings (import_broad).
"""

from __future__ import annotations

import argparse
import json
import sys
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from tqdm import tqdm

from gateway.fusion import broad, height
from gateway.fusion.base import FloatArray
from gateway.fusion.registry import make_filter
from gateway.recording.format import SUFFIX, read_meta, read_recording

FILTERS: tuple[str, ...] = ("complementary", "adaptive")


@dataclass(frozen=True)
class WindowFigures:
    """End-of-window height errors (m) of one filter on one trial."""

    errors_m: FloatArray

    @property
    def rms_m(self) -> float:
        return float(np.sqrt(np.mean(self.errors_m**2))) if self.errors_m.size else float("nan")

    @property
    def mean_abs_m(self) -> float:
        return float(np.mean(np.abs(self.errors_m))) if self.errors_m.size else float("nan")


def height_windows(trial: broad.Trial, filter_name: str, window_s: float) -> WindowFigures:
    """Run the filter 6D over the trial and return its windowed height errors against opt_pos z."""
    q = broad.run_filter(make_filter(filter_name, use_mag=False), trial, "6D")
    k = max(1, int(round(broad.REST_WINDOW_S * trial.rate_hz)))
    g = height.gravity_from_rest(q[:k], trial.acc_m_s2[:k])
    e = height.window_errors(q, trial.acc_m_s2, trial.pos_m[:, 2], trial.dt_s, window_s, trial.movement, g)
    return WindowFigures(e)


def load(path: Path) -> broad.Trial:
    """A BROAD .mat trial or an imported recording rebuilt as a trial."""
    if path.suffix == SUFFIX:
        from gateway.recording.score import recorded_trial

        name = str(read_meta(path).get("trial", path.stem))
        return recorded_trial(read_recording(path), name).trial
    return broad.load_trial(path)


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="python -m gateway.recording.height_eval", description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)  # fmt: skip
    p.add_argument("source", type=Path, nargs="+", help="BROAD folder, .mat files or .rigrec recordings")
    p.add_argument("--trials", default="*translation*.mat", help="glob inside a folder (default: *translation*.mat)")
    p.add_argument("--window-s", type=float, default=2.0, help="window length in seconds (default: 2)")
    p.add_argument("--json", action="store_true", help="print JSON")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    return p


def main(argv: Sequence[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    paths: list[Path] = []
    for s in args.source:
        paths += broad.find_trials(s, args.trials) if s.is_dir() else [s]
    if not paths:
        print("no trials found", file=sys.stderr)
        return 2
    rows: dict[str, dict[str, WindowFigures]] = {}
    for p in tqdm(paths, desc="height", unit="trial", file=sys.stderr, disable=args.no_progress):
        trial = load(p)
        rows[trial.name] = {f: height_windows(trial, f, args.window_s) for f in FILTERS}
    allf = {f: WindowFigures(np.concatenate([r[f].errors_m for r in rows.values()])) for f in FILTERS}
    table = {**rows, "[all windows]": allf}

    def cut(r: dict[str, WindowFigures]) -> float:
        return 100.0 * (1.0 - r["adaptive"].rms_m / r["complementary"].rms_m)

    if args.json:
        print(json.dumps({name: {**{f: {"rms_m": r[f].rms_m, "mean_abs_m": r[f].mean_abs_m,
                                        "windows": int(r[f].errors_m.size)} for f in FILTERS},
                                 "adaptive_cut_pct": cut(r)} for name, r in table.items()}, indent=1))  # fmt: skip
        return 0
    print(f"height error at the end of {args.window_s:g} s windows vs opt_pos z (m), 6D filters, BROAD (CC BY 4.0)")
    print(f"{'trial':44s} {'windows':>7s} {'plain rms':>10s} {'plain |e|':>10s} {'adapt rms':>10s} "
          f"{'adapt |e|':>10s} {'cut':>6s}")  # fmt: skip
    for name, r in table.items():
        c, a = r["complementary"], r["adaptive"]
        print(f"{name[:44]:44s} {c.errors_m.size:7d} {c.rms_m:10.3f} {c.mean_abs_m:10.3f} {a.rms_m:10.3f} "
              f"{a.mean_abs_m:10.3f} {cut(r):5.1f}%")  # fmt: skip
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
