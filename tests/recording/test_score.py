"""Scoring: a BROAD trial replayed through zenoh and the real gateway (`python -m gateway --attitude-blocks
--no-warmup-bias-seed`) scores exactly like the offline evaluate run (so nothing was lost, reordered or altered on
the way); attitude and attitude-block messages map back to their samples."""

from __future__ import annotations

import json
import subprocess
import sys
import time
from pathlib import Path
from types import SimpleNamespace

import httpx
import numpy as np
import pytest

from bench.bite_latency import free_port, stop_process
from gateway import schemas
from gateway.fusion import broad
from gateway.fusion.evaluate import registered_runner
from gateway.recording import score
from gateway.recording.format import Record, read_recording
from gateway.recording.import_broad import import_trial

pytestmark = pytest.mark.timeout(300)  # a first gateway start compiles the fusion kernels
REPO = Path(__file__).resolve().parents[2]


def cut_trial(trial: broad.Trial, rest_s: float = 1.0, move_s: float = 8.0) -> broad.Trial:
    """The first `rest_s` (the filter's rest window) joined to 0.5 s before the movement and `move_s` of it."""
    m0 = int(np.flatnonzero(trial.movement)[0])
    r = int(rest_s * trial.rate_hz)
    idx = np.r_[0:r, m0 - int(0.5 * trial.rate_hz) : m0 + int(move_s * trial.rate_hz)]
    return broad.Trial(f"{trial.name}_cut", trial.rate_hz, trial.gyr_rad_s[idx], trial.acc_m_s2[idx],
                       trial.mag_uT[idx], trial.quat_ref[idx], trial.pos_m[idx], trial.movement[idx], trial.groups)


