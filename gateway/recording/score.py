"""Score the gateway's published attitude of a replayed real recording against its reference, BROAD's way.

    # the gateway with every sample's attitude (gw/{kind}/{id}/attitude/block, BLOCK) and no warm-up bias seed
    python -m gateway --attitude-blocks --no-warmup-bias-seed --filter default &
    python -m gateway.recording.import_broad DATA/15_undisturbed_fast_translation_A.mat -o rec/
    python -m gateway.recording.score rec/15_undisturbed_fast_translation_A.rigrec --live --replay --speed 0
    # or from a recording of the gateway's output made with `record -k 'gw/**'`
    python -m gateway.recording.score rec/15_...rigrec --attitudes gwrec/

Uses the attitude blocks when the gateway publishes them (one attitude per sample), else the packet-end
`gw/{kind}/{id}/attitude` messages (decimated to 50 Hz and DROPped under load by a default gateway).
Prints RMSE (deg) of total / heading / inclination error over the reference's movement samples
(gateway.fusion.broad.score), next to the offline `gateway.fusion.evaluate` figures for the same filter on the
same samples, and their difference; `--check TOL` exits 1 when any figure differs by more than TOL degrees.
"""

from __future__ import annotations

import argparse
import json
import sys
import threading
import time
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import zenoh
from tqdm import tqdm

from gateway import schemas
from gateway.fusion import broad
from gateway.fusion.base import FloatArray
from gateway.fusion.evaluate import registered_runner
from gateway.ingest.stats import merge_ingest_stats
from gateway.recording._cli import add_zenoh_args, zenoh_config
from gateway.recording.format import Record, read_meta, read_recording
from gateway.recording.reference import TOPIC as REF_TOPIC
from gateway.recording.replay import DEVICE_KEYS, Publisher, replay, select


@dataclass(frozen=True)
class RecordedTrial:
    """A BROAD-style trial rebuilt from a recording's IMU and reference packets (one device)."""

    trial: broad.Trial
    kind: str
    device_id: str
    t0_us: int  # device time of sample 0

    def index(self, t_us: int) -> int:
        """Sample index of a device time (µs); exact because sample times are rounded to whole µs."""
        return int(round((t_us - self.t0_us) * self.trial.rate_hz * 1e-6))


def recorded_trial(records: Iterable[Record], name: str = "recording") -> RecordedTrial:
    """Collect the first device's IMU packets and reference packets (ordered by seq, duplicates dropped)."""
    imu: dict[int, schemas.ImuPacket] = {}
    ref: dict[int, dict[str, Any]] = {}
    device: tuple[str, str] | None = None
    for r in records:
        parts = r.key.split("/")
        if len(parts) != 4 or parts[0] != "rig" or parts[3] not in ("imu", REF_TOPIC):
            continue
        if device is None:
            device = (parts[1], parts[2])
        if (parts[1], parts[2]) != device:
            continue
        if parts[3] == "imu":
            p = schemas.decode(r.key, r.payload)
            assert isinstance(p, schemas.ImuPacket)
            imu.setdefault(p.seq, p)
        else:
            d = json.loads(r.payload)
            ref.setdefault(int(d["seq"]), d)
    if device is None or not imu:
        raise ValueError("no IMU packets in the recording")
    pkts = [imu[s] for s in sorted(imu)]
    gyr = np.concatenate([p.arrays()[0] for p in pkts])
    acc = np.concatenate([p.arrays()[1] for p in pkts])
    mags = [p.arrays()[2] for p in pkts]
    mag = np.concatenate(mags) if all(m is not None for m in mags) else np.full_like(gyr, np.nan)  # type: ignore[arg-type]
    n = gyr.shape[0]
    q_ref, pos, movement = np.full((n, 4), np.nan), np.full((n, 3), np.nan), np.zeros(n, dtype=bool)
    i = 0
    for p in pkts:
        d = ref.get(p.seq)
        if d is not None:
            for j, (q, x, m) in enumerate(zip(d["quat_wxyz"], d.get("pos_m") or [None] * p.n, d["movement"],
                                              strict=True)):  # fmt: skip
                if q is not None:
                    q_ref[i + j] = q
                if x is not None:
                    pos[i + j] = x
                movement[i + j] = bool(m)
        i += p.n
    trial = broad.Trial(name, pkts[0].rate_hz, gyr, acc, mag, q_ref, pos, movement, broad.groups_from_name(name))
    return RecordedTrial(trial, device[0], device[1], pkts[0].t0_us)


