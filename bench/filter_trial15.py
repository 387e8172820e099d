"""Why the default filter's inclination on BROAD trial 15 (fast translation) trails VQF's by ~0.006°: the figures of
docs/fusion.md, "Trial 15, second round".

    python -m bench.filter_trial15                                   # 9D, ../shared/data/broad
    python -m bench.filter_trial15 --mode 6D --cache /tmp/cv6.json   # reuse the LOO scores of an earlier run

Prints, from one run: (1) trial 15's gyro bias at motion onset against the mean gyro of its first rest; (2) each
trial's final gyro-scale estimate and its standard deviation (how well the trial's own motion observes the scale);
(3) the leave-one-trial-out figures with the scale carried over: gains chosen as in `tuning.cross_validate`, then the
held-out trial starts from the mean final scale the chosen filter reached on the other trials (no reference data,
nothing from the held-out trial), per trial against VQF; (4) inclination RMSE of ours and VQF's with the optical
reference shifted by whole samples (how much the IMU/optical timing alone moves the figure), and with the
accelerometer moved a sample against the gyro; also trial 15 (and 26, 30) started from other trials' final scales,
the tilt the accelerometer alone leaves after the low-pass, and where in trial 15 the excess error sits.
"""

from __future__ import annotations

import argparse
import dataclasses
from pathlib import Path

import numpy as np
from scipy.signal import butter, filtfilt, lfilter

from gateway.fusion import _default_kernels as K
from gateway.fusion import broad, tuning
from gateway.fusion import quaternion as quat
from gateway.fusion.base import FloatArray
from gateway.fusion.default import DefaultFilter, DefaultSettings

DEFAULT_DATA = Path(__file__).resolve().parent.parent.parent / "shared" / "data" / "broad"


def _vqf(trial: broad.Trial, mode: broad.Mode) -> FloatArray:
    from vqf import VQF

    out = VQF(trial.dt_s).updateBatch(trial.gyr_rad_s, trial.acc_m_s2, trial.mag_uT if mode == "9D" else None)
    return np.asarray(out["quat9D" if mode == "9D" else "quat6D"], dtype=np.float64)


def _run(f: DefaultFilter, trial: broad.Trial, mode: broad.Mode, scale: FloatArray | None = None) -> FloatArray:
    """`broad.run_filter`, optionally starting from a gyro-scale estimate (the kernel state's scale slots)."""
    acc, mag = broad.rest_means(trial)
    f.initialise(acc, mag if mode == "9D" else None)
    if scale is not None:
        f.state[K.S_SCALE : K.S_SCALE + 3] = scale
    return f.run(trial.gyr_rad_s, trial.acc_m_s2, trial.mag_uT if mode == "9D" else None, trial.dt_s)


def onset_bias(trial: broad.Trial) -> None:
    start = int(np.argmax(trial.movement))
    f = DefaultFilter(use_mag=False)
    _run(f, trial.slice(0, start), "6D")
    deg = np.rad2deg
    print(f"{trial.name}: bias at motion onset ({start * trial.dt_s:.1f} s) {np.round(deg(f.bias_rad_s), 4)} °/s; "
          f"mean gyro of the rest before it {np.round(deg(trial.gyr_rad_s[:start].mean(axis=0)), 4)} °/s")


def final_scale(spec: tuning.TuningSpec, params: tuning.Params, trial: broad.Trial,
                mode: broad.Mode) -> tuple[FloatArray, FloatArray]:
    """(scale estimate, its standard deviation) at the end of a cold run."""
    f = spec.make(params, mode)
    assert isinstance(f, DefaultFilter)
    _run(f, trial, mode)
    s = f.state
    return s[K.S_SCALE : K.S_SCALE + 3].copy(), np.sqrt([s[K.S_BIAS_P + 7 * (i + 3)] for i in range(3)])


