"""Seed 000's Simulink study (eq. 46, Table 1, Figs. 10-12) reproduced: single-loop vs cascade PID step responses.

Run `python -m gateway.control.paper_study --help`. Two independent computations are made for each case:

* **continuous**: the closed loop built by transfer-function algebra and stepped with scipy (the Simulink model
  with a continuous PID block, derivative D·s/(T_f s + 1), T_f = 1/N, N = 100 as Simulink's default);
* **sampled**: the shipped `Pid`/`Cascade` classes driving the exact-ZOH plant (`plants.LtiPlant`) at `--dt`.

Loop structures (u = plant input, y = angle, ω = ẏ measured by an ideal gyro, see `plants.py`):

    single:   u = F_a·r − C_a·y
    cascade:  ω_ref = F_a·r − C_a·y,   u = F_r·ω_ref − C_r·ω

with C = kp + ki/s + kd·s/(T_f s + 1) and F = C (derivative on error, Simulink) or F = kp + ki/s (derivative on
measurement, our default). Closed loop (cascade): Y/R = G F_r F_a / (1 + G F_r C_a + G C_r s).

Metrics: rise time 10-90 %, settling time to within 2 % of the final value (and staying there), overshoot %.
The gain search is a grid over the cascade gains on the continuous model; among the points that meet the
paper's claims (rise ≤ 0.035 s, settling ≤ 0.1 s, overshoot < 10 %) it keeps the one with the smallest peak
actuator command |u| for a unit step, since any claim is met by large enough gains on an unlimited actuator.
"""

from __future__ import annotations

import argparse
import itertools
import json
import math
from collections.abc import Sequence
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import Literal

import numpy as np
from numpy.polynomial import polynomial as npp
from numpy.typing import NDArray
from scipy import signal
from tqdm import tqdm

from gateway.control.cascade import Cascade, CascadeSettings
from gateway.control.pid import Pid, PidSettings
from gateway.control.plants import PAPER_PLANTS, LtiPlant, TransferFunction

FloatArray = NDArray[np.float64]
Gains = tuple[float, float, float]
Structure = Literal["single", "cascade"]
DerivativeOn = Literal["measurement", "error"]

TABLE1: dict[str, tuple[Gains, Gains]] = {
    # axis: ((angle P, I, D), (rate P, I, D)), seed 000 Table 1
    "pitch": ((4.5, 3.5, 0.1), (2.6, 0.01, 0.001)),
    "roll": ((4.5, 3.5, 0.1), (2.2, 0.01, 0.001)),
    "yaw": ((0.8, 0.15, 0.12), (0.3, 0.35, 0.001)),
}
CLAIM_RISE_S = 0.03
CLAIM_SETTLING_S = 0.1
CLAIM_OVERSHOOT_PCT = 10.0
ACCEPT_RISE_S = 0.035  # "≈ 0.03 s" read as ≤ 0.035 s
SIMULINK_N = 100.0  # Simulink PID block's default derivative filter coefficient, T_f = 1/N


@dataclass(frozen=True)
class StepMetrics:
    """Step-response figures; nan when the response never gets there within the horizon."""

    rise_s: float
    settling_s: float
    overshoot_pct: float
    final: float
    peak_u: float = math.nan

    def meets_claims(self) -> bool:
        """Rise ≤ 0.035 s, settling ≤ 0.1 s, overshoot < 10 % (the paper's claims, with ≈ read as +17 %)."""
        return (
            self.rise_s <= ACCEPT_RISE_S
            and self.settling_s <= CLAIM_SETTLING_S
            and self.overshoot_pct < CLAIM_OVERSHOOT_PCT
        )


def step_metrics(t_s: FloatArray, y: FloatArray, ref: float = 1.0, band: float = 0.02) -> StepMetrics:
    """Rise time 10-90 % of `ref`, settling time into ±`band`·ref, overshoot % of `ref` (linear interpolation)."""

    def crossing(level: float) -> float:
        idx = np.flatnonzero(y >= level)
        if idx.size == 0:
            return math.nan
        i = int(idx[0])
        if i == 0:
            return float(t_s[0])
        frac = (level - y[i - 1]) / (y[i] - y[i - 1])
        return float(t_s[i - 1] + frac * (t_s[i] - t_s[i - 1]))

    rise = crossing(0.9 * ref) - crossing(0.1 * ref)
    outside = np.flatnonzero(np.abs(y - ref) > band * abs(ref))
    if outside.size == 0:
        settling = float(t_s[0])
    elif outside[-1] + 1 >= y.size:
        settling = math.nan
    else:
        settling = float(t_s[outside[-1] + 1])
    overshoot = max(0.0, (float(np.max(y)) - ref) / abs(ref) * 100.0)
    return StepMetrics(rise, settling, overshoot, float(y[-1]))


