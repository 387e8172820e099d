"""Run the gateway: zenoh ingest, fusion and alarms, zenoh outputs and the REST API (`python -m gateway --help`).

By default the gateway is a zenoh peer that LISTENS on tcp/127.0.0.1:7447 with multicast scouting off, and the
devices (devices/common.py) connect to it; REST is served on http://127.0.0.1:8000 (docs at /docs).
Every option can also be set in the environment as RIG_<NAME> (e.g. RIG_HTTP_PORT=8001); options win.

    python -m gateway                      # gateway + REST only
    python -m gateway --with-devices       # also start the simulated rod, ball and hook (python -m devices)
"""

from __future__ import annotations

import argparse
import logging
import signal
import subprocess
import sys
from pathlib import Path
from typing import Any

from gateway.config import Settings


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="python -m gateway", description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)  # fmt: skip
    p.add_argument("--data-dir", type=Path, help="database and token file (default: ./var)")
    p.add_argument("--host", dest="http_host", help="REST bind address (default: 127.0.0.1)")
    p.add_argument("--port", dest="http_port", type=int, help="REST port (default: 8000)")
    z = p.add_argument_group("zenoh")
    z.add_argument("--mode", dest="zenoh_mode", choices=["peer", "client", "router"],
                   help="session mode (default: router, which devices and local shards connect to; "
                        "--mode peer keeps a peer)")  # fmt: skip
    z.add_argument("--listen", dest="zenoh_listen", action="append", metavar="ENDPOINT",
                   help="endpoint to listen on, repeatable (default: tcp/127.0.0.1:7447)")  # fmt: skip
    z.add_argument("--connect", dest="zenoh_connect", action="append", metavar="ENDPOINT",
                   help="endpoint to connect to, repeatable (default: none)")  # fmt: skip
    z.add_argument("--multicast", dest="zenoh_multicast_scouting", action="store_true", default=None,
                   help="enable multicast scouting (default: off)")  # fmt: skip
    z.add_argument("--zenoh-config", dest="zenoh_config_file", type=Path, metavar="FILE",
                   help="zenoh JSON5 config file (TLS/mTLS, user/password auth, access control: docs/security.md); "
                        "with it, only the zenoh options given explicitly override its keys")  # fmt: skip
    s = p.add_argument_group("browser access (DNS-rebinding and cross-site guards)")
    s.add_argument("--allowed-host", dest="allowed_hosts", action="append", metavar="NAME",
                   help="a host name the server answers to, besides IP addresses, localhost, dotless and .local "
                        "names; repeatable")  # fmt: skip
    s.add_argument("--allowed-origin", dest="allowed_origins", action="append", metavar="ORIGIN",
                   help="a browser origin (https://host:port) that may open /ws/stream without the token; repeatable")
    h = p.add_argument_group("shards (docs/gateway.md, Shards)")
    h.add_argument("--shards", type=int, metavar="N",
                   help="gateway processes on this machine sharing the devices; with N > 1 this process is also the "
                        "zenoh router the others connect to (default 0: one per core, at most 4; "
                        "docs/gateway.md)")  # fmt: skip
    h.add_argument("--shard-id", metavar="ID", help="this shard's id (default: host name and REST port)")
    h.add_argument("--devices", dest="shard_devices", action="append", metavar="GLOB",
                   help="serve only device ids matching this pattern, e.g. 'site1-*'; repeatable (default: all)")
    h.add_argument("--shard-subscribe", choices=("all", "own"),
                   help="beside other shards, subscribe to every device's data (all, default) or only to the devices "
                        "this shard serves (own: less traffic between machines; a new device's first packets may be "
                        "missed)")  # fmt: skip
    h.add_argument("--shard-child", action="store_true", help=argparse.SUPPRESS)  # a local shard of --shards N
    p.add_argument("--max-devices", type=int, metavar="N",
                   help="devices the gateway keeps state for; further new ids are dropped and counted (default: 1000)")
    p.add_argument("--filter", dest="default_filter", help="default attitude filter for rods (default: default)")
    p.add_argument("--ingest-coalesce-s", type=float, metavar="S",
                   help="a batch of fewer packets than its limit waits until its oldest is S old: less CPU per packet "
                        "at light load for up to S more latency (default: 0.01; 0: a batch per wake-up)")
    o = p.add_argument_group("attitude output (replay scoring, full-rate recording)")
    o.add_argument("--attitude-interval-s", type=float, metavar="S",
                   help="least device time between two gw/{kind}/{id}/attitude messages of a device; 0 = the last "
                        "sample of every packet (default: 0.02, i.e. at most 50 Hz)")  # fmt: skip
    o.add_argument("--attitude-blocks", action="store_true", default=None,
                   help="also publish every sample's attitude on gw/{kind}/{id}/attitude/block, one message per IMU "
                        "packet, with CongestionControl.BLOCK (default: off)")  # fmt: skip
    o.add_argument("--no-warmup-bias-seed", dest="warmup_bias_seed", action="store_false", default=None,
                   help="do not seed the gyro bias from a resting warm-up window; filters start from zero bias, as "
                        "the offline gateway.fusion.evaluate does (default: seed)")  # fmt: skip
    p.add_argument("--with-devices", action="store_true", help="also start the simulated devices (python -m devices)")
    p.add_argument("--devices-args", default="", metavar="ARGS", help="extra arguments for python -m devices")
    p.add_argument(
        "--no-3d",
        dest="view3d",
        action="store_false",
        help="do not start the viser 3-D view with the gateway (it then starts on the first /view3d)",
    )
    p.add_argument(
        "--prepare",
        action="store_true",
        help="compile and cache the fusion kernels, then exit (scripts/env.sh runs it after install)",
    )
    p.add_argument("--log-level", default="INFO", help="logging level (default: INFO)")
    return p


