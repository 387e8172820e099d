"""A zenoh router as a Python session, for shards and devices on several machines (`python -m gateway.shard.router`).

No zenohd binary is on PyPI; a session opened in router mode relays between its clients and peers (NOTES-zenoh-viser
§1). Shards connect to it with `--mode client --connect tcp/<router>:7447`, devices with `--connect` to the same
endpoint. It runs no gateway code: it only routes.

    python -m gateway.shard.router --listen tcp/0.0.0.0:7447
    python -m gateway.shard.router --listen tcp/0.0.0.0:7447 --zenoh-config secure.json5   # TLS / ACL (security.md)
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path

import zenoh

from gateway.recording._cli import stop_on_signals


def router_config(listen: list[str], connect: list[str], config_file: Path | None = None) -> zenoh.Config:
    """Router mode, multicast scouting off, the given endpoints (over the file's keys when one is given)."""
    conf = zenoh.Config() if config_file is None else zenoh.Config.from_file(str(config_file))
    conf.insert_json5("mode", '"router"')
    conf.insert_json5("scouting/multicast/enabled", "false")
    if listen:
        conf.insert_json5("listen/endpoints", json.dumps(listen))
    if connect:
        conf.insert_json5("connect/endpoints", json.dumps(connect))
    return conf


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m gateway.shard.router", description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)  # fmt: skip
    p.add_argument("--listen", action="append", metavar="ENDPOINT", help="repeatable (default: tcp/127.0.0.1:7447)")
    p.add_argument("--connect", action="append", default=[], metavar="ENDPOINT", help="another router, repeatable")
    p.add_argument("--zenoh-config", type=Path, metavar="FILE", help="zenoh JSON5 config file as the base")
    args = p.parse_args(argv)
    stop = stop_on_signals()
    listen = args.listen or ["tcp/127.0.0.1:7447"]
    with zenoh.open(router_config(listen, args.connect, args.zenoh_config)):
        print(f"zenoh router listening on {', '.join(listen)}", file=sys.stderr, flush=True)
        stop.wait()
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
