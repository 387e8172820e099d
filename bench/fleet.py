"""Fleet load: N rods and hooks at 100 Hz through real zenoh into the real gateway, and what it costs.

    python -m bench.fleet                              # N = 100, 300, 1000 (80 % rods, 20 % hooks), 30 s each
    python -m bench.fleet --counts 100 --duration 600  # one 10-minute soak (RSS over time)
    python -m bench.fleet --counts 50 --duration 10 --procs 1   # quick look
    python -m bench.fleet --counts 300 --shards 1 2            # one shard vs two shard processes, same session

For each N (and each `--shards` S) it starts `python -m gateway --shards S` (a zenoh router, the default, on a
free loopback port, REST on another), a cheap load generator and an observer, each its own process, then prints
one row:

- sent / processed / lost: IMU packets the generators put, the gateway's `received` counter and the sum of
  per-device `ok`, queue drops (packets the gateway's inbox had to drop), all summed over the shards
  (`/api/shards`; each counts only the devices it serves);
- gateway CPU per packet (ms): user + system CPU of the gateway and all its child processes over the measured
  window, divided by the packets processed in it (all-in: decode, fusion, rules, outputs, REST), counted from
  the shards' `gw/diag/ingest` messages (REST answers seconds late under overload, which made the window wrong);
  `--threads` splits it by process and thread, `--profile` profiles the parent's main thread;
- latency p50/p99 (ms): observer receipt time minus the device wall time of the packet's last sample, over every
  `gw/*/*/attitude` message (with `--observe batch`: over every entry of the batched `gw/attitudes`, one message
  per shard batch, docs/protocol.md); alarms the same over `gw/*/*/alarm`;
- attitudes received vs expected (one per packet end at the default attitude interval); fewer is not loss when the
  gateway runs behind: the hub publishes each device's newest attitude once per batch, so a batch holding several
  packets of a device sends one (docs/gateway.md);
- gateway RSS (MiB) at the start and end of the window and its maximum;
- the generators' own CPU (share of one core), and this process's (`obs core`: the observer and the REST probe);
- REST under load: time for `/api/stats` and `/api/health` to answer, probed once a second in the window (p50/max s).

The generator does not simulate physics while it runs: it replays pre-built streams (a pool of simulated rods and
hooks, `--pool` of each, built once with the real simulators and sensor model), patching only `seq`, `t0_us` and
`wall_t0_us` into the JSON text (with `--encoding binary`: into the protocol v2 header, docs/protocol.md 3.6), so
it costs a few microseconds per packet and the gateway is what is measured.
Devices are spread evenly over each packet period (no synchronised bursts). A pooled stream loops every
`--pool-seconds`; the loop joint is a small jump in the signals, not a gap in time.
"""

from __future__ import annotations

import argparse
import json
import multiprocessing as mp
import os
import pickle
import re
import struct
import tempfile
import threading
import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import zenoh

from bench.bite_latency import REPO, free_port, observer_config, stop_process, wait_http
from gateway import schemas
from gateway.ingest.bus import ZenohBus

RATE_HZ = 100.0
ENCODINGS = {"json": schemas.ENCODING_IMU, "binary": schemas.ENCODING_IMU_BINARY}
KIND_CODES = {kind: code for code, kind in enumerate(schemas.IMU_KINDS)}
BIN_IDS, BIN_SEQ, BIN_WALL = struct.Struct("<BB"), struct.Struct("<IIq"), struct.Struct("<q")  # header offsets 2, 8, 32
HEADER_KEYS = ("v", "device_id", "kind", "boot_id", "seq", "t0_us", "wall_t0_us")
WALL_RE = re.compile(rb'"wall_t_us":\s*(\d+)')
ENTRY_RE = re.compile(rb'"device_id":"([^"]+)",[^{}]*?"t_us":\d+,"wall_t_us":(\d+)')  # an AttitudeBatch entry


# -- the pool of pre-built streams ----------------------------------------------------------------------------

Body = str | tuple[bytes, bytes]  # JSON text without the header fields, or (binary header template, float32 rows)


