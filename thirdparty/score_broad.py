#!/usr/bin/env python3
"""Score attitudes received from the gateway (written by broad_device.py) against BROAD's optical reference.

Error definitions are BROAD's (data README): q_err = q_est ⊗ q_ref* in the earth frame, total 2·acos|w|,
heading 2·atan(|z|/|w|), inclination 2·acos√(w²+z²); RMSE over the trial's `movement` samples where the
reference is finite. Frames: BROAD's `opt_quat` is body -> ENU (README: "relative to an East-North-Up
frame"), the gateway's `quat_wxyz` is body -> ENU (protocol.md: "rotating body-frame vectors into ENU"), and
the device sends the BROAD IMU axes unchanged as its body axes, so q_est and q_ref are compared directly.
The inclination error only uses the vertical (the gravity direction) of both frames: it is the angle between
the world up vector seen in the estimated and in the true body frame, R_est^T e_z vs R_ref^T e_z, and does
not depend on heading. Also reported: the angle between the body z axes in the world frame, R_est e_z vs
R_ref e_z (NOT heading-free: a heading error moves a tilted body z), and the total error after removing one
constant heading offset per trial (fitted to minimise the total RMSE, as BROAD does for 6D).

`att` rows: the per-packet `gw/{kind}/{id}/attitude` (last sample of each packet);
`block` rows: every sample from `gw/{kind}/{id}/attitude/block` (if the gateway ran with --attitude-blocks).
"""
from __future__ import annotations

import argparse
import json
import sys

import numpy as np
import scipy.io
from scipy.optimize import minimize_scalar


def qmul(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    w1, x1, y1, z1 = a.T
    w2, x2, y2, z2 = b.T
    return np.stack([
        w1 * w2 - x1 * x2 - y1 * y2 - z1 * z2,
        w1 * x2 + x1 * w2 + y1 * z2 - z1 * y2,
        w1 * y2 - x1 * z2 + y1 * w2 + z1 * x2,
        w1 * z2 + x1 * y2 - y1 * x2 + z1 * w2,
    ], axis=1)


def conj(q: np.ndarray) -> np.ndarray:
    return q * np.array([1.0, -1.0, -1.0, -1.0])


def rot_z_col(q: np.ndarray) -> np.ndarray:
    """Third column of R(q): the body z axis in the world frame."""
    w, x, y, z = q.T
    return np.stack([2 * (x * z + w * y), 2 * (y * z - w * x), 1 - 2 * (x * x + y * y)], axis=1)


def rot_z_row(q: np.ndarray) -> np.ndarray:
    """Third row of R(q): the world up vector in the body frame."""
    w, x, y, z = q.T
    return np.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], axis=1)


def angle(u: np.ndarray, v: np.ndarray) -> np.ndarray:
    c = np.sum(u * v, axis=1) / (np.linalg.norm(u, axis=1) * np.linalg.norm(v, axis=1))
    return np.arccos(np.clip(c, -1.0, 1.0))


def rmse_deg(x: np.ndarray) -> float:
    return float(np.degrees(np.sqrt(np.mean(x ** 2))))


def errors(q_est: np.ndarray, q_ref: np.ndarray) -> dict | None:
    if len(q_est) == 0:
        return None
    q_est = q_est / np.linalg.norm(q_est, axis=1, keepdims=True)
    q_ref = q_ref / np.linalg.norm(q_ref, axis=1, keepdims=True)
    e = qmul(q_est, conj(q_ref))
    w, z = e[:, 0], e[:, 3]
    total = 2 * np.arccos(np.clip(np.abs(w), 0, 1))
    heading = 2 * np.arctan2(np.abs(z), np.abs(w))
    incl = 2 * np.arccos(np.clip(np.sqrt(w * w + z * z), 0, 1))
    incl_vec = angle(rot_z_row(q_est), rot_z_row(q_ref))
    bodyz_world = angle(rot_z_col(q_est), rot_z_col(q_ref))

    def total_after(delta: float) -> float:  # earth-frame heading offset removed: q_z(-δ) ⊗ e
        wd = np.cos(delta / 2) * w + np.sin(delta / 2) * z
        return float(np.mean((2 * np.arccos(np.clip(np.abs(wd), 0, 1))) ** 2))

    grid = np.radians(np.arange(-180, 180, 1.0))
    d0 = grid[int(np.argmin([total_after(d) for d in grid]))]
    res = minimize_scalar(total_after, bounds=(d0 - 0.02, d0 + 0.02), method="bounded")
    return {
        "n": int(len(w)),
        "total_9d": rmse_deg(total), "heading": rmse_deg(heading), "inclination": rmse_deg(incl),
        "inclination_vec_check": rmse_deg(incl_vec), "bodyz_world": rmse_deg(bodyz_world),
        "total_heading_aligned": float(np.degrees(np.sqrt(res.fun))), "heading_offset_deg": float(np.degrees(res.x)),
        "incl_mean": float(np.degrees(incl.mean())), "incl_max": float(np.degrees(incl.max())),
    }