# ---------------------------------------------------------------- continuous model (transfer-function algebra)
Rational = tuple[FloatArray, FloatArray]  # (num, den), coefficients lowest power first (numpy.polynomial)


def _pid_tf(g: Gains, tf_s: float, with_d: bool) -> Rational:
    """kp + ki/s + kd·s/(T_f s + 1) as num/den, lowest power first."""
    kp, ki, kd = g
    # common denominator s·(T_f s + 1)
    den = np.array([0.0, 1.0, tf_s])
    num = npp.polyadd(npp.polymul([ki, kp], [1.0, tf_s]), [0.0, 0.0, kd] if with_d else [0.0])
    return np.asarray(num, float), den


def _mul(a: Rational, b: Rational) -> Rational:
    return np.asarray(npp.polymul(a[0], b[0]), np.float64), np.asarray(npp.polymul(a[1], b[1]), np.float64)


def _add(a: Rational, b: Rational) -> Rational:
    num = npp.polyadd(npp.polymul(a[0], b[1]), npp.polymul(b[0], a[1]))
    return np.asarray(num, np.float64), np.asarray(npp.polymul(a[1], b[1]), np.float64)


def closed_loop(
    plant: TransferFunction, structure: Structure, angle: Gains, rate: Gains | None, tf_s: float, d_on: DerivativeOn
) -> tuple[Rational, Rational]:
    """(Y/R, U/R) of the single or cascade loop, as rationals lowest power first."""
    g: Rational = (np.asarray(plant.num[::-1], float), np.asarray(plant.den[::-1], float))
    c_a = _pid_tf(angle, tf_s, True)
    f_a = _pid_tf(angle, tf_s, d_on == "error")
    one: Rational = (np.array([1.0]), np.array([1.0]))
    if structure == "single":
        forward, loop = f_a, c_a  # U = F_a R − C_a Y
        y_r_num = _mul(g, forward)
        char = _add(one, _mul(g, loop))
        yr = _mul(y_r_num, (char[1], char[0]))
        ur = _mul(forward, (char[1], char[0]))
        return yr, ur
    if rate is None:
        raise ValueError("cascade needs rate gains")
    c_r = _pid_tf(rate, tf_s, True)
    f_r = _pid_tf(rate, tf_s, d_on == "error")
    s: Rational = (np.array([0.0, 1.0]), np.array([1.0]))
    forward = _mul(f_r, f_a)
    char = _add(one, _add(_mul(g, _mul(f_r, c_a)), _mul(g, _mul(c_r, s))))
    inv_char: Rational = (char[1], char[0])
    return _mul(_mul(g, forward), inv_char), _mul(forward, inv_char)


def _to_lti(r: Rational) -> signal.lti:
    num, den = np.trim_zeros(r[0][::-1], "f"), np.trim_zeros(r[1][::-1], "f")
    scale = den[0]
    return signal.lti(num / scale, den / scale)


def continuous_step(
    plant: TransferFunction,
    structure: Structure,
    angle: Gains,
    rate: Gains | None,
    *,
    tf_s: float = 1.0 / SIMULINK_N,
    d_on: DerivativeOn = "error",
    horizon_s: float = 3.0,
    n: int = 30001,
) -> tuple[FloatArray, FloatArray, StepMetrics]:
    """Unit-step response of the continuous closed loop: (t_s, y, metrics incl. peak |u| after t = 0⁺)."""
    yr, ur = closed_loop(plant, structure, angle, rate, tf_s, d_on)
    t = np.linspace(0.0, horizon_s, n)
    _, y = signal.step(_to_lti(yr), T=t)
    _, u = signal.step(_to_lti(ur), T=t)
    y = np.asarray(y, float)
    m = step_metrics(t, y)
    return t, y, StepMetrics(m.rise_s, m.settling_s, m.overshoot_pct, m.final, float(np.max(np.abs(u))))


