"""Shared command-line options of the recording commands: zenoh endpoints (same defaults as the devices)."""

from __future__ import annotations

import argparse
import json
import signal
import threading

import zenoh

GATEWAY_ENDPOINT = "tcp/127.0.0.1:7447"
"""Where the gateway listens by default (docs/protocol.md §1); recording tools connect there like devices do."""


def add_zenoh_args(parser: argparse.ArgumentParser) -> None:
    """`--mode`, `--connect EP` (repeatable, 'none' for none), `--listen EP` (repeatable), `--multicast`."""
    g = parser.add_argument_group("zenoh")
    g.add_argument("--mode", choices=["peer", "client"], default="peer", help="session mode (default: peer)")
    g.add_argument("--connect", action="append", metavar="ENDPOINT",
                   help=f"endpoint to connect to, repeatable (default: {GATEWAY_ENDPOINT}; 'none' for none)")
    g.add_argument("--listen", action="append", metavar="ENDPOINT", help="endpoint to listen on, repeatable")
    g.add_argument("--multicast", action="store_true", help="enable multicast scouting (default: off)")


def zenoh_config(args: argparse.Namespace) -> zenoh.Config:
    """A Config from `add_zenoh_args` options; connecting is retried in the background and never blocks."""
    connect = [c for c in (args.connect if args.connect is not None else [GATEWAY_ENDPOINT]) if c.lower() != "none"]
    conf = zenoh.Config()
    conf.insert_json5("mode", json.dumps(args.mode))
    conf.insert_json5("scouting/multicast/enabled", json.dumps(bool(args.multicast)))
    if connect:
        conf.insert_json5("connect/endpoints", json.dumps(connect))
        conf.insert_json5("connect/exit_on_failure", "false")
        retry = '{"period_init_ms": 250, "period_max_ms": 2000, "period_increase_factor": 2}'
        conf.insert_json5("connect/retry", retry)
    if args.listen:
        conf.insert_json5("listen/endpoints", json.dumps(args.listen))
    return conf


def stop_on_signals() -> threading.Event:
    """An event set by SIGINT or SIGTERM (Ctrl-C, a service manager): long-running record/export loops check it
    and end cleanly, flushing their files."""
    stop = threading.Event()
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, lambda _signum, _frame: stop.set())
    return stop