GatewayAttitude = schemas.Attitude | schemas.AttitudeBlock


def attitude_array(rt: RecordedTrial, attitudes: Iterable[GatewayAttitude]) -> FloatArray:
    """(N, 4) estimate per sample from the gateway's Attitude (packet end) and AttitudeBlock (every sample)
    messages; NaN where none was received."""
    q = np.full((rt.trial.n, 4), np.nan)
    for a in attitudes:
        pairs = zip(a.t_us(), a.quat_wxyz, strict=True) if isinstance(a, schemas.AttitudeBlock) else [
            (a.t_us, a.quat_wxyz)]  # fmt: skip
        for t_us, quat in pairs:
            i = rt.index(t_us)
            if 0 <= i < rt.trial.n:
                q[i] = quat
    return q


def parse_attitude(key: str, payload: bytes) -> GatewayAttitude:
    """An attitude message by its key: `.../attitude/block` -> AttitudeBlock, else Attitude."""
    if key.endswith("/block"):
        return schemas.AttitudeBlock.model_validate_json(payload)
    return schemas.Attitude.model_validate_json(payload)


def attitudes_from_records(records: Iterable[Record], kind: str, device_id: str) -> list[GatewayAttitude]:
    """Attitude and attitude-block messages of one device found in a recording of the gateway's output."""
    keys = (schemas.attitude_key(kind, device_id), schemas.attitude_block_key(kind, device_id))
    return [parse_attitude(r.key, r.payload) for r in records if r.key in keys]


@dataclass(frozen=True)
class Comparison:
    gateway: broad.Score
    offline: broad.Score
    offline_full: broad.Score
    covered: int
    samples: int
    filter_name: str
    mode: broad.Mode

    @property
    def max_diff_deg(self) -> float:
        a, b = self.gateway.as_dict(), self.offline.as_dict()
        return max(abs(a[k] - b[k]) for k in a)


def compare(rt: RecordedTrial, q_gw: FloatArray, filter_name: str, mode: broad.Mode) -> Comparison:
    """Score the gateway's estimate and the offline evaluate run of the same filter on the samples received."""
    out = registered_runner(filter_name)(rt.trial, mode)
    if out is None:
        raise ValueError(f"filter {filter_name!r} does not support {mode}")
    q_off = out[0]
    have = np.all(np.isfinite(q_gw), axis=-1)
    q_off_same = np.where(have[:, None], q_off, np.nan)
    return Comparison(broad.score(q_gw, rt.trial, mode), broad.score(q_off_same, rt.trial, mode),
                      broad.score(q_off, rt.trial, mode), int(have.sum()), rt.trial.n, filter_name, mode)  # fmt: skip


def format_comparison(c: Comparison) -> str:
    rows = [("gateway (zenoh)", c.gateway), ("offline evaluate, same samples", c.offline),
            ("offline evaluate, all samples", c.offline_full)]  # fmt: skip
    lines = [f"filter {c.filter_name} {c.mode}: attitude for {c.covered}/{c.samples} samples",
             f"{'':32s} {'total':>8s} {'heading':>8s} {'incl':>8s}   (RMSE deg over movement samples)"]
    lines += [f"{name:32s} {s.total_deg:8.3f} {s.heading_deg:8.3f} {s.inclination_deg:8.3f}" for name, s in rows]
    lines.append(f"largest |gateway - offline| = {c.max_diff_deg:.6f} deg")
    return "\n".join(lines)


class AttitudeCollector:
    """Zenoh callback target: decodes nothing on zenoh's thread, only appends the bytes."""

    def __init__(self) -> None:
        self.payloads: list[tuple[str, bytes]] = []
        self.lock = threading.Lock()
        self.last_s = time.monotonic()

    def __call__(self, sample: zenoh.Sample) -> None:
        with self.lock:
            self.payloads.append((str(sample.key_expr), sample.payload.to_bytes()))
            self.last_s = time.monotonic()

    def attitudes(self) -> list[GatewayAttitude]:
        with self.lock:
            return [parse_attitude(k, p) for k, p in self.payloads]

    def latest_wall_us(self) -> int | None:
        """Wall time (device clock mapped by the gateway) of the newest attitude received."""
        with self.lock:
            last = self.payloads[-1] if self.payloads else None
        if last is None:
            return None
        a = parse_attitude(*last)
        if isinstance(a, schemas.AttitudeBlock):
            return None if a.wall_t0_us is None else a.wall_t0_us + a.t_us()[-1] - a.t0_us
        return a.wall_t_us