def test_attitudes_map_to_their_samples_and_score_like_offline(tmp_path: Path, broad_dir: Path) -> None:
    trial = cut_trial(broad.load_trial(broad_dir / "08_undisturbed_fast_rotation_with_breaks_A.mat"), move_s=3.0)
    recs = list(read_recording(import_trial(trial, tmp_path, "b-1", "rod", samples_per_packet=10)))
    rt = score.recorded_trial(recs)
    out = registered_runner("mahony")(rt.trial, "9D")
    assert out is not None
    q = out[0]
    # what a gateway publishing the last sample of each packet would send
    atts = []
    for r in recs:
        if r.key.endswith("/imu"):
            p = schemas.decode(r.key, r.payload)
            assert isinstance(p, schemas.ImuPacket)
            i = rt.index(p.t0_us) + p.n - 1
            t_us = p.t0_us + round((p.n - 1) * 1e6 / p.rate_hz)
            atts.append(Record("gw/rod/b-1/attitude", schemas.Attitude(
                device_id="b-1", kind="rod", seq=p.seq, t_us=t_us, quat_wxyz=tuple(q[i]), roll_rad=0.0,
                pitch_rad=0.0, yaw_rad=0.0, yaw_unwrapped_rad=0.0, filter="mahony").to_json(), 0))  # fmt: skip
    got = score.attitudes_from_records(atts, "rod", "b-1")
    q_gw = score.attitude_array(rt, got)
    have = np.all(np.isfinite(q_gw), axis=1)
    assert have.sum() == len(atts) == -(-trial.n // 10)
    np.testing.assert_array_equal(np.flatnonzero(have), np.minimum(np.arange(len(atts)) * 10 + 9, trial.n - 1))
    c = score.compare(rt, q_gw, "mahony", "9D")
    assert c.max_diff_deg < 1e-9 and c.covered == len(atts)
    assert c.gateway.total_deg > 0.1  # a real error, not an empty mask
    full = broad.score(q, trial, "9D")
    assert c.offline_full == full


def test_attitude_blocks_map_every_sample(tmp_path: Path, broad_dir: Path) -> None:
    trial = cut_trial(broad.load_trial(broad_dir / "08_undisturbed_fast_rotation_with_breaks_A.mat"), move_s=1.0)
    recs = list(read_recording(import_trial(trial, tmp_path, "b-1", "rod", samples_per_packet=7)))
    rt = score.recorded_trial(recs)
    q = np.random.default_rng(0).normal(size=(trial.n, 4))
    q /= np.linalg.norm(q, axis=1, keepdims=True)
    blocks = []
    for r in recs:
        if r.key.endswith("/imu"):
            p = schemas.decode(r.key, r.payload)
            assert isinstance(p, schemas.ImuPacket)
            i = rt.index(p.t0_us)
            blocks.append(Record("gw/rod/b-1/attitude/block", schemas.AttitudeBlock(
                device_id="b-1", kind="rod", boot_id=p.boot_id, seq=p.seq, t0_us=p.t0_us, rate_hz=p.rate_hz,
                quat_wxyz=[tuple(x) for x in q[i : i + p.n].tolist()]).to_json(), 0))  # fmt: skip
    got = score.attitudes_from_records(blocks, "rod", "b-1")
    assert len(got) == -(-trial.n // 7) and all(isinstance(b, schemas.AttitudeBlock) for b in got)
    np.testing.assert_array_equal(score.attitude_array(rt, got), q)  # every sample, in place


def wait_http(port: int, proc: subprocess.Popen[bytes], log: Path, timeout_s: float = 150.0) -> None:
    """Until the gateway's REST answers (after its fusion kernels are compiled: slow on a cold cache)."""
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        assert proc.poll() is None, log.read_text()[-3000:]
        try:
            if httpx.get(f"http://127.0.0.1:{port}/api/health", timeout=1.0).status_code == 200:
                return
        except httpx.TransportError:
            pass
        time.sleep(0.2)
    raise AssertionError(f"gateway not up in {timeout_s} s: {log.read_text()[-3000:]}")


def test_ingest_stats_of_several_shards_merge_whichever_shard_owns_the_device() -> None:
    """Each shard sends its own `gw/diag/ingest` with only its devices; the score reads the sum, not the newest."""
    row = schemas.DeviceIngestCounters(device_id="b-1", kind="rod", ok=90, lost=0, duplicates=0, reordered=0,
                                       reboots=0)  # fmt: skip
    mine = schemas.IngestStats(wall_t_us=2, shard="s1", received=90, queue_drops=1, rejected={"bad_json": 2},
                               devices=[row])  # fmt: skip
    other = schemas.IngestStats(wall_t_us=3, shard="s2", received=90, queue_drops=0, rejected={"bad_json": 1})
    latest = score.LatestIngestStats()
    for msg in (mine, other, other):  # the other shard spoke last, and more often
        wire = msg.to_json()
        latest(SimpleNamespace(payload=SimpleNamespace(to_bytes=lambda wire=wire: wire)))  # type: ignore[arg-type]
    merged = latest.stats()
    assert merged is not None and merged.devices == [row]
    assert (merged.received, merged.queue_drops, merged.rejected, merged.wall_t_us) == (180, 1, {"bad_json": 3}, 3)
    assert score.merge_ingest_stats([]) is None


def test_broad_trial_through_zenoh_and_the_gateway_scores_like_evaluate(tmp_path: Path, broad_dir: Path) -> None:
    trial = cut_trial(broad.load_trial(broad_dir / "08_undisturbed_fast_rotation_with_breaks_A.mat"))
    rec = import_trial(trial, tmp_path, "b-1", "rod", samples_per_packet=10)
    port, http_port = free_port(), free_port()
    log = tmp_path / "gw.log"
    gw = subprocess.Popen([sys.executable, "-m", "gateway", "--attitude-blocks", "--no-warmup-bias-seed",
                           "--filter", "default", "--shards", "2", "--listen", f"tcp/127.0.0.1:{port}",
                           "--port", str(http_port), "--data-dir", str(tmp_path / "gw"), "--log-level", "WARNING"],
                          cwd=REPO,
                          stdout=subprocess.DEVNULL, stderr=open(log, "w"))  # noqa: SIM115 # fmt: skip
    try:
        wait_http(http_port, gw, log)
        out_json = tmp_path / "score.json"
        with open(out_json, "w") as f:
            rc = subprocess.run([sys.executable, "-m", "gateway.recording.score", str(rec), "--live", "--replay",
                                 "--speed", "0", "--idle-s", "2", "--check", "0.01", "--json", "--no-progress",
                                 "--connect", f"tcp/127.0.0.1:{port}"], cwd=REPO, stdout=f, timeout=150).returncode
    finally:
        stop_process(gw, 30.0)
    res = json.loads(out_json.read_text())
    ingest = res["gateway_ingest"]
    assert ingest["queue_drops"] == 0
    assert ingest["device"]["ok"] == -(-trial.n // 10) and ingest["device"]["lost"] == 0  # every packet fused
    assert res["covered"] == res["samples"] == trial.n  # every sample's attitude, none lost (blocks go out BLOCK)
    assert res["filter"] == "default" and res["mode"] == "9D"
    for k in ("total", "heading", "inclination"):
        assert res["gateway"][k] == pytest.approx(res["offline"][k], abs=1e-9)  # the same samples: identical
        assert res["gateway"][k] == pytest.approx(res["offline_all"][k], abs=0.01)
    assert res["gateway"]["total"] > 0.1
    assert res["max_diff_deg"] <= 0.01 and rc == 0
