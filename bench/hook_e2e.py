"""Crane-hook swing end to end over zenoh: hook device process -> gateway process -> `gw/hook/*/swing`, compared with
ground truth: RMSE of swing angle Θ, swing direction (displacement bearing, where Θ > 0.5°) and torsion φ.

The device process simulates `devices.hook_physics` (spherical pendulum + torsion, exact IMU truth) through the
shared IMU error model (`devices.common.SensorModel`, MPU-6050/HMC5883L class) and publishes `rig/hook/{id}/imu`
(5 samples per packet at 100 Hz) and `rig/hook/{id}/truth` with the shared fleet runtime. Scenario: hanging still
for `--still` s, then a trolley traverse that starts the swing, with gusty torque on the rope twisting the hook.
Each swing message (last sample of packet `seq`) is matched with the truth of the same `seq`. Target:
swing-angle RMSE <= 0.1°.

    python -m bench.hook_e2e --duration 40
"""

from __future__ import annotations

import argparse
import math
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

import numpy as np
import zenoh

from bench.bite_latency import REPO, Recorder, free_port, observer_config, start_gateway, wait_http
from devices import common
from devices.common import FleetSettings, ImuErrorModel, Message, SensorModel
from devices.hook_physics import HookPhysicsSettings, HookScenario, simulate, trolley_traverse
from gateway import schemas


class HookFleet:
    """One simulated hook playing a precomputed scenario (implements devices.common.Fleet)."""

    kind = "hook"
    command_selectors: tuple[str, ...] = ()

    def __init__(self, fleet: FleetSettings, duration_s: float, still_s: float, seed: int) -> None:
        self.fleet = fleet
        self.ids = fleet.ids
        scenario = HookScenario(
            duration_s=duration_s + 1.0, output_rate_hz=fleet.rate_hz,
            trolley_moves=trolley_traverse(still_s, 4.0, math.radians(30.0), acc_m_s2=0.4),
            wind_torque_std_n_m=10.0, wind_tau_s=2.0, seed=seed,
        )  # fmt: skip
        self.truth = simulate(HookPhysicsSettings(), scenario)
        rng = np.random.default_rng(seed)
        self.sensor = SensorModel(ImuErrorModel(), 1, rng)
        self.clock = common.DeviceClock.start(rng)
        self.boot_id = common.new_boot_id(rng)

    def on_command(self, key: str, payload: bytes) -> None:
        del key, payload

    def tick(self, k: int) -> tuple[list[list[Message]], list[Message]]:
        n, tr, dev = self.fleet.samples_per_packet, self.truth, self.ids[0]
        sl = slice(k * n, (k + 1) * n)
        dt = 1.0 / self.fleet.rate_hz
        gyr, acc, mag = self.sensor.measure(tr.gyr_rad_s[sl], tr.acc_m_s2[sl], tr.mag_uT[sl], dt)
        t0_us = self.clock.boot_offset_us + int(round(k * n * dt * 1e6))
        wall = self.clock.wall_us(t0_us)
        imu = common.imu_payload(device_id=dev, kind="hook", boot_id=self.boot_id, seq=k, t0_us=t0_us,
                                 rate_hz=self.fleet.rate_hz, gyr_rad_s=common.rows(gyr, 6),
                                 acc_m_s2=common.rows(acc, 5), mag_uT=None if mag is None else common.rows(mag, 3),
                                 wall_t0_us=wall)  # fmt: skip
        truth = schemas.HookTruth(
            v=1, device_id=dev, boot_id=self.boot_id, seq=k, t0_us=t0_us, rate_hz=self.fleet.rate_hz,
            wall_t0_us=wall, quat_wxyz=[tuple(map(float, q)) for q in tr.quat[sl]],  # type: ignore[misc]
            swing_angle_rad=[float(x) for x in tr.swing_rad[sl]],
            swing_direction_rad=[float(x) for x in tr.swing_bearing_rad[sl]],
            torsion_rad=[float(math.remainder(x, 2 * math.pi)) for x in tr.torsion_rad[sl]], rope_length_m=10.0,
        )  # fmt: skip
        return [[Message(schemas.imu_key("hook", dev), imu, schemas.ENCODING_IMU)]], [
            Message(schemas.truth_key("hook", dev), truth.to_json(), schemas.ENCODING_TRUTH)]


def run_device(port: int, duration_s: float, still_s: float, seed: int) -> None:
    fleet = FleetSettings(count=1, seed=seed, rate_hz=100.0, samples_per_packet=5, duration_s=duration_s,
                          id_prefix="hook", progress=False)  # fmt: skip
    hooks = HookFleet(fleet, duration_s, still_s, seed)
    with zenoh.open(common.zenoh_config("peer", [f"tcp/127.0.0.1:{port}"])) as session:
        common.run_fleet(session, hooks, fleet)