def build_pool(kind: str, count: int, seconds: float, spp: int, seed: int, encoding: str = "json") -> list[list[Body]]:
    """`count` simulated streams of `kind`, `seconds` long: per stream, the body of each packet without its header
    fields (what the generator patches in), in packet order."""
    from devices.common import FleetSettings

    fleet_settings = FleetSettings(count=count, seed=seed, samples_per_packet=spp, truth=False,
                                   id_prefix=f"pool-{kind}", progress=False)  # fmt: skip
    if kind == "rod":
        from devices.sim_rod import RodFleet

        fleet: Any = RodFleet(fleet_settings)
    else:
        from devices.hook_physics import HookPhysicsSettings, HookScenario
        from devices.sim_hook import HookFleet

        scenario = HookScenario(duration_s=seconds + 1.0, initial_swing_rad=0.05)
        fleet = HookFleet(fleet_settings, HookPhysicsSettings(), scenario)
    packets = max(1, round(seconds * RATE_HZ / spp))
    bodies: list[list[Body]] = [[] for _ in range(count)]
    for k in range(packets):
        data, _ = fleet.tick(k)
        for i, msgs in enumerate(data):
            if encoding == "binary":
                b = schemas.imu_to_binary(schemas.decode(msgs[0].key, msgs[0].payload))  # type: ignore[arg-type]
                head = schemas.IMU_BINARY_HEADER.size
                bodies[i].append((b[:head], b[head + b[3]:]))  # b[3]: length of the device id after the header
                continue
            d = json.loads(msgs[0].payload)
            body = {key: v for key, v in d.items() if key not in HEADER_KEYS}
            bodies[i].append(json.dumps(body, separators=(",", ":"))[1:-1])
    return bodies


@dataclass(frozen=True)
class GenJob:
    """One generator process: its devices (kind, id, pool stream index) and when to run."""

    port: int
    devices: tuple[tuple[str, str, int], ...]
    pool_path: str
    spp: int
    start_wall_s: float
    duration_s: float
    result_path: str
    encoding: str = "json"


def generator(job: GenJob) -> None:
    """Publish every device's packets at 100 Hz / spp, spread over the period; write (sent, cpu_s) to result_path."""
    with open(job.pool_path, "rb") as f:
        pools: dict[str, list[list[Body]]] = pickle.load(f)
    period_s = job.spp / RATE_HZ
    n = len(job.devices)
    conf = observer_config(job.port)
    sent = 0
    with zenoh.open(conf) as session:
        pubs, tokens, heads, idents = [], [], [], []
        for j, (kind, dev, _) in enumerate(job.devices):
            pubs.append(session.declare_publisher(
                f"rig/{kind}/{dev}/imu", encoding=ENCODINGS[job.encoding],
                congestion_control=zenoh.CongestionControl.BLOCK,
            ))  # fmt: skip
            tokens.append(session.liveliness().declare_token(f"rig/{kind}/{dev}"))
            heads.append(f'{{"v":1,"device_id":"{dev}","kind":"{kind}","boot_id":{1000 + j},')
            idents.append(dev.encode())
        deadline = time.time() + 60.0  # the gateway's subscription must reach this session before the first put
        while not all(p.matching_status.matching for p in pubs) and time.time() < deadline:
            time.sleep(0.05)
        time.sleep(max(2.0, job.start_wall_s - time.time()))  # peers' gossip links settle after the first match
        cpu0 = time.process_time()
        t_start = time.time()
        k = 0
        while True:
            tick_wall = t_start + k * period_s
            if tick_wall - t_start >= job.duration_s:
                break
            for j, (kind, _, stream) in enumerate(job.devices):
                slot_wall = tick_wall + period_s * j / n
                delay = slot_wall - time.time()
                if delay > 0.0005:
                    time.sleep(delay)
                body = pools[kind][stream]
                t0_us = k * round(period_s * 1e6)
                wall_last_us = int(slot_wall * 1e6)
                wall_t0_us = wall_last_us - round((job.spp - 1) * 1e6 / RATE_HZ)
                part = body[k % len(body)]
                if isinstance(part, tuple):  # binary: patch kind, id length, boot_id, seq, t0_us, wall_t0_us
                    h = bytearray(part[0])
                    BIN_IDS.pack_into(h, 2, KIND_CODES[kind], len(idents[j]))
                    BIN_SEQ.pack_into(h, 8, 1000 + j, k, t0_us)
                    BIN_WALL.pack_into(h, 32, wall_t0_us)
                    pubs[j].put(bytes(h) + idents[j] + part[1])
                else:
                    pubs[j].put(f'{heads[j]}"seq":{k},"t0_us":{t0_us},"wall_t0_us":{wall_t0_us},{part}}}')
                sent += 1
            k += 1
        cpu = time.process_time() - cpu0
        wall_s = time.time() - t_start
        time.sleep(1.0)  # closing the session at once drops what is still in its transmit queue
        for p in pubs:
            p.undeclare()
        for t in tokens:
            t.undeclare()
    Path(job.result_path).write_text(json.dumps({"sent": sent, "cpu_s": cpu, "wall_s": wall_s}))