def settings_from_args(args: argparse.Namespace) -> Settings:
    """Settings from the environment (RIG_*) with the given options on top."""
    names = ("data_dir", "http_host", "http_port", "zenoh_mode", "zenoh_listen", "zenoh_connect",
             "zenoh_multicast_scouting", "default_filter", "attitude_interval_s", "attitude_blocks",
             "warmup_bias_seed", "zenoh_config_file", "allowed_hosts", "allowed_origins",
             "max_devices", "shards", "shard_id", "shard_devices", "shard_subscribe", "ingest_coalesce_s")  # fmt: skip
    overrides: dict[str, Any] = {n: getattr(args, n) for n in names if getattr(args, n) is not None}
    return Settings(**overrides)


def process_settings(settings: Settings, n_shards: int) -> Settings:
    """The settings this process runs with: its shard id, and the zenoh mode and endpoints its role needs."""
    from gateway.shard import launch

    update: dict[str, Any] = {"shard_id": settings.shard_id or launch.default_shard_id(settings)}
    if settings.zenoh_mode == "client" and "zenoh_listen" not in settings.model_fields_set:
        update["zenoh_listen"] = []  # a client reaches everything through its router (a shard on another machine)
    if settings.zenoh_mode == "peer" and (n_shards > 1 or "zenoh_mode" not in settings.model_fields_set):
        # The local shards are its clients: it relays the devices' data to them. With one shard too: as a router
        # zenoh's receive threads cost a third of what they cost in peer mode for the same packets (bench.fleet
        # --threads, 300 devices: 0.04 vs 0.10-0.13 ms per packet); devices connect to it as before.
        update["zenoh_mode"] = "router"
    return settings.model_copy(update=update)


def device_command(settings: Settings, extra: str) -> list[str]:
    """`python -m devices` connected to where this gateway listens."""
    import shlex

    endpoints = [e.replace("0.0.0.0", "127.0.0.1") for e in settings.zenoh_listen] or ["tcp/127.0.0.1:7447"]
    cmd = [sys.executable, "-m", "devices"]
    for ep in endpoints:
        cmd += ["--connect", ep]
    return cmd + shlex.split(extra)


def prepare(settings: Settings) -> int:
    """Compile the numba kernels the gateway runs (numba caches them in __pycache__), with a progress line."""
    import time

    t0 = time.perf_counter()
    print("[prepare] compiling the fusion kernels (once after install; ~40 s on 2 cores)...", file=sys.stderr,
          flush=True)  # fmt: skip
    from gateway.ingest.runner import pipeline_settings_from
    from gateway.pipeline import Pipeline

    Pipeline(pipeline_settings_from(settings)).warm_up()
    # Once more in a fresh process: numba keeps a kernel it compiled as another kernel's callee under that signature,
    # and a new process calling it directly looked it up under another and compiled `_step_context` again (39 s at
    # the first gateway start after this command, 2 s at later ones). Done here, the first start is as fast.
    import subprocess

    subprocess.run([sys.executable, "-c", "from gateway.pipeline import Pipeline; Pipeline().warm_up()"], check=False)
    print(f"[prepare] fusion kernels ready in {time.perf_counter() - t0:.1f} s", file=sys.stderr, flush=True)
    return 0


def _terminate(signum: int, frame: object) -> None:
    raise SystemExit(128 + signum)


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    logging.basicConfig(level=args.log_level.upper(), format="%(asctime)s %(levelname)s %(name)s: %(message)s")
    settings = settings_from_args(args)
    if args.prepare:
        return prepare(settings)
    import uvicorn

    from gateway.app import create_app
    from gateway.shard import launch

    n_shards = launch.shard_count(settings)
    settings = process_settings(settings, n_shards)
    if args.shard_child:
        launch.exit_with_parent()

    # uvicorn shuts down gracefully on SIGTERM, then re-raises it; with Python's default disposition that kills the
    # process before `finally`, orphaning the devices. As an exception it unwinds through the cleanup below.
    signal.signal(signal.SIGTERM, _terminate)
    devices: list[subprocess.Popen[bytes]] = []
    shards = launch.start_local_shards(settings, str(settings.shard_id), n_shards - 1, args.log_level)

    def start_devices() -> None:  # when the gateway is ready: the simulators do not slow its warm-up
        devices.append(subprocess.Popen(device_command(settings, args.devices_args)))

    try:
        app = create_app(settings, start_view3d=args.view3d, on_ready=start_devices if args.with_devices else None,
                         adopt_config=args.shard_child, announce=not args.shard_child)  # fmt: skip
        uvicorn.run(app, host=settings.http_host, port=settings.http_port, log_level="warning")
    finally:
        launch.stop_local_shards(shards)
        for p in devices:
            p.terminate()
            try:
                p.wait(timeout=10)
            except subprocess.TimeoutExpired:
                p.kill()
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
