"""`python -m gateway --shards N`: this process is the first shard (with the REST endpoint people open) and the
zenoh router of the machine; it starts N - 1 more shard processes that connect to it as zenoh clients.

Local shards are full gateways (their own data directory `<data_dir>/shards/<id>`, REST on a free loopback port
that nobody needs to know) started with `--shard-child`: they adopt the parent's configuration at start and exit
when the parent goes away.
"""

from __future__ import annotations

import json
import os
import re
import socket
import subprocess
import sys
import threading
import time

from gateway.config import Settings

# settings a local shard inherits (through RIG_* variables; the zenoh and REST options are its own)
INHERITED = ("default_filter", "attitude_interval_s", "attitude_blocks", "warmup_bias_seed", "ingest_queue_size",
             "ingest_coalesce_s", "max_devices", "shard_devices", "shard_subscribe", "shard_lease_s", "shard_mirror_hz",
             "zenoh_config_file")  # fmt: skip


DEFAULT_MAX_SHARDS = 4  # each process costs ~250 MB and its own interpreter and kernels: more cost more than they give


def shard_count(settings: Settings) -> int:
    """`settings.shards`, or one per core this process may run on, at most DEFAULT_MAX_SHARDS."""
    return settings.shards or min(DEFAULT_MAX_SHARDS, len(os.sched_getaffinity(0)))


def default_shard_id(settings: Settings) -> str:
    """Host name and REST port: stable over restarts, so a restarted shard gets the same devices back."""
    host = re.sub(r"[^A-Za-z0-9_-]", "-", socket.gethostname())[:40] or "gw"
    return f"{host}-{settings.http_port}"


def parent_endpoints(settings: Settings) -> list[str]:
    """Where a local shard connects: the parent's router (its listen endpoints), or the parent's own router."""
    if settings.zenoh_mode == "client":
        return list(settings.zenoh_connect)
    return [e.replace("0.0.0.0", "127.0.0.1").replace("[::]", "[::1]") for e in settings.zenoh_listen]


def local_shard_command(settings: Settings, shard_id: str, log_level: str) -> tuple[list[str], dict[str, str]]:
    """argv and environment of one local shard process."""
    env = dict(os.environ)
    for name in INHERITED:
        value = getattr(settings, name)
        if value is not None:
            env[f"RIG_{name.upper()}"] = json.dumps(value) if isinstance(value, list | bool) else str(value)
    env["RIG_ZENOH_LISTEN"] = "[]"
    argv = [sys.executable, "-m", "gateway", "--shards", "1", "--shard-id", shard_id, "--shard-child",
            "--data-dir", str(settings.data_dir / "shards" / shard_id), "--port", "0", "--no-3d",
            "--mode", "client", "--log-level", log_level]  # fmt: skip
    for ep in parent_endpoints(settings):
        argv += ["--connect", ep]
    return argv, env


def start_local_shards(settings: Settings, shard_id: str, count: int, log_level: str) -> list[subprocess.Popen[bytes]]:
    """Start `count` more shards of this machine (ids `<shard_id>-1`, ...)."""
    procs = []
    for k in range(1, count + 1):
        argv, env = local_shard_command(settings, f"{shard_id}-{k}", log_level)
        procs.append(subprocess.Popen(argv, env=env))
    return procs


def stop_local_shards(procs: list[subprocess.Popen[bytes]]) -> None:
    for p in procs:
        p.terminate()
    for p in procs:
        try:
            p.wait(timeout=10)
        except subprocess.TimeoutExpired:
            p.kill()


def exit_with_parent(poll_s: float = 0.5) -> None:
    """A local shard ends (SIGTERM to itself: graceful) when the process that started it is gone."""
    import signal

    parent = os.getppid()

    def watch() -> None:
        while os.getppid() == parent:
            time.sleep(poll_s)
        os.kill(os.getpid(), signal.SIGTERM)

    threading.Thread(target=watch, name="shard-parent-watch", daemon=True).start()