# -- observer and process accounting ---------------------------------------------------------------------------

@dataclass
class Observer:
    """Receipt-time latencies of attitude and alarm messages (a cheap regex, not a JSON parse)."""

    attitude_ms: list[float] = field(default_factory=list)
    alarm_ms: list[float] = field(default_factory=list)
    lock: threading.Lock = field(default_factory=threading.Lock)
    measuring: bool = False

    batch_devices: set[bytes] = field(default_factory=set)  # device ids seen in gw/attitudes (`--observe batch`)
    ok_by_shard: dict[str, int] = field(default_factory=dict)
    diag_at: dict[str, float] = field(default_factory=dict)

    def on_diag(self, _key: str, payload: bytes) -> None:
        """gw/diag/ingest (each shard's counters, once a second, made between two batches): packets processed so
        far per shard, for the CPU-per-packet window (REST answers late under overload, the diag does not)."""
        try:
            d = json.loads(payload)
            ok = sum(int(x.get("ok", 0)) for x in d.get("devices", []))
        except (ValueError, TypeError, AttributeError):
            return
        with self.lock:
            self.ok_by_shard[str(d.get("shard"))] = ok
            self.diag_at[str(d.get("shard"))] = time.monotonic()

    def processed(self, shards: int, fresh_s: float = 2.0) -> int | None:
        """Packets processed by all shards, or None unless every shard's count is at most `fresh_s` old (diag
        messages are DROP puts: at 1000 devices, each ~150 kB, most of them are dropped)."""
        now = time.monotonic()
        with self.lock:
            if len(self.diag_at) < shards or any(now - t > fresh_s for t in self.diag_at.values()):
                return None
            return sum(self.ok_by_shard.values())

    def on_sample(self, key: str, payload: bytes) -> None:
        t_us = time.time() * 1e6
        if not self.measuring:
            return
        m = WALL_RE.search(payload)
        if m is None:
            return
        lat = (t_us - int(m.group(1))) / 1e3
        with self.lock:
            (self.alarm_ms if key.endswith("/alarm") else self.attitude_ms).append(lat)


    def on_batch(self, _key: str, payload: bytes) -> None:
        """gw/attitudes (`--observe batch`): one latency per entry, each from its own device wall time."""
        t_us = time.time() * 1e6
        if not self.measuring:
            return
        entries = ENTRY_RE.findall(payload)
        with self.lock:
            self.attitude_ms += [(t_us - int(wall)) / 1e3 for _, wall in entries]
            self.batch_devices.update(d for d, _ in entries)


