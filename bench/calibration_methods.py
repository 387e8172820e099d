"""Seed 004's calibration procedure against the gateway's fits, on the simulated calibration dance.

    python -m bench.calibration_methods [--seeds 1 2 3 4 5 6 7 8]

Each seed draws a raw (uncalibrated) MPU-6050 + HMC5883L board (`ImuErrorModel.uncalibrated()`), records the dance of
tests/test_calibrate.py (8 rest poses of 2 s, the first lying flat, then a 20 s slow tumble) into a `.rigrec`, reads it
back and calibrates it with `--method fit` and `--method paper`. Printed per method: the error terms left against
the simulator's own drawn errors (max over axes, then median and worst over the seeds) and the heading error the
left-over hard iron alone would cause across a 20 µT horizontal field.
"""

from __future__ import annotations

import argparse
import tempfile
from collections.abc import Sequence
from pathlib import Path

import numpy as np

from devices.common import ImuErrorModel
from gateway import calibrate
from gateway.recording.format import write_recording
from gateway.recording.importers import ImuStream, imu_records
from tests.test_calibrate import RATE_HZ, measured, residuals

H_FIELD_UT = 20.0


def main(argv: Sequence[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m bench.calibration_methods", description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)  # fmt: skip
    ap.add_argument("--seeds", type=int, nargs="+", default=list(range(1, 9)), help="board seeds (default 1-8)")
    args = ap.parse_args(argv)
    res: dict[str, list[dict[str, float]]] = {m: [] for m in calibrate.METHODS}
    with tempfile.TemporaryDirectory() as tmp:
        for seed in args.seeds:
            sensor, g, a, m = measured(seed, ImuErrorModel.uncalibrated())
            rec = Path(tmp) / f"dance-{seed}.rigrec"
            write_recording(rec, [r for *_, r in imu_records(ImuStream(RATE_HZ, g, a, m), "rod-1")])
            imu = calibrate.load_imu(rec)
            for method in calibrate.METHODS:
                cal = calibrate.fit_device(imu.gyr_rad_s, imu.acc_m_s2, imu.mag_uT, imu.rate_hz, method=method)
                res[method].append(residuals(sensor, cal))
            if seed == args.seeds[0]:
                print(f"`python -m gateway.calibrate dance-{seed}.rigrec --compare`:\n")
                print(calibrate.compare_table(imu, imu.mag_uT) + "\n")
    raw = res["fit"]
    raw_hi = np.median([r["raw_hard_iron_uT"] for r in raw])
    raw_ab = np.median([r["raw_acc_bias_m_s2"] for r in raw]) * 1e3
    print(f"raw board, median over seeds {args.seeds}: hard iron {raw_hi:.1f} µT, accel bias {raw_ab:.0f} mm/s²\n")
    print("| method | hard iron µT (median / worst) | heading from it ° | soft iron % | accel bias mm/s² "
          "| accel scale % |")
    print("|---|---|---|---|---|---|")
    for method, rs in res.items():
        def col(k: str, f: float = 1.0, rs: list[dict[str, float]] = rs) -> str:
            v = np.array([r[k] for r in rs]) * f
            return f"{np.median(v):.2f} / {v.max():.2f}"

        hi = np.array([r["hard_iron_uT"] for r in rs])
        head = np.degrees(np.arctan(hi / H_FIELD_UT))
        print(f"| {method} | {col('hard_iron_uT')} | {np.median(head):.2f} / {head.max():.2f} | "
              f"{col('soft_iron', 100)} | {col('acc_bias_m_s2', 1e3)} | {col('acc_scale', 100)} |")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
