"""Start every simulated device (rod, environment ball, hook) in one go: `python -m devices --help`.

Each device kind runs as its own subprocess (`python -m devices.sim_rod`, `devices.sim_env_ball`,
`devices.sim_hook`) with the shared zenoh options passed through; the hook is skipped with a warning when
`devices.sim_hook` is not installed. Ctrl-C (or --duration) stops them all.

Contract for a child module: `python -m devices.sim_<kind>` accepts the options of `common.add_zenoh_args` and
`common.add_fleet_args` (it is given `--mode --count --no-progress [--connect --listen --multicast --duration
--no-truth --seed]`) and exits 0 on --duration or SIGINT.
"""

from __future__ import annotations

import argparse
import importlib.util
import logging
import shlex
import signal
import subprocess
import sys
import time

from devices import common

log = logging.getLogger("devices")

KINDS = {"rod": "devices.sim_rod", "ball": "devices.sim_env_ball", "hook": "devices.sim_hook"}


def build_parser() -> argparse.ArgumentParser:
    """CLI of the launcher."""
    p = argparse.ArgumentParser(prog="python -m devices", description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    common.add_zenoh_args(p)
    p.add_argument("--only", choices=sorted(KINDS), action="append", help="start only these kinds (repeatable)")
    p.add_argument("--count", type=int, default=1, help="instances of each kind (default: 1)")
    p.add_argument("--seed", type=int, default=None, help="base random seed")
    p.add_argument("--duration", type=float, default=None, help="stop after this many seconds")
    p.add_argument("--random-events", action=argparse.BooleanOptionalAction, default=True,
                   help="random bites, fights, wind and handling on the rod (default: on)")
    p.add_argument("--truth", action=argparse.BooleanOptionalAction, default=True, help="publish ground truth")
    for kind in KINDS:
        p.add_argument(f"--{kind}-args", default="", metavar="ARGS", help=f"extra arguments for {KINDS[kind]}")
    return p


def child_commands(args: argparse.Namespace) -> dict[str, list[str]]:
    """The command line of each child process, by kind (the hook only when its module exists)."""
    shared: list[str] = ["--mode", args.mode, "--count", str(args.count), "--no-progress"]
    for ep in args.connect or []:
        shared += ["--connect", ep]
    for ep in args.listen or []:
        shared += ["--listen", ep]
    if args.multicast:
        shared.append("--multicast")
    if getattr(args, "zenoh_config", None) is not None:
        shared += ["--zenoh-config", str(args.zenoh_config)]
    if args.duration is not None:
        shared += ["--duration", str(args.duration)]
    if not args.truth:
        shared.append("--no-truth")
    cmds: dict[str, list[str]] = {}
    for offset, (kind, module) in enumerate(KINDS.items()):
        if args.only and kind not in args.only:
            continue
        if importlib.util.find_spec(module) is None:
            log.warning("%s is not available yet: no %s devices", module, kind)
            continue
        extra = shlex.split(getattr(args, f"{kind}_args"))
        if args.seed is not None:
            extra += ["--seed", str(args.seed + 1000 * offset)]
        if kind == "rod" and args.random_events:
            extra.append("--random-events")
        cmds[kind] = [sys.executable, "-m", module, *shared, *extra]
    return cmds


def main(argv: list[str] | None = None) -> int:
    """Start the children, wait for them, stop them all on Ctrl-C or when one fails."""
    logging.basicConfig(level=logging.INFO, format="%(levelname)s %(message)s")
    args = build_parser().parse_args(argv)
    common.stop_on_termination_signals()  # the gateway stops us with SIGTERM: pass it on, never orphan children
    procs = {kind: subprocess.Popen(cmd) for kind, cmd in child_commands(args).items()}
    if not procs:
        log.error("nothing to start")
        return 1
    log.info("started %s", ", ".join(f"{k} (pid {p.pid})" for k, p in procs.items()))
    rc = 0
    try:
        while procs:
            for kind, p in list(procs.items()):
                code = p.poll()
                if code is not None:
                    del procs[kind]
                    if code not in (0, -signal.SIGINT, 130):
                        log.error("%s exited with %s", kind, code)
                        rc = code
            time.sleep(0.2)
    except KeyboardInterrupt:
        rc = 130
    finally:
        common.ignore_termination_signals()
        for p in procs.values():
            p.send_signal(signal.SIGTERM)
        for p in procs.values():
            try:
                p.wait(timeout=5)
            except subprocess.TimeoutExpired:
                p.kill()
    return rc


if __name__ == "__main__":
    raise SystemExit(main())