class RestProbe(threading.Thread):
    """Times `GET /api/stats` and `/api/health` once a second until stopped (each with a 30 s timeout): whether the
    REST side keeps answering while ingest is overloaded."""

    def __init__(self, http_port: int) -> None:
        super().__init__(name="rest-probe", daemon=True)
        self.http_port = http_port
        self.latency_s: list[float] = []
        self.stop = threading.Event()

    def run(self) -> None:
        import httpx

        with httpx.Client(timeout=30.0) as client:
            while not self.stop.wait(1.0):
                for path in ("/api/stats", "/api/health"):
                    t0 = time.perf_counter()
                    try:
                        client.get(f"http://127.0.0.1:{self.http_port}{path}")
                    except httpx.HTTPError:
                        pass  # a timeout counts as its full 30 s
                    self.latency_s.append(time.perf_counter() - t0)


def process_tree(pid: int) -> list[int]:
    """pid and all its descendants (from /proc)."""
    children: dict[int, list[int]] = {}
    for entry in os.listdir("/proc"):
        if not entry.isdigit():
            continue
        try:
            with open(f"/proc/{entry}/stat") as f:
                ppid = int(f.read().rsplit(")", 1)[1].split()[1])
        except (OSError, IndexError, ValueError):
            continue
        children.setdefault(ppid, []).append(int(entry))
    out, todo = [], [pid]
    while todo:
        p = todo.pop()
        out.append(p)
        todo += children.get(p, [])
    return out


def tree_cpu_s(pid: int) -> float:
    """User + system CPU seconds of a process tree (live processes only)."""
    tick = os.sysconf("SC_CLK_TCK")
    total = 0.0
    for p in process_tree(pid):
        try:
            with open(f"/proc/{p}/stat") as f:
                fields = f.read().rsplit(")", 1)[1].split()
            total += (int(fields[11]) + int(fields[12])) / tick
        except (OSError, IndexError, ValueError):
            pass
    return total


def thread_cpu_s(pid: int) -> dict[tuple[int, str], float]:
    """CPU seconds of every thread of a process tree, by (pid, thread name) (threads of one name summed):
    where the gateway's CPU goes (zenoh's rx/tx threads run the subscriber callbacks, the main thread ingest)."""
    tick = os.sysconf("SC_CLK_TCK")
    out: dict[tuple[int, str], float] = {}
    for p in process_tree(pid):
        try:
            tids = os.listdir(f"/proc/{p}/task")
        except OSError:
            continue
        for tid in tids:
            try:
                with open(f"/proc/{p}/task/{tid}/stat") as f:
                    text = f.read()
            except OSError:
                continue
            name = re.sub(r"[-_ ]?\d+$", "", text[text.index("(") + 1: text.rindex(")")]) or "?"
            fields = text.rsplit(")", 1)[1].split()
            if tid == str(p):
                name = "main"
            out[(p, name)] = out.get((p, name), 0.0) + (int(fields[11]) + int(fields[12])) / tick
    return out


def print_threads(before: dict[tuple[int, str], float], after: dict[tuple[int, str], float], root: int,
                  packets: int) -> None:
    """The CPU of each process (root = the router-parent) and thread name over the window, ms per processed packet."""
    total = sum(after.values()) - sum(before.get(k, 0.0) for k in after)
    print(f"  CPU by process and thread over the window, ms per processed packet ({packets} packets):")
    for pid in sorted({p for p, _ in after}, key=lambda p: (p != root, p)):
        rows = sorted(((after[k] - before.get(k, 0.0), k[1]) for k in after if k[0] == pid), reverse=True)
        proc = sum(c for c, _ in rows)
        parts = ", ".join(f"{name} {1e3 * c / max(1, packets):.3f}" for c, name in rows if c > 0.0)
        print(f"    {'parent' if pid == root else 'child':>6} {pid}: {1e3 * proc / max(1, packets):.3f} ({parts})")
    print(f"    all: {1e3 * total / max(1, packets):.3f}")


def tree_rss_mib(pid: int) -> float:
    """Resident memory of a process tree, MiB."""
    total = 0
    for p in process_tree(pid):
        try:
            with open(f"/proc/{p}/status") as f:
                for line in f:
                    if line.startswith("VmRSS:"):
                        total += int(line.split()[1])
        except OSError:
            pass
    return total / 1024.0


