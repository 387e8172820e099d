"""Live height / heave (gateway.fusion.heave, seed 002 eq. 6-8) on BROAD translation trials and simulated hoisting.

    python -m bench.heave --broad ../shared/data/broad      # both parts
    python -m bench.heave                                   # simulated hoisting only

Attitude: the registered filter (`--filter`, default `default`, 9D) over the whole run, as the gateway runs it; the
heave estimator then runs over every sample with g seeded from the first 0.5 s, as the gateway's warm-up does.
Scores, per trial and per setting:
- `rms` of H against the reference height (relative to its first value) over the scored samples, beside `zero`, the
  rms of the reference itself (what always answering 0 m would score);
- `win` rms error of the height *change* over 2 s windows against the reference change, beside `ref`, the rms of
  the reference change (the part of short motions the estimate captures);
- rest %: share of the scored samples the rest detector held (on BROAD the scored samples are the moving ones).
Simulated hoisting: a calibrated board (`ImuErrorModel.calibrated()`, devices.common) on a hook load lifted 2 m in
4 s, held 6 s, lowered 2 m in 4 s, held 6 s, three times, with a 2° / 0.5 Hz sway; with and without a 2 cm-noise
depth sensor at 10 Hz (the load hanging under water, depth = −height).
"""

from __future__ import annotations

import argparse
from collections.abc import Sequence
from dataclasses import replace
from pathlib import Path

import numpy as np

from gateway.fusion import broad, heave, height
from gateway.fusion.base import FloatArray
from gateway.fusion.registry import make_filter

TRANSLATION = "*translation*.mat"
NEVER = float("inf")
SETTINGS: dict[str, heave.HeaveSettings] = {
    "free (no rest, no high-pass)": heave.HeaveSettings(rest_gyr_rad_s=0.0, leak_after_s=NEVER),
    "rest only": heave.HeaveSettings(leak_after_s=NEVER),
    "default (rest; high-pass after 10 s free)": heave.HeaveSettings(),
    "rest + high-pass always": heave.HeaveSettings(leak_after_s=0.0),
}


def scores(h: FloatArray, at_rest: FloatArray, ref: FloatArray, ok: FloatArray, rate_hz: float,
           window_s: float = 2.0) -> tuple[float, float, float, float, float]:  # fmt: skip
    """(rms, zero, win, ref, rest %) as in the module docstring."""
    e = h - ref
    idx = np.flatnonzero(ok)
    w = int(round(window_s * rate_hz))
    good = (idx[w:] - idx[:-w]) == w
    d_est = (h[idx[w:]] - h[idx[:-w]])[good]
    d_ref = (ref[idx[w:]] - ref[idx[:-w]])[good]
    return (float(np.sqrt(np.mean(e[ok] ** 2))), float(np.sqrt(np.mean(ref[ok] ** 2))),
            float(np.sqrt(np.mean((d_est - d_ref) ** 2))), float(np.sqrt(np.mean(d_ref**2))),
            float(100 * at_rest[ok].mean()))  # fmt: skip


def _row(name: str, setting: str, s: tuple[float, float, float, float, float]) -> str:
    return f"| {name} | {setting} | {s[0]:.3f} | {s[1]:.3f} | {s[2]:.3f} | {s[3]:.3f} | {s[4]:.0f} |"


HEADER = ("| run | setting | rms m | zero m | win m | ref m | rest % |\n"
          "|---|---|---|---|---|---|---|")  # fmt: skip


PACKET = 10  # samples per packet, as the gateway's fleet bench sends them


def fused_as_gateway(filter_name: str, gyr: FloatArray, acc: FloatArray, mag: FloatArray | None, dt_s: float,
                     k_rest: int) -> tuple[FloatArray, FloatArray]:  # fmt: skip
    """Quaternions and the gyro rates the gateway's heave sees: the filter fed packet by packet (`PACKET` samples),
    each packet's rates less the filter's gyro bias estimate as it stood before the packet (`FusionBank.bias`, as
    `gateway.kinds.base.heave_rows` is given it); raw rates for a filter without one. Initialised on the first
    `k_rest` samples."""
    f = make_filter(filter_name, use_mag=mag is not None)
    f.initialise(acc[:k_rest].mean(axis=0), mag[:k_rest].mean(axis=0) if mag is not None else None)
    q, seen = np.empty((gyr.shape[0], 4)), gyr.copy()
    for a in range(0, gyr.shape[0], PACKET):
        b = a + PACKET
        bias = getattr(f, "bias_rad_s", None)
        if bias is not None:
            seen[a:b] -= np.asarray(bias, dtype=float)
        q[a:b] = f.run(gyr[a:b], acc[a:b], None if mag is None else mag[a:b], dt_s)
    return q, seen