# ---------------------------------------------------------------- sampled simulation with the shipped controllers
def sampled_step(
    plant: TransferFunction,
    structure: Structure,
    angle: Gains,
    rate: Gains | None,
    *,
    tf_s: float = 1.0 / SIMULINK_N,
    d_on: DerivativeOn = "error",
    horizon_s: float = 3.0,
    dt_s: float = 1e-4,
) -> tuple[FloatArray, FloatArray, StepMetrics]:
    """Unit step at t = 0 through `Pid` (single) or `Cascade` on the exact-ZOH plant; returns (t_s, y, metrics)."""
    sim = LtiPlant(plant, dt_s)

    def pid(g: Gains) -> PidSettings:
        return PidSettings(g[0], g[1], g[2], derivative_filter_s=tf_s, derivative_on=d_on)

    n = int(round(horizon_s / dt_s)) + 1
    t = np.arange(n, dtype=np.float64) * dt_s
    y = np.empty(n)
    peak_u = 0.0
    single = Pid(pid(angle))
    cascade = Cascade(CascadeSettings(pid(angle), pid(rate if rate is not None else (1.0, 0.0, 0.0))))
    # Prime the derivative memories at rest (r = y = 0) so the step at t = 0 is seen as a change.
    for p in (single, cascade.outer, cascade.inner):
        p.state.last_input = 0.0
    for k in range(n):
        y[k] = sim.output
        if structure == "single":
            u = single.update(1.0, y[k], dt_s)
        else:
            u = cascade.update(1.0, y[k], sim.output_rate(), dt_s)
        peak_u = max(peak_u, abs(u))
        sim.step(u)
    m = step_metrics(t, y)
    return t, y, StepMetrics(m.rise_s, m.settling_s, m.overshoot_pct, m.final, peak_u)


# ---------------------------------------------------------------- gain search
@dataclass(frozen=True)
class SearchGrid:
    """Cascade gain grid (outer kp, ki, kd × inner kp, ki, kd); inner kd and ki kept at Table 1's order."""

    outer_kp: tuple[float, ...] = (20.0, 30.0, 40.0, 50.0, 60.0, 80.0, 100.0)
    outer_ki: tuple[float, ...] = (0.0, 3.5, 10.0)
    outer_kd: tuple[float, ...] = (0.0, 0.1)
    inner_kp: tuple[float, ...] = (0.2, 0.3, 0.5, 1.0, 2.6, 5.0)
    inner_ki: tuple[float, ...] = (0.01,)
    inner_kd: tuple[float, ...] = (0.001,)


def search_gains(
    plant: TransferFunction, grid: SearchGrid, *, d_on: DerivativeOn = "measurement", progress: bool = True
) -> tuple[tuple[Gains, Gains] | None, int, int]:
    """Least-effort cascade gains meeting the claims on the continuous model: (gains or None, n_ok, n_tried)."""
    best: tuple[float, tuple[Gains, Gains]] | None = None
    points = list(
        itertools.product(grid.outer_kp, grid.outer_ki, grid.outer_kd, grid.inner_kp, grid.inner_ki, grid.inner_kd)
    )
    n_ok = 0
    for okp, oki, okd, ikp, iki, ikd in tqdm(points, desc="gain search", disable=not progress, leave=False):
        gains: tuple[Gains, Gains] = ((okp, oki, okd), (ikp, iki, ikd))
        try:
            _, _, m = continuous_step(plant, "cascade", *gains, d_on=d_on, horizon_s=1.0, n=2001)
        except (ValueError, np.linalg.LinAlgError):
            continue
        if m.meets_claims() and abs(m.final - 1.0) < 0.02:
            n_ok += 1
            if best is None or m.peak_u < best[0]:
                best = (m.peak_u, gains)
    return (best[1] if best else None), n_ok, len(points)


# ---------------------------------------------------------------- the study
@dataclass(frozen=True)
class Row:
    """One line of the results table."""

    axis: str
    case: str
    angle: Gains
    rate: Gains | None
    model: str
    metrics: StepMetrics


def run_study(
    axes: Sequence[str], *, d_on: DerivativeOn, dt_s: float, horizon_s: float, search: bool, progress: bool
) -> tuple[list[Row], dict[str, dict[str, float]], dict[str, tuple[FloatArray, FloatArray, str]]]:
    """All rows (continuous + sampled), search statistics per axis, and curves keyed by label for the plot."""
    rows: list[Row] = []
    curves: dict[str, tuple[FloatArray, FloatArray, str]] = {}
    stats: dict[str, dict[str, float]] = {}
    searched: dict[TransferFunction, tuple[tuple[Gains, Gains] | None, int, int]] = {}
    for axis in tqdm(axes, desc="axes", disable=not progress):
        plant = PAPER_PLANTS[axis]
        angle, rate = TABLE1[axis]
        cases: list[tuple[str, Structure, Gains, Gains | None, DerivativeOn]] = [
            ("table1 single", "single", angle, None, d_on),
            ("table1 cascade", "cascade", angle, rate, d_on),
        ]
        if search:
            if plant not in searched:  # pitch and roll share G1 = G2
                searched[plant] = search_gains(plant, SearchGrid(), d_on="measurement", progress=progress)
            tuned, n_ok, n_tried = searched[plant]
            stats[axis] = {"grid_points": n_tried, "meeting_claims": n_ok}
            if tuned is not None:
                cases.append(("tuned cascade", "cascade", tuned[0], tuned[1], "measurement"))
        for label, structure, a, r, don in cases:
            _, _, mc = continuous_step(plant, structure, a, r, d_on=don, horizon_s=horizon_s)
            rows.append(Row(axis, label, a, r, "continuous", mc))
            t, y, ms = sampled_step(plant, structure, a, r, d_on=don, horizon_s=horizon_s, dt_s=dt_s)
            rows.append(Row(axis, label, a, r, f"sampled dt={dt_s:g}", ms))
            curves[f"{axis}: {label}"] = (t, y, axis)
    return rows, stats, curves