def start_gateway(data_dir: Path, zenoh_port: int, http_port: int, log_path: Path, shards: int,
                  profile: Path | None = None) -> Any:
    """`python -m gateway --shards S` listening on tcp/127.0.0.1:zenoh_port, REST on http_port; with `profile`, the
    parent process runs under cProfile (its main thread only) and writes its stats there on exit."""
    import subprocess
    import sys

    # the profile counts the main thread's CPU time (thread_time), not wall time: on a loaded machine wall time
    # charges preemption and GIL waits to whatever function was running
    prof = ["-m", "gateway"] if profile is None else ["-c", (
        "import cProfile, sys, time; from gateway.__main__ import main; p = cProfile.Profile(time.thread_time)\n"
        f"try: p.runcall(main, sys.argv[2:])\nfinally: p.dump_stats({str(profile)!r})"), "gateway"]  # fmt: skip
    return subprocess.Popen(
        [sys.executable, *prof, "--data-dir", str(data_dir), "--port", str(http_port), "--no-3d",
         "--listen", f"tcp/127.0.0.1:{zenoh_port}", "--log-level", "WARNING", "--shards", str(shards)],
        cwd=REPO, stdout=log_path.open("wb"), stderr=subprocess.STDOUT, env=os.environ | {"PYTHONUNBUFFERED": "1"},
    )  # fmt: skip


SUMMED = ("received", "offered", "ignored", "queue_drops")


def stats(http_port: int) -> dict[str, Any]:
    """The shards' ingest counters summed (`/api/shards`), with a long timeout: an overloaded gateway answers
    slowly, and the count is what matters. {} if it does not answer."""
    import httpx

    try:
        shards = httpx.get(f"http://127.0.0.1:{http_port}/api/shards", timeout=30.0).json()["shards"]
    except (httpx.HTTPError, KeyError, ValueError):
        return {}
    out: dict[str, Any] = {k: sum(int(s.get(k, 0)) for s in shards) for k in SUMMED}
    out["rejected"] = {k: v for s in shards for k, v in s.get("rejected", {}).items()}
    out["devices"] = [d for s in shards for d in s.get("devices", [])]
    out["shards"] = len(shards)
    return out


def processed(s: dict[str, Any]) -> int:
    return int(sum(d.get("ok", 0) for d in s.get("devices", [])))


def pct(xs: Sequence[float], q: float) -> float:
    if not xs:
        return float("nan")
    ys = sorted(xs)
    return ys[min(len(ys) - 1, int(q * len(ys)))]


# -- one fleet size ----------------------------------------------------------------------------------------------

@dataclass
class Row:
    n: int
    shards: int
    sent: int
    received: int
    processed: int
    queue_drops: int
    cpu_ms_per_packet: float
    attitude_p50_ms: float
    attitude_p99_ms: float
    attitudes: int
    attitudes_expected: int
    alarms: int
    alarm_p99_ms: float
    rss_start_mib: float
    rss_end_mib: float
    rss_max_mib: float
    generator_core_share: float
    observer_core_share: float  # this process: the observer's zenoh session and callbacks, the REST probe
    devices_seen: int
    rest_p50_s: float = float("nan")
    rest_max_s: float = float("nan")
    observe: str = "devices"
    batch_devices: int = 0  # devices seen in gw/attitudes in the window (`observe="batch"`)