def acc_only_tilt_deg(trial: broad.Trial, taus_s: tuple[float, ...]) -> tuple[list[float], float]:
    """RMS tilt (deg) that the horizontal specific force in the optical earth frame leaves after the filter's
    low-pass (what the inclination would see with a perfect gyro), and the horizontal acceleration RMS (m/s²)."""
    q = trial.quat_ref.copy()
    ok = np.all(np.isfinite(q), axis=1)
    q[: int(np.argmax(ok))] = q[int(np.argmax(ok))]
    for i in np.flatnonzero(~ok):  # hold the last good attitude through marker losses
        if i > 0:
            q[i] = q[i - 1]
    a_e = quat.rotate(q, trial.acc_m_s2)[:, :2]
    mask = trial.movement & ok
    out = []
    for tau in taus_s:
        c = np.zeros(5)
        K._butter2(tau, trial.dt_s, c, 0)
        lp = lfilter(c[:3], np.r_[1.0, c[3:]], a_e, axis=0)
        out.append(float(np.degrees(np.sqrt(np.mean((np.linalg.norm(lp[mask], axis=1) / K.GRAVITY_M_S2) ** 2)))))
    return out, float(np.sqrt(np.mean(np.sum(a_e[mask] ** 2, axis=1))))


def where_15_loses(trial: broad.Trial, mode: broad.Mode) -> None:
    """Share of the excess squared inclination error of the defaults (over tau_acc_s 2.0, over VQF) per quartile of
    the gyro rate (low-passed at 1 Hz, zero phase)."""
    def incl(q: FloatArray) -> FloatArray:
        return broad.error_angles(broad.error_quaternion(q, trial.quat_ref))[2]

    e = incl(_run(DefaultFilter(use_mag=mode == "9D"), trial, mode)) ** 2
    e20 = incl(_run(DefaultFilter(DefaultSettings(tau_acc_s=2.0), use_mag=mode == "9D"), trial, mode)) ** 2
    ev = incl(_vqf(trial, mode)) ** 2
    b, a = butter(2, 1.0 / (trial.rate_hz / 2))
    rate = np.degrees(filtfilt(b, a, np.linalg.norm(trial.gyr_rad_s, axis=1)))
    m = trial.movement & np.isfinite(e)
    edges = np.quantile(rate[m], [0, 0.25, 0.5, 0.75, 1])
    print(f"\n{trial.name}: share of the excess squared inclination error per gyro-rate quartile (°/s)")
    for lo, hi in zip(edges[:-1], edges[1:], strict=True):
        k = m & (rate >= lo) & (rate <= hi)
        print(f"  {lo:5.0f}-{hi:3.0f}: over tau 2.0 {(e[k] - e20[k]).sum() / (e[m] - e20[m]).sum():+.2f}, "
              f"over VQF {(e[k] - ev[k]).sum() / (e[m] - ev[m]).sum():+.2f}")


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m bench.filter_trial15", description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--data-dir", type=Path, default=DEFAULT_DATA, help="BROAD folder (default: ../shared/data/broad)")
    p.add_argument("--mode", choices=["6D", "9D"], default="9D")
    p.add_argument("--cache", type=Path, help="JSON cache of LOO scores (as `evaluate --cv --cache`)")
    a = p.parse_args(argv)
    mode: broad.Mode = a.mode
    trials = [broad.load_trial(x) for x in broad.find_trials(a.data_dir)]
    if not trials:
        p.error(f"no BROAD trials in {a.data_dir}")
    names = [t.name[:2] for t in trials]
    if "15" in names:
        onset_bias(trials[names.index("15")])

    spec = tuning.SPECS["default"]
    cv = tuning.cross_validate("default", trials, mode, spec, tuning.ScoreCache(a.cache))
    finals: dict[tuple[int, int], tuple[FloatArray, FloatArray]] = {}

    def final(c: int, i: int) -> tuple[FloatArray, FloatArray]:
        if (c, i) not in finals:
            finals[(c, i)] = final_scale(spec, cv.candidates[c], trials[i], mode)
        return finals[(c, i)]

    print("\nfinal gyro-scale estimate and its std (%) with the in-sample choice, cold start:")
    for i, t in enumerate(trials):
        k, sd = final(cv.in_sample_choice, i)
        print(f"  {t.name[:24]:<24} scale {np.round(100 * k, 2)}  std {np.round(100 * sd, 2)}")

    print(f"\n{mode} LOO, scale carried over from the other trials (total; inclination) against VQF:")
    warm = np.empty_like(cv.loo)
    ref = np.empty_like(cv.loo)
    for j, t in enumerate(trials):
        c = cv.loo_choice[j]
        prior = np.mean([final(c, i)[0] for i in range(len(trials)) if i != j], axis=0)
        f = spec.make(cv.candidates[c], mode)
        assert isinstance(f, DefaultFilter)
        s = broad.score(_run(f, t, mode, prior), t, mode)
        v = broad.score(_vqf(t, mode), t, mode)
        warm[j] = (s.total_deg, s.heading_deg, s.inclination_deg)
        ref[j] = (v.total_deg, v.heading_deg, v.inclination_deg)
        flag = "  inclination behind" if s.inclination_deg >= v.inclination_deg else ""
        print(f"  {t.name[:24]:<24} cold {cv.loo[j, 0]:.3f}; {cv.loo[j, 2]:.3f}  carried {s.total_deg:.3f}; "
              f"{s.inclination_deg:.3f}  VQF {v.total_deg:.3f}; {v.inclination_deg:.3f}  "
              f"ratio {s.total_deg / v.total_deg:.3f}{flag}")
    print(f"  mean: cold {cv.loo[:, 0].mean():.3f}; {cv.loo[:, 2].mean():.3f}  carried {warm[:, 0].mean():.3f}; "
          f"{warm[:, 2].mean():.3f}  VQF {ref[:, 0].mean():.3f}; {ref[:, 2].mean():.3f}; "
          f"worst ratio carried {np.max(warm[:, 0] / ref[:, 0]):.3f}")

    print("\nstarted from another trial's final scale (in-sample choice; total; inclination):")
    params = cv.candidates[cv.in_sample_choice]
    for name, sources in (("15", ("01", "04", "06", "08")), ("26", ("26",)), ("30", ("30",))):
        if name not in names or not all(x in names for x in sources):
            continue
        j = names.index(name)
        cells = []
        for src in ("cold", *sources):
            f = spec.make(params, mode)
            assert isinstance(f, DefaultFilter)
            start = None if src == "cold" else final(cv.in_sample_choice, names.index(src))[0]
            sc = broad.score(_run(f, trials[j], mode, start), trials[j], mode)
            cells.append(f"{src} {sc.total_deg:.3f}; {sc.inclination_deg:.3f}")
        print(f"  {trials[j].name[:24]:<24} " + "  ".join(cells))

    print("\ntilt from the accelerometer alone (optical attitude, horizontal specific force through the filter's "
          "low-pass), RMS over the scored samples at tau_acc_s 1.5 / 2 / 2.5 / 3.1 s; horizontal acceleration RMS:")
    for t in trials:
        tilt, a_h = acc_only_tilt_deg(t, (1.5, 2.0, 2.5, 3.1))
        print(f"  {t.name[:24]:<24} " + " / ".join(f"{x:.2f}" for x in tilt) + f"   {a_h:.1f} m/s²")

    if "15" in names:
        where_15_loses(trials[names.index("15")], mode)

    shifts = (-1, 0, 1, 2)
    print(f"\ninclination RMSE (ours in-sample defaults / VQF) against the reference shifted by {shifts} samples "
          "(+1: one sample earlier):")
    for t in trials:
        ours = _run(DefaultFilter(use_mag=mode == "9D"), t, mode)
        theirs = _vqf(t, mode)
        cells = []
        for k in shifts:
            shifted = dataclasses.replace(t, quat_ref=np.roll(t.quat_ref, k, axis=0))
            cells.append(f"{k:+d} {broad.score(ours, shifted, mode).inclination_deg:.3f}/"
                         f"{broad.score(theirs, shifted, mode).inclination_deg:.3f}")
        print(f"  {t.name[:24]:<24} " + "  ".join(cells))
    print("\ninclination RMSE (ours) with the accelerometer delayed (+1) / advanced (-1) one sample against the gyro:")
    for t in trials:
        cells = []
        for k in (-1, 0, 1):
            moved = dataclasses.replace(t, acc_m_s2=np.ascontiguousarray(np.roll(t.acc_m_s2, k, axis=0)))
            q = _run(DefaultFilter(use_mag=mode == "9D"), moved, mode)
            cells.append(f"{k:+d} {broad.score(q, t, mode).inclination_deg:.3f}")
        print(f"  {t.name[:24]:<24} " + "  ".join(cells))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