class LatestIngestStats:
    """Keeps the gateway's newest `gw/diag/ingest` message of each shard (queue drops and per-device loss); a
    sharded gateway sends one per shard, each with only the devices that shard owns."""

    def __init__(self) -> None:
        self.latest: dict[str | None, schemas.IngestStats] = {}  # by shard id (None: an unsharded gateway)

    def __call__(self, sample: zenoh.Sample) -> None:
        try:
            msg = schemas.IngestStats.model_validate_json(sample.payload.to_bytes())
        except ValueError:
            return
        self.latest[msg.shard] = msg

    def stats(self) -> schemas.IngestStats | None:
        """The shards' newest messages summed into one (per-device rows kept as they are)."""
        return merge_ingest_stats(list(self.latest.values()))


def paced(put: Callable[[Record], None], col: AttitudeCollector, max_ahead_s: float,
          stall_s: float = 10.0, warmup_s: float = 1.0) -> Callable[[Record], None]:  # fmt: skip
    """Flow control for a fast replay: hold back a record while it is more than `max_ahead_s` (recorded time)
    ahead of the newest attitude the gateway has published (before the first one, which needs the filter's 0.5 s
    warm-up: `warmup_s` ahead of the first record), so the gateway's bounded ingest queue never overflows and its
    output (CongestionControl.DROP) is not sent in bursts. Waiting ends anyway after `stall_s` without progress."""
    limit_us = int(max_ahead_s * 1e6)
    warmup_us = int(max(warmup_s, max_ahead_s) * 1e6)
    first_us: int | None = None

    def put_paced(rec: Record) -> None:
        nonlocal first_us
        if first_us is None:
            first_us = rec.t_us
        waiting_since = time.monotonic()
        while True:
            latest = col.latest_wall_us()
            if (rec.t_us - latest <= limit_us) if latest is not None else (rec.t_us - first_us <= warmup_us):
                break
            if time.monotonic() - max(col.last_s, waiting_since) > stall_s:
                break
            time.sleep(0.002)
        put(rec)

    return put_paced


def wait_for_gateway(session: zenoh.Session, timeout_s: float) -> bool:
    """True once the gateway's liveliness token `gw/alive` is visible (a replay before that would be lost)."""
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        if any(r.ok is not None for r in session.liveliness().get(schemas.GW_ALIVE_KEY, timeout=1.0)):
            return True
        time.sleep(0.2)
    return False


def wait_for_routes(session: zenoh.Session, rt: RecordedTrial, diag: LatestIngestStats, timeout_s: float) -> None:
    """Wait until the gateway's IMU subscription has reached this session (a put before that is dropped here,
    unseen) and the gateway has our subscriptions (its 1 Hz `gw/diag/ingest` reaches the subscriber declared
    after the attitude ones), so neither the first packets nor the first attitudes are lost."""
    deadline = time.monotonic() + timeout_s
    probe = session.declare_publisher(schemas.imu_key(rt.kind, rt.device_id))
    try:
        while not (probe.matching_status.matching and diag.latest):  # type: ignore[attr-defined]
            if time.monotonic() > deadline:
                raise TimeoutError("the gateway's subscriptions did not reach this session")
            time.sleep(0.02)
    finally:
        probe.undeclare()  # type: ignore[no-untyped-call]