def run_one(n: int, hook_share: float, pools: dict[str, list[list[Body]]], pool_path: Path, spp: int, procs: int,
            duration_s: float, warmup_s: float, work: Path, encoding: str = "json", shards: int = 1,
            threads: bool = False, profile: bool = False, count_imu: bool = False, observe: str = "devices") -> Row:
    """Start a gateway, run n devices for warmup + duration seconds, measure the last `duration_s`; with
    `count_imu` the observer also counts every IMU packet zenoh delivers (to tell zenoh's loss from the gateway's,
    at ~0.1 core more on the machine at 1000 devices). `observe`: the observer takes every device's attitude key
    (`gw/*/*/attitude`, "devices") or the batched `gw/attitudes` ("batch")."""
    zport, hport = free_port(), free_port()
    n_hook = round(n * hook_share)
    devices = [("hook", f"fleet-hook-{i + 1:04d}", i % len(pools["hook"])) for i in range(n_hook)]
    devices += [("rod", f"fleet-rod-{i + 1:04d}", i % len(pools["rod"])) for i in range(n - n_hook)]
    prof = work / f"gw-{n}-{shards}.prof" if profile else None
    gw = start_gateway(work / f"gw-{n}-{shards}", zport, hport, work / f"gw-{n}-{shards}.log", shards, prof)
    try:
        wait_http(hport, timeout_s=600.0)
        deadline = time.time() + 300.0  # every shard up (its kernels loaded) and in the live set
        while stats(hport).get("shards", 0) < shards and time.time() < deadline:
            time.sleep(0.5)
        obs = Observer()
        with zenoh.open(observer_config(zport)) as session:
            # subscribed as the gateway subscribes (its bus declares the received keys, `RouteKeys`: without that
            # this session's zenoh receive took ~0.8 core)
            bus = ZenohBus(session)
            if observe == "batch":
                bus.subscribe(schemas.T_ATTITUDES.key(), obs.on_batch)
            else:
                bus.subscribe("gw/*/*/attitude", obs.on_sample)
            bus.subscribe("gw/*/*/alarm", obs.on_sample)
            bus.subscribe(schemas.DIAG_INGEST_KEY, obs.on_diag)
            imu_seen = [0]
            if count_imu:
                bus.subscribe("rig/*/*/imu", lambda _k, _p: imu_seen.__setitem__(0, imu_seen[0] + 1))
            time.sleep(1.0)
            start = time.time() + 3.0  # generators connect and declare first
            ctx = mp.get_context("spawn")  # zenoh sessions do not survive fork
            jobs = [GenJob(zport, tuple(devices[g::procs]), str(pool_path), spp, start, warmup_s + duration_s,
                           str(work / f"gen-{n}-{g}.json"), encoding) for g in range(procs)]  # fmt: skip
            gens = [ctx.Process(target=generator, args=(job,)) for job in jobs]
            for g in gens:
                g.start()
            time.sleep(max(0.0, start + warmup_s - time.time()))
            probe = RestProbe(hport)  # from the window's start: the first stats call below may be slow itself
            probe.start()
            cpu0, th0, ok0 = tree_cpu_s(gw.pid), thread_cpu_s(gw.pid), obs.processed(shards)
            own0, t0 = time.process_time(), time.monotonic()
            s0 = stats(hport)
            obs.measuring = True
            rss: list[float] = []
            while time.time() < start + warmup_s + duration_s:
                rss.append(tree_rss_mib(gw.pid))
                time.sleep(1.0)
            cpu1, th1, ok1 = tree_cpu_s(gw.pid), thread_cpu_s(gw.pid), obs.processed(shards)
            own_share = (time.process_time() - own0) / max(1e-9, time.monotonic() - t0)
            obs.measuring = False
            probe.stop.set()
            probe.join(timeout=60)
            for g in gens:
                g.join(timeout=60)
            time.sleep(5.0)  # let the gateway drain its queue before the final count
            s1 = stats(hport)
            bus.route_keys.close()
    finally:
        stop_process(gw)
    if s1.get("shards", 0) != shards:
        print(f"  only {s1.get('shards', 0)} of {shards} shards answered the final count: the sums are short")
    gen = [json.loads(Path(j.result_path).read_text()) for j in jobs if Path(j.result_path).exists()]
    if len(gen) < len(jobs):
        print(f"  {len(jobs) - len(gen)} of {len(jobs)} generators did not finish (blocked by a saturated gateway?)")
    sent = sum(g["sent"] for g in gen)
    lost_seq = sum(d.get("lost", 0) for d in s1.get("devices", []))
    if sent != int(s1.get("received", 0)) or s1.get("rejected") or lost_seq:  # where were packets lost?
        seen = f"observer got {imu_seen[0]} of {sent} imu packets from zenoh" if count_imu else f"sent {sent}"
        print(f"  loss: {seen}, the gateway's callbacks "
              f"{s1.get('offered')} (summed over shards, {s1.get('ignored')} of them other shards' devices), its "
              f"ingest {s1.get('received')}; rejected {s1.get('rejected')}, "
              f"sequence gaps {lost_seq}")
    # packets in the measured window: what the gateway processed between the two CPU readings, from its diag
    # messages (at most 2 s old at either end); else the REST counters, whose window may be shorter (late answer)
    if ok0 is not None and ok1 is not None and ok1 > ok0:
        done = ok1 - ok0
    else:
        done = processed(s1) - processed(s0)
        print("  CPU per packet from the REST counters (no fresh gw/diag/ingest): unreliable under overload")
    if observe == "batch":
        print(f"  gw/attitudes: entries of {len(obs.batch_devices)} of {n} devices in the window")
    if threads:
        print_threads(th0, th1, gw.pid, done)
    cpu_ms = 1e3 * (cpu1 - cpu0) / max(1, done)
    expected_att = int(n * duration_s * RATE_HZ / spp)
    gen_share = sum(g["cpu_s"] for g in gen) / max(1e-9, max((g["wall_s"] for g in gen), default=1.0))
    return Row(
        n=n, shards=shards, sent=sent, received=int(s1.get("received", 0)), processed=processed(s1),
        queue_drops=int(s1.get("queue_drops", 0)), cpu_ms_per_packet=cpu_ms,
        attitude_p50_ms=pct(obs.attitude_ms, 0.5), attitude_p99_ms=pct(obs.attitude_ms, 0.99),
        attitudes=len(obs.attitude_ms), attitudes_expected=expected_att, alarms=len(obs.alarm_ms),
        alarm_p99_ms=pct(obs.alarm_ms, 0.99), rss_start_mib=rss[0] if rss else float("nan"),
        rss_end_mib=rss[-1] if rss else float("nan"), rss_max_mib=max(rss) if rss else float("nan"),
        generator_core_share=gen_share, observer_core_share=own_share, devices_seen=len(s1.get("devices", [])),
        rest_p50_s=pct(probe.latency_s, 0.5), rest_max_s=max(probe.latency_s, default=float("nan")),
        observe=observe, batch_devices=len(obs.batch_devices),
    )  # fmt: skip


