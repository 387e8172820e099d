"""A headless gateway for scoring replays: the real ingest + pipeline + hub, with one attitude per packet end
(no 50 Hz decimation), no gyro-bias seed from the warm-up window, and every output published with
CongestionControl.BLOCK (the normal gateway DROPs attitude under bursts), so a 1-sample-per-packet replay gets the
same attitude for every sample as the offline `gateway.fusion.evaluate` run. No REST, no dashboard.

    python -m gateway.recording.exact_gateway --filter default --listen tcp/127.0.0.1:7447

Until `python -m gateway` offers these two pipeline options, this is how to check the live path end to end.
"""

from __future__ import annotations

import argparse
import asyncio
import logging
import signal
import tempfile
from collections.abc import Sequence
from pathlib import Path

from gateway.config import Settings
from gateway.ingest.bus import PresenceCallback, QueryHandler, SampleCallback, ZenohBus
from gateway.ingest.runner import GatewayService
from gateway.pipeline import PipelineSettings
from gateway.store import Store

log = logging.getLogger("gateway.recording")


def exact_pipeline_settings(filter_name: str) -> PipelineSettings:
    """Every packet end published; the warm-up never counts as rest, so no bias seed (evaluate has none)."""
    return PipelineSettings(default_filter=filter_name, attitude_interval_s=0.0, rest_gyr_std_rad_s=0.0)


class BlockingBus:
    """A Bus that publishes everything with CongestionControl.BLOCK: a scoring run must not lose outputs."""

    def __init__(self, inner: ZenohBus) -> None:
        self.inner = inner

    def subscribe(self, selector: str, callback: SampleCallback) -> None:
        self.inner.subscribe(selector, callback)

    def put(self, key: str, payload: bytes, *, encoding: str, block: bool = False) -> None:
        self.inner.put(key, payload, encoding=encoding, block=True)

    def watch_liveliness(self, selector: str, callback: PresenceCallback) -> None:
        self.inner.watch_liveliness(selector, callback)

    def declare_token(self, key: str) -> None:
        self.inner.declare_token(key)

    def declare_queryable(self, selector: str, handler: QueryHandler, *, encoding: str) -> None:
        self.inner.declare_queryable(selector, handler, encoding=encoding)

    def close(self) -> None:
        self.inner.close()


async def serve(settings: Settings, filter_name: str, stop: asyncio.Event) -> None:
    """Run the gateway service until `stop` is set; the bus and store are always closed."""
    store = Store(settings.db_path)
    bus = BlockingBus(ZenohBus.open(settings))
    service = GatewayService(settings, bus, store, exact_pipeline_settings(filter_name))
    try:
        await service.start()
        print(f"exact gateway ready on {', '.join(settings.zenoh_listen)}", flush=True)
        await stop.wait()
    finally:
        await service.stop()
        bus.close()
        store.close()


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="python -m gateway.recording.exact_gateway", description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)  # fmt: skip
    p.add_argument("--filter", default="default", help="filter for rods (default: default)")
    p.add_argument("--listen", action="append", metavar="ENDPOINT", help="default: tcp/127.0.0.1:7447")
    p.add_argument("--connect", action="append", metavar="ENDPOINT", help="endpoint to connect to, repeatable")
    p.add_argument("--data-dir", type=Path, help="store directory (default: a temporary one)")
    return p


def main(argv: Sequence[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    logging.basicConfig(level=logging.WARNING, format="%(asctime)s %(levelname)s %(name)s: %(message)s")
    with tempfile.TemporaryDirectory() as tmp:
        settings = Settings(data_dir=args.data_dir or Path(tmp), zenoh_listen=args.listen or ["tcp/127.0.0.1:7447"],
                            zenoh_connect=args.connect or [], default_filter=args.filter)  # fmt: skip
        settings.data_dir.mkdir(parents=True, exist_ok=True)

        async def run() -> None:
            stop = asyncio.Event()
            loop = asyncio.get_running_loop()
            for sig in (signal.SIGINT, signal.SIGTERM):
                loop.add_signal_handler(sig, stop.set)
            await serve(settings, args.filter, stop)

        asyncio.run(run())
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