def collect_live(
    session: zenoh.Session, rt: RecordedTrial, recording: Path | None, speed: float | None, idle_s: float,
    timeout_s: float, progress: bool = True, max_ahead_s: float = 0.3,
) -> tuple[list[GatewayAttitude], schemas.IngestStats | None]:  # fmt: skip
    """Subscribe to the device's attitude and attitude-block keys; replay `recording` if given (paced, see
    `paced`); stop `idle_s` after the last attitude. Returns the attitudes and the gateway's last ingest counters."""
    col = AttitudeCollector()
    diag = LatestIngestStats()
    subs = [session.declare_subscriber(key, col) for key in (schemas.attitude_key(rt.kind, rt.device_id),
                                                             schemas.attitude_block_key(rt.kind, rt.device_id))]
    sub_diag = session.declare_subscriber(schemas.DIAG_INGEST_KEY, diag)
    deadline = time.monotonic() + timeout_s
    if not wait_for_gateway(session, min(timeout_s, 60.0)):
        raise TimeoutError(f"no gateway ({schemas.GW_ALIVE_KEY} liveliness token) within {min(timeout_s, 60.0)} s")
    wait_for_routes(session, rt, diag, max(1.0, deadline - time.monotonic()))
    if recording is not None:
        recs = list(select(read_recording(recording), DEVICE_KEYS))
        pub = Publisher(session)
        with tqdm(total=len(recs), desc="replay", unit="sample", file=sys.stderr, disable=not progress) as bar:
            replay(paced(pub.put, col, max_ahead_s) if max_ahead_s > 0 else pub.put, recs, speed, progress=bar)
        col.last_s = max(col.last_s, time.monotonic())
    while time.monotonic() < deadline and time.monotonic() - col.last_s < idle_s:
        time.sleep(0.05)
    time.sleep(1.1)  # one more ingest report (about 1 Hz) covering everything
    for s in (*subs, sub_diag):
        s.undeclare()  # type: ignore[no-untyped-call]
    if recording is not None:
        pub.close()
    return col.attitudes(), diag.stats()


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="python -m gateway.recording.score", description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)  # fmt: skip
    p.add_argument("recording", type=Path, help="imported recording with IMU + reference packets (import_broad)")
    src = p.add_mutually_exclusive_group(required=True)
    src.add_argument("--attitudes", type=Path, help="a recording of the gateway's gw/** output")
    src.add_argument("--live", action="store_true", help="subscribe to the gateway's attitude key now")
    p.add_argument("--replay", action="store_true", help="with --live: replay RECORDING to the gateway as well")
    p.add_argument("--speed", type=float, default=10.0, help="replay speed (default: 10× real time; 0 = fast)")
    p.add_argument("--max-ahead-s", type=float, default=0.3,
                   help="--replay: stay at most this far (recorded s) ahead of the gateway's output (0 = no pacing)")
    p.add_argument("--idle-s", type=float, default=3.0, help="--live: stop this long after the last attitude")
    p.add_argument("--timeout-s", type=float, default=600.0, help="--live: give up after this long")
    p.add_argument("--filter", help="filter for the offline row (default: the one named in the attitude messages)")
    p.add_argument("--check", type=float, metavar="DEG", help="exit 1 if any figure differs by more than DEG")
    p.add_argument("--json", action="store_true", help="print JSON")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    add_zenoh_args(p)
    return p


def main(argv: Sequence[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    meta = read_meta(args.recording)
    rt = recorded_trial(read_recording(args.recording), str(meta.get("trial", args.recording.stem)))
    ingest: schemas.IngestStats | None = None
    if args.live:
        with zenoh.open(zenoh_config(args)) as session:
            atts, ingest = collect_live(session, rt, args.recording if args.replay else None, args.speed or None,
                                        args.idle_s, args.timeout_s, not args.no_progress, args.max_ahead_s)
    else:
        atts = attitudes_from_records(read_recording(args.attitudes), rt.kind, rt.device_id)
    if not atts:
        print(f"no attitude received for {rt.kind}/{rt.device_id}", file=sys.stderr)
        return 2
    name = args.filter or atts[-1].filter or "default"
    mode: broad.Mode = "9D" if bool(np.all(np.isfinite(rt.trial.mag_uT))) else "6D"
    c = compare(rt, attitude_array(rt, atts), name, mode)
    dev = next((d for d in ingest.devices if d.device_id == rt.device_id), None) if ingest else None
    diag = {"queue_drops": ingest.queue_drops, "device": dev.model_dump() if dev else None} if ingest else None
    if args.json:
        print(json.dumps({"filter": name, "mode": mode, "covered": c.covered, "samples": c.samples,
                          "gateway": c.gateway.as_dict(), "offline": c.offline.as_dict(),
                          "offline_all": c.offline_full.as_dict(), "max_diff_deg": c.max_diff_deg,
                          "gateway_ingest": diag}, indent=1))  # fmt: skip
    else:
        print(format_comparison(c))
        if ingest is not None:
            print(f"gateway ingest: {ingest.queue_drops} queue drops since its start; this device: "
                  + (f"ok {dev.ok}, lost {dev.lost}, duplicates {dev.duplicates}, reordered {dev.reordered}"
                     if dev else "not reported"))  # fmt: skip
    return 1 if args.check is not None and not c.max_diff_deg <= args.check else 0


if __name__ == "__main__":
    raise SystemExit(main())