def print_profile(path: Path, top: int = 25) -> None:
    """The parent's cProfile stats: the functions with the most cumulative time in its main thread."""
    import pstats

    if not path.exists():
        print(f"  no profile at {path} (the gateway did not exit cleanly)")
        return
    st = pstats.Stats(str(path))
    st.sort_stats("cumulative").print_stats("gateway/", top)
    st.sort_stats("tottime").print_stats(top)


def print_table(rows: Sequence[Row]) -> None:
    print(f"{'N':>5} {'sh':>2} {'sent':>8} {'received':>8} {'processed':>9} {'lost':>7} {'q.drop':>6} "
          f"{'CPU ms/pkt':>10} {'att p50':>8} {'att p99':>8} {'att rx/exp':>13} {'alarms':>6} "
          f"{'RSS MiB start/end/max':>22} {'gen core':>8} {'obs core':>8} {'REST p50/max s':>14}")
    for r in rows:
        lost = r.sent - r.processed
        print(f"{r.n:>5} {r.shards:>2} {r.sent:>8} {r.received:>8} {r.processed:>9} {lost:>7} {r.queue_drops:>6} "
              f"{r.cpu_ms_per_packet:>10.3f} {r.attitude_p50_ms:>8.1f} {r.attitude_p99_ms:>8.1f} "
              f"{r.attitudes:>6}/{r.attitudes_expected:<6} "
              f"{r.alarms:>6} {r.rss_start_mib:>7.0f}/{r.rss_end_mib:>6.0f}/{r.rss_max_mib:>6.0f} "
              f"{r.generator_core_share:>8.2f} {r.observer_core_share:>8.2f} {r.rest_p50_s:>6.2f}/{r.rest_max_s:<7.2f}")


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m bench.fleet", description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--counts", type=int, nargs="+", default=[100, 300, 1000], help="fleet sizes (default 100 300 1000)")
    p.add_argument("--hook-share", type=float, default=0.2, help="share of hooks in the fleet (default 0.2)")
    p.add_argument("--duration", type=float, default=30.0, help="measured seconds per fleet size (default 30)")
    p.add_argument("--warmup", type=float, default=8.0, help="seconds before measuring (filter warm-up; default 8)")
    p.add_argument("--samples-per-packet", type=int, default=5, help="samples per packet (default 5, as sim_rod)")
    p.add_argument("--shards", type=int, nargs="+", default=[1],
                   help="gateway shard processes (python -m gateway --shards S), each in turn (default 1)")
    p.add_argument("--procs", type=int, default=2, help="generator processes (default 2)")
    p.add_argument("--pool", type=int, default=16, help="distinct simulated streams per kind (default 16)")
    p.add_argument("--pool-seconds", type=float, default=20.0, help="length of each pooled stream (default 20 s)")
    p.add_argument("--count-imu", action="store_true",
                   help="the observer also counts the IMU packets zenoh delivers (where loss happens; ~0.1 core)")
    p.add_argument("--threads", action="store_true",
                   help="also print the gateway's CPU by process and thread (zenoh callback threads vs ingest)")
    p.add_argument("--profile", action="store_true",
                   help="run the gateway's parent process under cProfile and print its top functions per row")
    p.add_argument("--observe", choices=("devices", "batch"), default="devices",
                   help="the observer subscribes to every device's attitude key (gw/*/*/attitude, default) or to the "
                        "batched gw/attitudes (one message per shard batch)")
    p.add_argument("--json", type=Path, help="also write the rows as JSON to this file")
    p.add_argument("--encoding", choices=tuple(ENCODINGS), default="json",
                   help="IMU packets as JSON or protocol v2 binary (default json)")
    args = p.parse_args(argv)
    spp = args.samples_per_packet
    print(f"building the stream pool: {args.pool} rods + {args.pool} hooks x {args.pool_seconds:g} s ...", flush=True)
    pools = {kind: build_pool(kind, args.pool, args.pool_seconds, spp, seed=7, encoding=args.encoding)
             for kind in ("rod", "hook")}
    rows = []
    with tempfile.TemporaryDirectory(prefix="rig-fleet-") as tmp:
        work = Path(tmp)
        pool_path = work / "pool.pickle"
        pool_path.write_bytes(pickle.dumps(pools))
        for n in args.counts:
            for sh in args.shards:
                print(f"N = {n}, {sh} shard(s): {args.warmup:g} s warm-up + {args.duration:g} s measured ...",
                      flush=True)  # fmt: skip
                rows.append(run_one(n, args.hook_share, pools, pool_path, spp, args.procs, args.duration,
                                    args.warmup, work, args.encoding, sh, args.threads, args.profile,
                                    args.count_imu, args.observe))  # fmt: skip
                print_table(rows[-1:])
                if args.profile:
                    print_profile(work / f"gw-{n}-{sh}.prof")
                logs = (work / f"gw-{n}-{sh}.log").read_text(errors="replace").strip().splitlines()
                errors = [x for x in logs if "ERROR" in x or "Traceback" in x]
                if errors:
                    print(f"  gateway log: {len(errors)} error lines, first: {errors[0][:160]}")
    print(f"\nfleet at {RATE_HZ:g} Hz, {spp} samples/packet, {args.encoding} IMU packets, {args.hook_share:.0%} hooks, "
          f"{args.procs} generator process(es), {os.cpu_count()} cores; gateway = `python -m gateway --shards S` "
          f"(all its processes); observer on {'gw/attitudes' if args.observe == 'batch' else 'gw/*/*/attitude'}")
    print_table(rows)
    if args.json:
        args.json.write_text(json.dumps([r.__dict__ for r in rows], indent=1))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
