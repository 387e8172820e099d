"""Command-line options reach the pipeline, and attitude blocks go out on their own key with BLOCK."""

from __future__ import annotations

import itertools
import time
from pathlib import Path

import pytest

from gateway import schemas
from gateway.__main__ import build_parser, settings_from_args
from gateway.app import compose
from gateway.config import Settings
from gateway.ingest.bus import MemoryBus
from gateway.ingest.runner import pipeline_settings_from
from gateway.pipeline import PipelineSettings
from gateway.store import Store
from tests.gateway.conftest import rod_messages


def test_attitude_options_reach_the_pipeline(tmp_path: Path) -> None:
    args = build_parser().parse_args(["--data-dir", str(tmp_path), "--attitude-blocks", "--no-warmup-bias-seed",
                                      "--attitude-interval-s", "0", "--filter", "mahony"])  # fmt: skip
    ps = pipeline_settings_from(settings_from_args(args))
    assert (ps.attitude_blocks, ps.warmup_bias_seed, ps.attitude_interval_s, ps.default_filter) == (
        True, False, 0.0, "mahony")  # fmt: skip
    plain = pipeline_settings_from(settings_from_args(build_parser().parse_args(["--data-dir", str(tmp_path)])))
    d = PipelineSettings()
    assert (plain.attitude_blocks, plain.warmup_bias_seed, plain.attitude_interval_s) == (
        d.attitude_blocks, d.warmup_bias_seed, d.attitude_interval_s) == (False, True, 0.02)  # fmt: skip


def test_attitude_blocks_are_published_with_block_next_to_the_decimated_attitude(tmp_path: Path) -> None:
    bus = MemoryBus()
    imu = [(k, p) for k, p in rod_messages(1.0) if k.endswith("/imu")]
    with Store(tmp_path / "gw.sqlite3") as store:
        service = compose(Settings(data_dir=tmp_path, zenoh_listen=[], attitude_blocks=True,
                                   attitude_interval_s=0.1), bus, store, blocking_thread=False)
        for key, payload in imu:
            service.handle([(key, payload, time.monotonic())], now_wall_s=1e9)
    block_key, att_key = schemas.attitude_block_key("rod", "rod-1"), schemas.attitude_key("rod", "rod-1")
    blocks = [(schemas.AttitudeBlock.model_validate_json(p), b) for k, p, b in bus.sent if k == block_key]
    assert [m.seq for m, _ in blocks] == list(range(len(imu))) and all(b for _, b in blocks)
    atts = [(schemas.Attitude.model_validate_json(p), b) for k, p, b in bus.sent if k == att_key]
    assert not any(b for _, b in atts)  # DROP
    # 0.05 s packets, attitude every 0.1 s: every second packet; the warm-up's buffered packets end in one batch,
    # whose attitudes are coalesced to its newest (one per device per batch)
    seqs = [m.seq for m, _ in atts]
    assert all(b - a == 2 for a, b in itertools.pairwise(seqs)) and seqs[-1] >= len(imu) - 2, seqs


def test_the_gateway_is_a_zenoh_router_unless_a_mode_is_asked_for(monkeypatch: pytest.MonkeyPatch) -> None:
    """A router's receive threads cost a third of a peer's per packet (bench.fleet --threads): the default; an
    explicit `--mode peer` stays a peer with one shard, and with several the first process must route."""
    from gateway.__main__ import process_settings

    monkeypatch.delenv("RIG_ZENOH_MODE", raising=False)

    def mode(argv: list[str], shards: int) -> str:
        return process_settings(settings_from_args(build_parser().parse_args(argv)), shards).zenoh_mode

    assert mode([], 1) == "router" and mode([], 2) == "router"
    assert mode(["--mode", "peer"], 1) == "peer"
    assert mode(["--mode", "peer"], 2) == "router"
    assert mode(["--mode", "client", "--connect", "tcp/127.0.0.1:7999"], 1) == "client"


def test_the_coalescing_window_option_reaches_the_settings_and_a_local_shard(tmp_path: Path) -> None:
    from gateway.shard.launch import local_shard_command

    settings = settings_from_args(build_parser().parse_args(["--data-dir", str(tmp_path), "--ingest-coalesce-s",
                                                             "0.003"]))  # fmt: skip
    assert settings.ingest_coalesce_s == 0.003
    assert Settings(data_dir=tmp_path).ingest_coalesce_s == 0.01  # the default
    _, env = local_shard_command(settings, "s1", "WARNING")
    assert env["RIG_INGEST_COALESCE_S"] == "0.003"