def wrap(x: np.ndarray[Any, Any]) -> np.ndarray[Any, Any]:
    return np.angle(np.exp(1j * x))


def analyse(rec: Recorder, skip_s: float = 1.0) -> dict[str, float]:
    """RMSEs in degrees over matched (seq) swing / truth pairs, after the first `skip_s` of swing output."""
    truth = {p.seq: p for _, p in rec.decoded("/truth") if isinstance(p, schemas.HookTruth)}
    swings = [s for _, s in rec.decoded("/swing")]
    pairs = [(s, truth[s["seq"]]) for s in swings if s["seq"] in truth]
    if not pairs:
        return {"n": 0}
    t_first = pairs[0][0]["t_us"]
    pairs = [(s, t) for s, t in pairs if s["t_us"] - t_first >= skip_s * 1e6]
    est = np.array([[s["swing_angle_rad"], s["swing_direction_rad"], s["torsion_rad"]] for s, _ in pairs])
    ref = np.array([[t.swing_angle_rad[-1], t.swing_direction_rad[-1], t.torsion_rad[-1]] for _, t in pairs])
    swinging = ref[:, 0] > math.radians(0.5)
    deg = 180.0 / math.pi
    return {
        "n": float(len(pairs)),
        "swing_angle_rmse_deg": float(np.sqrt(np.mean((est[:, 0] - ref[:, 0]) ** 2)) * deg),
        "swing_angle_max_deg": float(np.max(ref[:, 0]) * deg),
        "direction_rmse_deg": float(np.sqrt(np.mean(wrap(est[swinging, 1] - ref[swinging, 1]) ** 2)) * deg)
        if swinging.any() else math.nan,
        "torsion_rmse_deg": float(np.sqrt(np.mean(wrap(est[:, 2] - ref[:, 2]) ** 2)) * deg),
        "torsion_max_deg": float(np.max(np.abs(ref[:, 2])) * deg),
    }  # fmt: skip


def run_session(duration_s: float, still_s: float, seed: int, work: Path) -> tuple[Recorder, int]:
    """Gateway + hook processes with an observer session; returns what it saw and the device's exit code."""
    import subprocess

    zport, hport = free_port(), free_port()
    gw = start_gateway(work / "data", zport, hport, work / "gateway.log")
    rec = Recorder()
    try:
        wait_http(hport)
        with zenoh.open(observer_config(zport)) as session:
            subs = [session.declare_subscriber(sel, rec) for sel in ("gw/hook/*/swing", "rig/hook/*/truth")]
            time.sleep(0.5)
            dev = subprocess.run(
                [sys.executable, "-m", "bench.hook_e2e", "--device", "--port", str(zport), "--duration",
                 str(duration_s), "--still", str(still_s), "--seed", str(seed)],
                cwd=REPO, capture_output=True, timeout=duration_s + 120,
            )  # fmt: skip
            time.sleep(1.0)
            for s in subs:
                s.undeclare()  # type: ignore[no-untyped-call]
    finally:
        gw.terminate()
        try:
            gw.wait(timeout=15)
        except subprocess.TimeoutExpired:
            gw.kill()
    if dev.returncode != 0:
        print(dev.stderr.decode()[-2000:], file=sys.stderr)
    return rec, dev.returncode


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m bench.hook_e2e", description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)  # fmt: skip
    p.add_argument("--duration", type=float, default=40.0, help="seconds of hook data (default: 40)")
    p.add_argument("--still", type=float, default=3.0, help="seconds hanging still before the trolley moves")
    p.add_argument("--seed", type=int, default=1)
    p.add_argument("--device", action="store_true", help="(internal) run the hook device process")
    p.add_argument("--port", type=int, default=7447, help="(with --device) gateway zenoh port")
    args = p.parse_args(argv)
    if args.device:
        run_device(args.port, args.duration, args.still, args.seed)
        return 0
    with tempfile.TemporaryDirectory() as tmp:
        print(f"running {args.duration:g} s of hook data through zenoh and the gateway ...", file=sys.stderr)
        rec, code = run_session(args.duration, args.still, args.seed, Path(tmp))
    r = analyse(rec)
    print(f"matched swing messages: {r['n']:.0f} (device exit code {code})")
    if r["n"]:
        print(f"swing angle RMSE {r['swing_angle_rmse_deg']:.3f} deg "
              f"(max true swing {r['swing_angle_max_deg']:.2f} deg)")
        print(f"swing direction RMSE {r['direction_rmse_deg']:.2f} deg (where swing > 0.5 deg)")
        print(f"torsion RMSE {r['torsion_rmse_deg']:.2f} deg (max true torsion {r['torsion_max_deg']:.1f} deg)")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
