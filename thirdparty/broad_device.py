#!/usr/bin/env python3
"""Play one BROAD trial into a running rig gateway as an IMU device, written from docs/protocol.md only.

The script behaves like an ESP32 with zenoh-pico would:

* one liveliness token `rig/{kind}/{id}` declared before the first put (protocol.md section 6);
* IMU packets of `--spp` samples on `rig/{kind}/{id}/imu`, JSON (`rig.imu.v1`, floats printed with 7
  significant digits as a C `printf("%.7g")` of a float32 would) or the binary v2 layout of section 3.6;
* `boot_id` random uint32, `seq` starting at a random value, `t0_us` taken from a simulated microsecond
  timer (esp_timer style, since boot) at the data-ready interrupt of sample 0: sample clock + oscillator drift
  (`--drift-ppm`) + interrupt latency jitter (`--jitter-us`, gaussian, plus rare late interrupts
  `--late-prob`/`--late-us`); `wall_t0_us` from the host clock (SNTP-synced device realtime clock);
* real-time pacing by default: a packet is put when its last sample has been "measured"
  (`--pace fast` sends back to back with a small sleep, which a real device cannot do).

It subscribes to `gw/{kind}/{id}/attitude` (and `.../attitude/block` if the gateway publishes it) and to
`gw/diag/rejected`, and writes everything received with gateway/receive timestamps to an .npz file which
`score_broad.py` scores against the optical reference.

Only eclipse-zenoh, numpy and scipy (plus the standard library) are used; nothing from the gateway package.
"""
from __future__ import annotations

import argparse
import json
import random
import struct
import sys
import threading
import time
import urllib.request

import numpy as np
import scipy.io
import zenoh


def load_trial(path: str) -> dict:
    d = scipy.io.loadmat(path)
    return {
        "gyr": np.asarray(d["imu_gyr"], dtype=np.float64),
        "acc": np.asarray(d["imu_acc"], dtype=np.float64),
        "mag": np.asarray(d["imu_mag"], dtype=np.float64),
        "rate": float(np.asarray(d["sampling_rate"]).squeeze()),
    }


def fmt_rows(a: np.ndarray) -> str:
    """n x 3 array as JSON rows, float32 values printed with %.7g (what a C device would do)."""
    a32 = a.astype(np.float32)
    return "[" + ",".join("[" + ",".join(f"{v:.7g}" for v in row) + "]" for row in a32) + "]"


def json_packet(dev: str, kind: str, boot: int, seq: int, t0: int, rate: float, gyr, acc, mag, wall_t0) -> bytes:
    parts = [
        '"v":1', f'"device_id":"{dev}"', f'"kind":"{kind}"', f'"boot_id":{boot}', f'"seq":{seq}',
        f'"t0_us":{t0}', f'"rate_hz":{rate!r}', f'"gyr_rad_s":{fmt_rows(gyr)}', f'"acc_m_s2":{fmt_rows(acc)}',
    ]
    if mag is not None:
        parts.append(f'"mag_uT":{fmt_rows(mag)}')
    if wall_t0 is not None:
        parts.append(f'"wall_t0_us":{wall_t0}')
    return ("{" + ",".join(parts) + "}").encode()


def binary_packet(dev: str, kind: str, boot: int, seq: int, t0: int, rate: float, gyr, acc, mag, wall_t0) -> bytes:
    """protocol.md section 3.6: 56-byte little-endian header, id, n rows of float32 (g, a[, m])."""
    flags = (1 if mag is not None else 0) | (0x10 if wall_t0 is not None else 0)
    idb = dev.encode("ascii")
    n = gyr.shape[0]
    header = struct.pack(
        "<BBBBHHIIqdqffff", 0xB2, flags, {"rod": 0, "hook": 1, "imu": 2}[kind], len(idb), n, 0, boot, seq, t0, rate,
        wall_t0 if wall_t0 is not None else 0, 0.0, 0.0, 0.0, 0.0,
    )
    assert len(header) == 56
    cols = [gyr, acc] + ([mag] if mag is not None else [])
    rows = np.hstack(cols).astype("<f4")
    return header + idb + rows.tobytes()