def broad_rows(data_dir: Path, filter_name: str) -> list[str]:
    rows = []
    for path in broad.find_trials(data_dir, TRANSLATION):
        t = broad.load_trial(path)
        k = int(broad.REST_WINDOW_S * t.rate_hz)
        q, gyr = fused_as_gateway(filter_name, t.gyr_rad_s, t.acc_m_s2, t.mag_uT, t.dt_s, k)
        g = height.gravity_from_rest(q[:k], t.acc_m_s2[:k])
        z = t.pos_m[:, 2]
        ref = z - z[np.isfinite(z)][0]
        ok = np.isfinite(z) & t.movement
        for label, s in SETTINGS.items():
            out = heave.run_heave(q, gyr, t.acc_m_s2, t.dt_s, replace(s, gravity_m_s2=g))
            rows.append(_row(t.name[:2], label, scores(out[:, 0], out[:, 2], ref, ok, t.rate_hz)))
    return rows


def hoist(seed: int, rate_hz: float = 100.0) -> dict[str, FloatArray]:
    """True height (m), body rate, specific force, field and quaternion of the simulated hoisting run."""
    from devices import _quat
    from devices.common import field_body, specific_force_body

    dt = 1.0 / rate_hz
    prof: list[FloatArray] = [np.zeros(int(3 * rate_hz))]
    for _ in range(3):
        for sign in (1.0, -1.0):
            u = np.arange(int(4 * rate_hz)) / (4 * rate_hz)
            base = 0.0 if sign > 0 else 2.0
            prof.append(base + sign * 2.0 * (u - np.sin(2 * np.pi * u) / (2 * np.pi)))  # smooth 2 m move
            prof.append(np.full(int(6 * rate_hz), base + sign * 2.0))
    z = np.concatenate(prof)
    n = z.shape[0]
    t = np.arange(n) * dt
    rng = np.random.default_rng(seed)
    sway = np.radians(2.0) * np.sin(2 * np.pi * 0.5 * t + rng.uniform(0, 2 * np.pi))
    moving = np.abs(np.gradient(z, dt)) > 1e-6
    sway = np.where(moving, sway, 0.0)  # the load sways while it moves, hangs still when held
    yaw = np.radians(30.0)
    q = _quat.multiply(np.array([np.cos(yaw / 2), 0, 0, np.sin(yaw / 2)]),
                       np.stack([np.cos(sway / 2), np.sin(sway / 2), np.zeros(n), np.zeros(n)], axis=1))
    rel = _quat.multiply(_quat.conjugate(q[:-1]), q[1:])
    gyr = np.vstack([2 * rel[:, 1:] / dt, np.zeros((1, 3))])
    a_earth = np.zeros((n, 3))
    a_earth[:, 2] = np.gradient(np.gradient(z, dt), dt)
    return {"z": z, "gyr": gyr, "acc": specific_force_body(q, a_earth), "mag": field_body(q), "dt": np.array(dt)}


def sim_rows(filter_name: str, seeds: Sequence[int]) -> list[str]:
    from devices.common import ImuErrorModel, SensorModel

    rows = []
    for seed in seeds:
        d = hoist(seed)
        dt = float(d["dt"])
        rng = np.random.default_rng(100 + seed)
        g, a, m = SensorModel(ImuErrorModel.calibrated(), 1, rng).measure(d["gyr"], d["acc"], d["mag"], dt)
        k = int(0.5 / dt)
        q, gyr = fused_as_gateway(filter_name, g, a, m, dt, k)
        g0 = height.gravity_from_rest(q[:k], a[:k])
        ok = np.ones(d["z"].shape[0], dtype=bool)
        depth = np.full(ok.shape[0], np.nan)
        depth[:: int(0.1 / dt)] = -d["z"][:: int(0.1 / dt)] + 3.0 + rng.normal(0, 0.02, depth[:: int(0.1 / dt)].shape)
        runs = {**SETTINGS, "default + depth sensor (10 Hz, 2 cm)": heave.HeaveSettings()}
        for label, s in runs.items():
            dep = depth if "depth" in label else None
            out = heave.run_heave(q, gyr, a, dt, replace(s, gravity_m_s2=g0), dep)
            h = out[:, 0] + (3.0 if dep is not None else 0.0)  # depth-aided height is −depth: 3 m below the start
            rows.append(_row(f"hoist seed {seed}", label, scores(h, out[:, 2], d["z"], ok, 1.0 / dt)))
    return rows


def main(argv: Sequence[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="python -m bench.heave", description=__doc__,
                                 formatter_class=argparse.RawDescriptionHelpFormatter)  # fmt: skip
    ap.add_argument("--broad", type=Path, default=None, help="BROAD folder (translation trials are scored)")
    ap.add_argument("--filter", default="default", help="registered attitude filter (default: default)")
    ap.add_argument("--seeds", type=int, nargs="+", default=[1, 2, 3], help="simulation seeds (default 1 2 3)")
    args = ap.parse_args(argv)
    print(HEADER)
    if args.broad is not None:
        print("\n".join(broad_rows(args.broad, args.filter)))
    print("\n".join(sim_rows(args.filter, args.seeds)))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
