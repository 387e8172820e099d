"""Semi-synthetic attached magnet: a constant body-frame field offset added to clean BROAD trials, 9D error printed.

A magnet fixed to the sensor adds the same vector in the body frame whatever the attitude (a hard-iron offset that
appears and disappears). It is added during 60 s of each undisturbed trial's motion (from 10 s after the motion
starts), one random direction per trial and size (seeded); the optical reference is unchanged, so the extra error is
the filter's. Small offsets change the field's norm and dip by less than the usual thresholds but turn its bearing.

    python -m bench.magnet_disturbance                      # VQF, default filter, previous defaults, bearing test
    python -m bench.magnet_disturbance --offsets 3 6 12 --data-dir ../shared/data/broad
"""

from __future__ import annotations

import argparse
from dataclasses import replace
from pathlib import Path

import numpy as np
from tqdm import tqdm

from gateway.fusion import broad
from gateway.fusion.default import DefaultFilter, DefaultSettings

DEFAULT_DATA = Path(__file__).resolve().parent.parent.parent / "shared" / "data" / "broad"
CONFIGS: dict[str, DefaultSettings | None] = {
    "VQF (defaults)": None,
    "default": DefaultSettings(),
    "default before issue 14": DefaultSettings(tau_mag_s=15.0, mag_heading_kf=False, acc_spike_m_s2=0.0),
    "default, mag_bearing_th_deg=4": DefaultSettings(mag_bearing_th_deg=4.0),
}


def with_magnet(
    trial: broad.Trial, offset_uT: float, rng: np.random.Generator, duration_s: float = 60.0
) -> broad.Trial:
    """The trial with `offset_uT` (random body direction) added from 10 s after the motion starts, for `duration_s`."""
    moving = np.flatnonzero(trial.movement)
    i0 = int(moving[0] + 10.0 * trial.rate_hz)
    i1 = int(min(i0 + duration_s * trial.rate_hz, moving[-1]))
    d = rng.normal(size=3)
    mag = trial.mag_uT.copy()
    mag[i0:i1] += offset_uT * d / np.linalg.norm(d)
    return replace(trial, mag_uT=mag)


def total_deg(trial: broad.Trial, settings: DefaultSettings | None) -> float:
    """9D total RMSE of VQF (settings None) or the default filter with `settings`."""
    if settings is None:
        from vqf import VQF

        q = VQF(trial.dt_s).updateBatch(trial.gyr_rad_s, trial.acc_m_s2, trial.mag_uT)["quat9D"]
    else:
        q = broad.run_filter(DefaultFilter(settings), trial, "9D")
    return broad.score(q, trial, "9D").total_deg


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m bench.magnet_disturbance", description=__doc__.split("\n")[0])
    p.add_argument("--data-dir", type=Path, default=DEFAULT_DATA, help="BROAD folder (default: ../shared/data/broad)")
    p.add_argument("--offsets", type=float, nargs="+", default=[3.0, 6.0, 12.0], help="offsets in µT (default 3 6 12)")
    p.add_argument("--seed", type=int, default=0)
    a = p.parse_args(argv)
    paths = [q for q in broad.find_trials(a.data_dir) if "undisturbed" in q.stem]
    if not paths:
        p.error(f"no undisturbed BROAD trials in {a.data_dir} (pass --data-dir)")
    rng = np.random.default_rng(a.seed)
    cases = [(off, with_magnet(broad.load_trial(path), off, rng)) for path in paths for off in a.offsets]
    errors: dict[str, dict[float, list[float]]] = {name: {off: [] for off in a.offsets} for name in CONFIGS}
    for off, trial in tqdm(cases, desc="trials", unit="case"):
        for name, settings in CONFIGS.items():
            errors[name][off].append(total_deg(trial, settings))
    print(f"9D total RMSE (deg), mean over {len(paths)} undisturbed trials [max], magnet on for 60 s of the motion")
    print(f"{'filter':32s}" + "".join(f"{f'{off:g} µT':>18s}" for off in a.offsets))
    for name, by_off in errors.items():
        cells = "".join(f"{np.mean(v):>10.2f} [{np.max(v):5.2f}]" for v in by_off.values())
        print(f"{name:32s}{cells}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