class Receiver:
    """Collects gateway outputs in zenoh callbacks (kept short: append raw bytes, parse later)."""

    def __init__(self) -> None:
        self.lock = threading.Lock()
        self.att: list[tuple[int, bytes]] = []
        self.block: list[tuple[int, bytes]] = []
        self.rejected: list[bytes] = []
        self.ingest: list[bytes] = []
        self.alarms: list[tuple[int, bytes]] = []
        self.cmds: list[tuple[int, bytes]] = []

    def _cb(self, store: list):
        def cb(sample: zenoh.Sample) -> None:
            b = sample.payload.to_bytes()
            store.append((time.time_ns() // 1000, b))
        return cb


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("trial", help="BROAD .mat file")
    ap.add_argument("--id", default=None, help="device id (default: broad-<trial number>-<spp>)")
    ap.add_argument("--kind", default="imu", choices=["imu", "rod", "hook"], help="device kind (default imu)")
    ap.add_argument("--spp", type=int, default=8, help="samples per packet (default 8)")
    ap.add_argument("--encoding", choices=["json", "binary"], default="json")
    ap.add_argument("--no-mag", action="store_true", help="6-axis device: leave mag_uT out")
    ap.add_argument("--no-wall", action="store_true", help="do not send wall_t0_us")
    ap.add_argument("--connect", default="tcp/127.0.0.1:7447", help="gateway endpoint (protocol.md section 1)")
    ap.add_argument("--mode", default="peer", choices=["peer", "client"])
    ap.add_argument("--pace", choices=["realtime", "fast"], default="realtime")
    ap.add_argument("--fast-gap-s", type=float, default=0.002, help="sleep between packets with --pace fast")
    ap.add_argument("--jitter-us", type=float, default=150.0, help="interrupt latency sigma of t0_us, µs")
    ap.add_argument("--late-prob", type=float, default=0.01, help="probability of a late data-ready interrupt")
    ap.add_argument("--late-us", type=float, default=4000.0, help="max extra delay of a late interrupt, µs")
    ap.add_argument("--late-fixed", action="store_true", help="a late interrupt is exactly --late-us late")
    ap.add_argument("--drift-ppm", type=float, default=40.0, help="IMU ODR vs MCU timer drift, ppm")
    ap.add_argument("--seed", type=int, default=None, help="random seed (boot_id, seq start, jitter)")
    ap.add_argument("--start-s", type=float, default=0.0, help="start at this time into the trial")
    ap.add_argument("--duration-s", type=float, default=None, help="play only this long")
    ap.add_argument("--wait-gateway-s", type=float, default=30.0,
                    help="wait up to this long for the gw/alive token before playing (0: do not wait)")
    ap.add_argument("--linger-s", type=float, default=3.0, help="keep listening after the last packet")
    ap.add_argument("--stats-url", default=None, help="REST stats URL to save at the end, e.g. "
                    "http://127.0.0.1:8000/api/stats")
    ap.add_argument("--out", required=True, help="output .npz")
    args = ap.parse_args()

    rng = random.Random(args.seed)
    nrng = np.random.default_rng(args.seed)
    tr = load_trial(args.trial)
    rate = tr["rate"]
    period_us = 1e6 / rate
    N = tr["gyr"].shape[0]
    i0 = int(round(args.start_s * rate))
    i1 = N if args.duration_s is None else min(N, i0 + int(round(args.duration_s * rate)))
    trial_no = args.trial.rsplit("/", 1)[-1][:2]
    dev = args.id or f"broad-{trial_no}-{args.spp}"
    kind = args.kind
    boot = rng.getrandbits(32)
    seq0 = rng.getrandbits(32)
    boot_offset_us = rng.randint(800_000, 3_000_000)  # µs since boot when the IMU stream starts

    # Device timestamp of every sample: drifting sample clock + interrupt latency (never negative).
    k = np.arange(N, dtype=np.float64)
    lat = np.abs(nrng.normal(0.0, args.jitter_us, N))
    late = nrng.random(N) < args.late_prob
    lat[late] += (args.late_us if args.late_fixed else nrng.uniform(0.0, args.late_us, int(late.sum())))
    t_dev = boot_offset_us + k * period_us * (1.0 + args.drift_ppm * 1e-6) + lat

    conf = zenoh.Config()
    conf.insert_json5("mode", json.dumps(args.mode))
    conf.insert_json5("connect/endpoints", json.dumps([args.connect]))
    conf.insert_json5("connect/exit_on_failure", "false")
    conf.insert_json5("connect/retry", json.dumps(
        {"period_init_ms": 250, "period_max_ms": 2000, "period_increase_factor": 2}))
    conf.insert_json5("scouting/multicast/enabled", "false")
    if args.mode == "peer":
        conf.insert_json5("listen/endpoints", "[]")

    rx = Receiver()
    enc_name = ("application/json;schema=rig.imu.v1" if args.encoding == "json"
                else "application/octet-stream;schema=rig.imu.v2")
    make = json_packet if args.encoding == "json" else binary_packet
    sent = []  # (seq, first sample index, n, t0_us, put wall µs, size)
    with zenoh.open(conf) as s:
        alive = threading.Event()

        def on_alive(sample: zenoh.Sample) -> None:
            if sample.kind == zenoh.SampleKind.PUT:
                alive.set()

        lsub = s.liveliness().declare_subscriber("gw/alive", on_alive, history=True)
        subs = [
            s.declare_subscriber(f"gw/{kind}/{dev}/attitude", rx._cb(rx.att)),
            s.declare_subscriber(f"gw/{kind}/{dev}/attitude/block", rx._cb(rx.block)),
            s.declare_subscriber("gw/diag/rejected", rx._cb(rx.rejected)),
            s.declare_subscriber("gw/diag/ingest", rx._cb(rx.ingest)),
            s.declare_subscriber(f"gw/{kind}/{dev}/alarm", rx._cb(rx.alarms)),
            # a rod's reel commands (protocol.md section 5): a real device would act on them; we only log them
            s.declare_subscriber(f"rig/{kind}/{dev}/reel/cmd", rx._cb(rx.cmds)),
        ]
        if args.wait_gateway_s > 0 and not alive.wait(args.wait_gateway_s):
            print("gateway token gw/alive not seen; playing anyway", file=sys.stderr)
        token = s.liveliness().declare_token(f"rig/{kind}/{dev}")
        pub = s.declare_publisher(f"rig/{kind}/{dev}/imu", encoding=zenoh.Encoding(enc_name),
                                  congestion_control=zenoh.CongestionControl.DROP)
        time.sleep(0.2)  # give a shard subscribing on the token time to declare (protocol.md section 6)
        start_mono = time.monotonic()
        start_wall_us = time.time_ns() // 1000
        sntp_offset_us = rng.randint(-3000, 3000)
        seq = seq0
        for a in range(i0, i1, args.spp):
            b = min(a + args.spp, i1)
            if args.pace == "realtime":
                due = start_mono + (b - i0) * period_us * 1e-6
                dt = due - time.monotonic()
                if dt > 0:
                    time.sleep(dt)
            t0 = int(round(t_dev[a]))
            wall_t0 = None if args.no_wall else int(start_wall_us + (a - i0) * period_us + sntp_offset_us)
            mag = None if args.no_mag else tr["mag"][a:b]
            payload = make(dev, kind, boot, seq, t0, rate, tr["gyr"][a:b], tr["acc"][a:b], mag, wall_t0)
            pub.put(payload)
            sent.append((seq, a, b - a, t0, time.time_ns() // 1000, len(payload)))
            seq = (seq + 1) & 0xFFFFFFFF
            if args.pace == "fast":
                time.sleep(args.fast_gap_s)
        play_s = time.monotonic() - start_mono
        time.sleep(args.linger_s)
        stats = None
        if args.stats_url:
            try:
                with urllib.request.urlopen(args.stats_url, timeout=5) as r:
                    stats = r.read().decode()
            except Exception as e:  # noqa: BLE001 - report, do not fail the run
                stats = json.dumps({"error": repr(e)})
        for sub in subs:
            sub.undeclare()
        lsub.undeclare()
        token.undeclare()

    sent_a = np.array(sent, dtype=np.int64)
    att = [(w, json.loads(p)) for w, p in rx.att]
    blk = [(w, json.loads(p)) for w, p in rx.block]
    rej = [json.loads(p) for _, p in rx.rejected]
    rej_mine = [r for r in rej if f"/{dev}/" in r.get("key", "")]
    ing = [json.loads(p) for _, p in rx.ingest]
    my_counters = None
    for m in reversed(ing):
        for d in m.get("devices") or []:
            if d.get("device_id") == dev:
                my_counters = d
                break
        if my_counters:
            break
    np.savez_compressed(
        args.out,
        trial=args.trial, device_id=dev, spp=args.spp, encoding=args.encoding, mag=not args.no_mag,
        rate=rate, i0=i0, i1=i1, pace=args.pace,
        sent=sent_a,  # seq, first index, n, t0_us, put wall µs, bytes
        att_recv_wall_us=np.array([w for w, _ in att], dtype=np.int64),
        att_seq=np.array([m["seq"] for _, m in att], dtype=np.int64),
        att_t_us=np.array([m["t_us"] for _, m in att], dtype=np.int64),
        att_wall_t_us=np.array([m.get("wall_t_us") or -1 for _, m in att], dtype=np.int64),
        att_quat=np.array([m["quat_wxyz"] for _, m in att], dtype=np.float64).reshape(-1, 4),
        att_filter=np.array([m.get("filter") or "" for _, m in att]),
        blk_seq=np.array([m["seq"] for _, m in blk], dtype=np.int64),
        blk_t0_us=np.array([m["t0_us"] for _, m in blk], dtype=np.int64),
        blk_n=np.array([len(m["quat_wxyz"]) for _, m in blk], dtype=np.int64),
        blk_quat=(np.concatenate([np.asarray(m["quat_wxyz"], dtype=np.float64) for _, m in blk])
                  if blk else np.zeros((0, 4))),
        rejected_json=json.dumps(rej_mine), rejected_all_count=len(rej),
        counters_json=json.dumps(my_counters), stats_json=stats or "",
        alarms_json=json.dumps([json.loads(p) for _, p in rx.alarms]),
        cmds_json=json.dumps([p.decode(errors="replace") for _, p in rx.cmds]),
    )
    print(json.dumps({
        "device_id": dev, "packets_sent": len(sent), "samples": i1 - i0, "play_s": round(play_s, 1),
        "mean_bytes": float(sent_a[:, 5].mean()) if len(sent) else 0, "attitudes": len(att),
        "attitude_blocks": len(blk), "rejected_for_me": len(rej_mine),
        "rejected_reasons": sorted({r.get("reason", "") + ": " + r.get("detail", "")[:120] for r in rej_mine}),
        "alarms": len(rx.alarms), "reel_cmds": len(rx.cmds),
        "counters": my_counters, "filters": sorted({m.get("filter") or "" for _, m in att}),
    }, indent=1))
    return 0


if __name__ == "__main__":
    sys.exit(main())