def format_table(rows: Sequence[Row]) -> str:
    """Markdown table, with the paper's claim for the cascade on top."""

    def f(x: float, unit: str = "") -> str:
        return "not within horizon" if math.isnan(x) else f"{x:.3f}{unit}"

    out = [
        "| axis | case | model | angle PID | rate PID | rise 10-90% (s) | settling 2% (s) | overshoot % | peak u |",
        "|---|---|---|---|---|---|---|---|---|",
        f"| (paper) | cascade claim | Simulink | Table 1 | Table 1 | ≈ {CLAIM_RISE_S} | ≈ {CLAIM_SETTLING_S} "
        f"| < {CLAIM_OVERSHOOT_PCT:.0f} | - |",
    ]
    for r in rows:
        m = r.metrics
        out.append(
            f"| {r.axis} | {r.case} | {r.model} | {r.angle} | {r.rate if r.rate else '-'} | {f(m.rise_s)} "
            f"| {f(m.settling_s)} | {m.overshoot_pct:.1f} | {m.peak_u:.3g} |"
        )
    return "\n".join(out)


def save_plot(curves: dict[str, tuple[FloatArray, FloatArray, str]], path: Path, axes: Sequence[str]) -> None:
    """One panel per axis with every case's unit-step response (matplotlib, Agg backend)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, panels = plt.subplots(len(axes), 1, figsize=(8, 3 * len(axes)), squeeze=False)
    for ax_name, panel in zip(axes, panels[:, 0], strict=True):
        for label, (t, y, axis) in curves.items():
            if axis == ax_name:
                panel.plot(t, y, label=label.split(": ", 1)[1])
        panel.axhline(1.0, color="k", lw=0.5)
        panel.axhspan(0.98, 1.02, color="g", alpha=0.1)
        panel.set_xscale("symlog", linthresh=0.1)
        panel.set_xlim(0.0, max(float(c[0][-1]) for c in curves.values()))
        panel.set_title(f"{ax_name}: unit step (x axis linear to 0.1 s, log beyond)")
        panel.set_xlabel("t (s)")
        panel.set_ylabel("angle (rad)")
        panel.legend(fontsize=8)
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main(argv: Sequence[str] | None = None) -> int:
    """CLI entry: print the table (or JSON) and save the plot."""
    ap = argparse.ArgumentParser(prog="python -m gateway.control.paper_study", description=__doc__.split("\n")[0])
    ap.add_argument("--axes", nargs="+", default=["pitch", "roll", "yaw"], choices=sorted(PAPER_PLANTS))
    ap.add_argument(
        "--derivative-on",
        choices=["error", "measurement"],
        default="error",
        help="derivative path for the Table 1 runs (Simulink PID block default: error)",
    )
    ap.add_argument("--dt", type=float, default=1e-4, help="step of the sampled simulation in s (default 1e-4)")
    ap.add_argument("--horizon", type=float, default=5.0, help="simulated time in s (default 5)")
    ap.add_argument("--no-search", action="store_true", help="skip the gain search")
    ap.add_argument("--plot", type=Path, default=Path("bench-output/paper_study.png"), help="PNG path")
    ap.add_argument("--json", action="store_true", help="print machine-readable results instead of the table")
    ap.add_argument("--quiet", action="store_true", help="no progress bars")
    args = ap.parse_args(argv)
    rows, stats, curves = run_study(
        args.axes,
        d_on=args.derivative_on,
        dt_s=args.dt,
        horizon_s=args.horizon,
        search=not args.no_search,
        progress=not args.quiet,
    )
    save_plot(curves, args.plot, args.axes)
    if args.json:
        print(json.dumps({"rows": [asdict(r) for r in rows], "search": stats, "plot": str(args.plot)}, indent=1))
    else:
        print(format_table(rows))
        for axis, st in stats.items():
            print(f"search {axis}: {st['meeting_claims']} of {st['grid_points']} grid points meet the claims")
        print(f"plot: {args.plot}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