def score(npz_path: str, skip_s: float = 0.0) -> dict:
    r = np.load(npz_path, allow_pickle=False)
    d = scipy.io.loadmat(str(r["trial"]))
    q_ref_all = np.asarray(d["opt_quat"], dtype=np.float64)
    movement = np.asarray(d["movement"]).ravel().astype(bool)
    rate = float(r["rate"])
    sent = r["sent"]
    by_seq = {int(s): (int(a), int(n), int(t0)) for s, a, n, t0, _, _ in sent}
    put_wall = {int(s): int(w) for s, _, _, _, w, _ in sent}
    usable = movement & np.all(np.isfinite(q_ref_all), axis=1)
    usable[: int(r["i0"]) + int(round(skip_s * rate))] = False
    usable[int(r["i1"]):] = False
    out: dict = {"file": npz_path, "device_id": str(r["device_id"]), "spp": int(r["spp"]),
                 "encoding": str(r["encoding"]), "mag": bool(r["mag"]), "packets_sent": int(len(sent))}

    # per-packet attitude
    idx, tmis, lat = [], [], []
    for s, t in zip(r["att_seq"], r["att_t_us"], strict=True):
        a, n, t0 = by_seq[int(s)]
        idx.append(a + n - 1)
        tmis.append(int(t) - (t0 + (n - 1) * 1e6 / rate))
    for s, w in zip(r["att_seq"], r["att_recv_wall_us"], strict=True):
        lat.append((int(w) - put_wall[int(s)]) / 1000.0)
    idx = np.array(idx, dtype=np.int64)
    out["attitudes"] = int(len(idx))
    out["attitude_t_us_minus_last_sample_us"] = ([float(np.min(tmis)), float(np.max(tmis))] if tmis else None)
    out["latency_put_to_recv_ms_p50_p99"] = ([float(np.percentile(lat, 50)), float(np.percentile(lat, 99))]
                                              if lat else None)
    out["filters"] = sorted({str(f) for f in r["att_filter"]})
    if len(idx):
        m = usable[idx]
        out["att"] = errors(r["att_quat"][m], q_ref_all[idx[m]])
    # per-sample attitude blocks
    if len(r["blk_seq"]):
        bidx = []
        for s, n in zip(r["blk_seq"], r["blk_n"], strict=True):
            a, n_sent, _ = by_seq[int(s)]
            assert n == n_sent
            bidx.extend(range(a, a + n))
        bidx = np.array(bidx, dtype=np.int64)
        m = usable[bidx]
        out["blocks"] = int(len(r["blk_seq"]))
        out["block_samples_missing"] = int(int(r["i1"]) - int(r["i0"]) - len(np.unique(bidx)))
        out["block"] = errors(r["blk_quat"][m], q_ref_all[bidx[m]])
    out["rejected"] = json.loads(str(r["rejected_json"]))
    out["counters"] = json.loads(str(r["counters_json"]))
    return out


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("npz", nargs="+")
    ap.add_argument("--json", action="store_true")
    args = ap.parse_args()
    res = [score(p) for p in args.npz]
    if args.json:
        print(json.dumps(res, indent=1))
        return 0
    print(f"{'device':16} {'spp':>3} {'enc':6} {'src':5} {'n':>6} {'incl':>6} {'tot9D':>6} {'totHA':>6} "
          f"{'head':>6} {'bzW':>6} {'lat50':>6} {'lat99':>6} rejected")
    for o in res:
        for src in ("block", "att"):
            if src not in o:
                continue
            e = o[src]
            if e is None:
                continue
            lt = o["latency_put_to_recv_ms_p50_p99"] or [float("nan")] * 2
            print(f"{o['device_id']:16} {o['spp']:3d} {o['encoding']:6} {src:5} {e['n']:6d} {e['inclination']:6.2f} "
                  f"{e['total_9d']:6.2f} {e['total_heading_aligned']:6.2f} {e['heading']:6.2f} "
                  f"{e['bodyz_world']:6.2f} {lt[0]:6.1f} {lt[1]:6.1f} {len(o['rejected'])}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
