"""Crane-hook swing end to end over zenoh: hook device process -> gateway process -> `gw/hook/*/swing`, compared
with ground truth: RMSE of swing angle Θ, swing direction (displacement bearing, where Θ > 0.5°) and torsion φ.

The device process simulates `devices.hook_physics` with the simulator's own physics (`devices.sim_hook`
defaults: l = 10 m, g = 9.80665 m/s², air damping 0.002 1/s) through the shared IMU error model
(`devices.common.SensorModel`, MPU-6050/HMC5883L class: ~1 °/s gyro bias, 1 % scale, 0.5 % misalignment,
5 µT hard iron) and publishes `rig/hook/{id}/imu` (5 samples per packet at 100 Hz) and `rig/hook/{id}/truth`.
Each swing message (last sample of packet `seq`) is matched with the truth of the same `seq`.

Scenarios (the hook hangs still for `--still` s first; the gateway warms up on the first 0.5 s):

- `free` (default): a 2 s trolley jerk (1.6 m/s² for 1 s towards 40°, then back) sets a ~5° swing that then
  swings freely, with gusty torque about the rope (`--twist-torque`, default 2 N·m std as `devices.sim_hook`).
  The jerk is 3-10× a crane trolley's: measured 0.14° free-swing RMSE in process (docs/fusion.md).
- `traverse`: a 4 m start-cruise-stop trolley move at 0.4 m/s² and strong torque gusts (10 N·m std, the hook
  twists by ±100° at up to 100 °/s). The boom tip's acceleration is unobservable from the hook (see
  gateway.fusion.hook_filter), so Θ during the move is not scored in the free-swing window.
- `suite:SEED`: bench.hook_suite's randomised crane of that seed (its physics and the calibrated IMU preset; the
  rope length is set with `PUT /api/thresholds/hook` first, as a user would, unless `--no-length`); `--still`
  does not apply.
  `suite:SEED:1`: the same from the suite's generator version 1 (before its hoist fix; default: its default, 2).
  `--imu` picks the board's preset; `--iron-told` sets the compass calibration a twist by hand of that hook with the
  device's board gives (`calibrate --hook-mount`, docs/calibration.md) over REST first.

Windows, in scenario time (device time since its first sample): *free swing* from the end of the excitation plus
`--settle` s (default 12 s, as bench.hook_accuracy) to the end; *all* from 1 s after the first swing message.
Torsion is compared as the gateway reports it: relative to the hook's heading at the first fused sample (unless a
rest heading is configured), against the truth's twist relative to its value at that sample. `--rest-heading`
(suite:SEED): the crane's true rest heading is set over REST with its rope length, so the torsion is compared as it
is, and each Swing's `torsion_std_rad` is scored too: the shares of torsion errors within 1, 2 and 3 of its σ.

With `--compare` the received IMU packets are also run through VQF (offline, same samples, same geometry
functions, same windows) for comparison. `--in-process` skips zenoh and both processes (same packets straight
into `gateway.pipeline.Pipeline`), and prints the pipeline's cost per hook packet.

    python -m bench.hook_e2e --duration 40
    python -m bench.hook_e2e --scenario traverse --duration 40 --compare
"""

from __future__ import annotations

import argparse
import dataclasses
import math
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import zenoh
from tqdm import tqdm

from bench.bite_latency import REPO, Recorder, free_port, observer_config, start_gateway, stop_process, wait_http
from bench.hook_torsion_std import coverage
from devices import common
from devices.common import FleetSettings, ImuErrorModel, Message, SensorModel
from devices.hook_physics import HookPhysicsSettings, HookScenario, TrolleyMove, simulate, trolley_traverse
from devices.sim_hook import crane_message
from gateway import schemas
from gateway.fusion import hook as hook_geo

RATE_HZ = 100.0
SAMPLES_PER_PACKET = 5
SCENARIOS = ("free", "traverse")


@dataclass(frozen=True)
class Case:
    """A scenario and the scenario time (s) at which its scripted excitation ends; a suite crane brings its own
    physics and the calibrated IMU preset (as bench.hook_suite), the others use the simulator's."""

    scenario: HookScenario
    excitation_end_s: float
    physics: HookPhysicsSettings | None = None
    imu: str = "legacy"


def physics() -> HookPhysicsSettings:
    """The simulator's physics (as `python -m devices.sim_hook` builds it with its defaults)."""
    return HookPhysicsSettings(rope_length_m=10.0, gravity_m_s2=common.G_M_S2, earth_field_uT=common.EARTH_FIELD_ENU_UT,
                               swing_damping_1_s=0.002)  # fmt: skip


def make_case(name: str, duration_s: float, still_s: float, seed: int, twist_torque_n_m: float | None,
              imu: str | None = None) -> Case:  # fmt: skip
    """The scenario `name` (see the module docstring); `twist_torque_n_m` overrides its gust torque. `suite:SEED` is
    bench.hook_suite's crane of that seed (`still_s` and the torque are ignored), `suite:SEED:VERSION` from that
    version of its generator. `imu`: the board's error preset instead of the scenario's."""
    case = _make_case(name, duration_s, still_s, seed, twist_torque_n_m)
    return case if imu is None else dataclasses.replace(case, imu=imu)


def _make_case(name: str, duration_s: float, still_s: float, seed: int, twist_torque_n_m: float | None) -> Case:
    if name.startswith("suite:"):
        from bench.hook_suite import SUITE_VERSION
        from bench.hook_suite import make_case as suite_case

        _, seed_text, *version = name.split(":")
        sc = suite_case(int(seed_text), duration_s + 1.0, suite_version=int(version[0]) if version else SUITE_VERSION)
        return Case(sc.scenario, 0.0, sc.physics, "calibrated")
    if name == "free":
        a, b = 1.6, math.radians(40.0)
        moves: tuple[TrolleyMove, ...] = (
            TrolleyMove(still_s, 1.0, (a * math.cos(b), a * math.sin(b))),
            TrolleyMove(still_s + 1.0, 1.0, (-a * math.cos(b), -a * math.sin(b))),
        )
        torque = 2.0
    elif name == "traverse":
        moves, torque = trolley_traverse(still_s, 4.0, math.radians(30.0), acc_m_s2=0.4), 10.0
    else:
        raise ValueError(f"unknown scenario {name!r}; known: {', '.join(SCENARIOS)}")
    scenario = HookScenario(
        duration_s=duration_s + 1.0, output_rate_hz=RATE_HZ, trolley_moves=moves,
        wind_torque_std_n_m=torque if twist_torque_n_m is None else twist_torque_n_m, wind_tau_s=2.0, seed=seed,
    )  # fmt: skip
    end = max(m.start_s + m.duration_s for m in moves)
    return Case(scenario, end)


class HookFleet:
    """One simulated hook playing a precomputed scenario (implements devices.common.Fleet)."""

    kind = "hook"
    command_selectors: tuple[str, ...] = ()

    def __init__(self, fleet: FleetSettings, case: Case, seed: int, crane_feed: bool = False) -> None:
        self.fleet, self.scenario, self.crane_feed = fleet, case.scenario, crane_feed
        self.ids = fleet.ids
        self.physics = case.physics or physics()
        self.truth = simulate(self.physics, case.scenario)
        rng = np.random.default_rng(seed)
        self.sensor = SensorModel(ImuErrorModel.preset(case.imu), 1, rng)
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
            torsion_rad=[float(math.remainder(x, 2 * math.pi)) for x in tr.torsion_rad[sl]],
            rope_length_m=self.physics.rope_length_m,
        )  # fmt: skip
        data = [Message(schemas.imu_key("hook", dev), imu, schemas.ENCODING_IMU)]
        if self.crane_feed:  # the crane tells its boom tip's acceleration at the same samples (docs/protocol.md 3.7)
            data.append(crane_message(self.scenario, tr.t_s[sl], device_id=dev, boot_id=self.boot_id, seq=k,
                                      wall_t0_us=wall, rate_hz=self.fleet.rate_hz))  # fmt: skip
        return [data], [Message(schemas.truth_key("hook", dev), truth.to_json(), schemas.ENCODING_TRUTH)]


def fleet_settings(duration_s: float, seed: int, link: common.LinkModel | None = None) -> FleetSettings:
    """The hook device's settings; `link`: packet loss on its way (the truth mirror shares each packet's fate)."""
    return FleetSettings(count=1, seed=seed, rate_hz=RATE_HZ, samples_per_packet=SAMPLES_PER_PACKET,
                         duration_s=duration_s, id_prefix="hook", progress=False,
                         link=link or common.LinkModel())  # fmt: skip


def run_device(port: int, case: Case, duration_s: float, seed: int, link: common.LinkModel | None = None,
               crane_feed: bool = False) -> None:  # fmt: skip
    fleet = fleet_settings(duration_s, seed, link)
    with zenoh.open(common.zenoh_config("peer", [f"tcp/127.0.0.1:{port}"])) as session:
        common.run_fleet(session, HookFleet(fleet, case, seed, crane_feed), fleet)


def wrap(x: np.ndarray[Any, Any]) -> np.ndarray[Any, Any]:
    return np.angle(np.exp(1j * x))


def _scenario_t_s(t: schemas.HookTruth) -> float:
    """Scenario time of a truth packet's last sample (packet `seq` k starts at sample k·n)."""
    n = len(t.swing_angle_rad)
    return (t.seq * n + n - 1) / t.rate_hz


def score(est: np.ndarray[Any, Any], ref: np.ndarray[Any, Any], t_s: np.ndarray[Any, Any], start_s: float,
          ref_torsion0_rad: float, heading_offset_rad: float = math.nan) -> dict[str, float]:  # fmt: skip
    """RMSEs in degrees of rows `[Θ, bearing, φ]` (est vs ref) with `t_s >= start_s`; truth torsion taken relative to
    `ref_torsion0_rad` (its value where the estimate's reference heading was taken). `heading_offset_rad`: the
    estimate's reference heading minus the true one; the bearing error after removing it is `direction_rel`."""
    keep = t_s >= start_s
    est, ref = est[keep], ref[keep]
    if not len(est):
        return {"n": 0.0}
    swinging = ref[:, 0] > math.radians(0.5)
    deg = 180.0 / math.pi
    tors_err = wrap(est[:, 2] - (ref[:, 2] - ref_torsion0_rad))
    rel_err = wrap(est[swinging, 1] - ref[swinging, 1] - heading_offset_rad)
    return {
        "n": float(len(est)),
        "swing_angle_rmse_deg": float(np.sqrt(np.mean((est[:, 0] - ref[:, 0]) ** 2)) * deg),
        "swing_angle_maxerr_deg": float(np.max(np.abs(est[:, 0] - ref[:, 0])) * deg),
        "swing_angle_max_deg": float(np.max(ref[:, 0]) * deg),
        "direction_rmse_deg": float(np.sqrt(np.mean(wrap(est[swinging, 1] - ref[swinging, 1]) ** 2)) * deg)
        if swinging.any() else math.nan,
        "direction_rel_rmse_deg": float(np.sqrt(np.mean(rel_err**2)) * deg) if swinging.any() else math.nan,
        "heading_offset_deg": heading_offset_rad * deg,
        "torsion_rmse_deg": float(np.sqrt(np.mean(tors_err**2)) * deg),
        "torsion_max_deg": float(np.max(np.abs(ref[:, 2] - ref_torsion0_rad)) * deg),
    }  # fmt: skip


def analyse(rec: Recorder, excitation_end_s: float, settle_s: float = 12.0, rest_heading: bool = False
            ) -> dict[str, dict[str, float]]:  # fmt: skip
    """`{"free": ..., "all": ...}` RMSEs (see `score`) over matched (seq) swing / truth pairs; `free` from
    `excitation_end_s + settle_s`, `all` from 1 s after the first swing message; plus `"vqf_free"`/`"vqf_all"`
    when the recorder also holds the IMU packets. `rest_heading`: the gateway was told the simulator's rest heading
    (`--rest-heading`), so its torsion is compared with the true one as it is (not from the first sample's), and the
    Swings' `torsion_std_rad` is scored too: the shares of torsion errors within 1, 2 and 3 σ
    (`torsion_within_{k}sigma`, of `n_sigma` Swings that carried one)."""
    truth = {p.seq: p for _, p in rec.decoded("/truth") if isinstance(p, schemas.HookTruth)}
    swings = [s for _, s in rec.decoded("/swing")]
    pairs = [(s, truth[s["seq"]]) for s in swings if s["seq"] in truth]
    if not pairs or 0 not in truth:
        return {"free": {"n": 0.0}, "all": {"n": 0.0}}
    est = np.array([[s["swing_angle_rad"], s["swing_direction_rad"], s["torsion_rad"]] for s, _ in pairs])
    ref = np.array([[t.swing_angle_rad[-1], t.swing_direction_rad[-1], t.torsion_rad[-1]] for _, t in pairs])
    t_s = np.array([_scenario_t_s(t) for _, t in pairs])
    # the gateway's torsion reference: the first fused sample (seq 0, sample 0), or the configured true rest heading
    tors0 = 0.0 if rest_heading else truth[0].torsion_rad[0]
    # The gateway's reference heading (twist heading minus torsion, from the attitude of the same packet) against the
    # true heading at the first sample: an absolute heading error (e.g. magnetometer hard iron) shifts every bearing.
    att = {a["seq"]: a for _, a in rec.decoded("/attitude")}
    swing_by_seq = {s["seq"]: s for s, _ in pairs}
    refs = [float(hook_geo.twist_heading(np.array(att[k]["quat_wxyz"])) - swing_by_seq[k]["torsion_rad"])
            for k in att if k in swing_by_seq]  # fmt: skip
    true_ref = float(hook_geo.twist_heading(np.array(truth[0].quat_wxyz[0])))
    offset = float(np.angle(np.mean(np.exp(1j * np.array(refs))))) - true_ref if refs else math.nan
    offset = 0.0 if rest_heading else offset  # told, the reference is the true rest heading
    start_free, start_all = excitation_end_s + settle_s, t_s[0] + 1.0
    out = {"free": score(est, ref, t_s, start_free, tors0, offset),
           "all": score(est, ref, t_s, start_all, tors0, offset)}
    if rest_heading:
        std = np.array([math.nan if s.get("torsion_std_rad") is None else s["torsion_std_rad"] for s, _ in pairs])
        for key, start in (("free", start_free), ("all", start_all)):
            sel = (t_s >= start) & np.isfinite(std)
            shares = coverage(wrap(est[sel, 2] - ref[sel, 2]), std[sel]) if sel.any() else (math.nan,) * 3
            out[key]["n_sigma"] = float(sel.sum())
            for k, share in zip((1, 2, 3), shares, strict=True):
                out[key][f"torsion_within_{k}sigma"] = share
    imu = {p.seq: p for _, p in rec.decoded("/imu") if isinstance(p, schemas.ImuPacket)}
    if imu and _vqf_available():
        seqs = sorted(imu)
        if seqs == list(range(len(seqs))):  # VQF offline needs the whole stream
            q = _vqf([imu[k] for k in seqs])
            n = SAMPLES_PER_PACKET
            rows = [(k, q[k * n + n - 1]) for k in seqs if k in truth]
            qe = np.array([r[1] for r in rows])
            heading0 = float(hook_geo.twist_heading(q[0]))
            off_v = heading0 - true_ref
            est_v = np.stack([hook_geo.swing_angle(qe), hook_geo.displacement_bearing(qe),
                              hook_geo.torsion(qe, heading0)], axis=1)  # fmt: skip
            ref_v = np.array([[truth[k].swing_angle_rad[-1], truth[k].swing_direction_rad[-1],
                               truth[k].torsion_rad[-1]] for k, _ in rows])  # fmt: skip
            tv = np.array([_scenario_t_s(truth[k]) for k, _ in rows])
            out["vqf_free"] = score(est_v, ref_v, tv, start_free, tors0, off_v)
            out["vqf_all"] = score(est_v, ref_v, tv, start_all, tors0, off_v)
    return out


def _vqf_available() -> bool:
    try:
        import vqf  # noqa: F401
    except ImportError:
        return False
    return True


def _vqf(packets: list[schemas.ImuPacket]) -> np.ndarray[Any, Any]:
    """VQF (9D when the packets carry a magnetometer) over the packets' samples: quaternions (N, 4)."""
    from vqf import offlineVQF

    gyr = np.ascontiguousarray([s for p in packets for s in p.gyr_rad_s], dtype=np.float64)
    acc = np.ascontiguousarray([s for p in packets for s in p.acc_m_s2], dtype=np.float64)
    mags = [p.mag_uT for p in packets]
    mag = np.ascontiguousarray([s for m in mags for s in m or ()], dtype=np.float64) if all(mags) else None
    out = offlineVQF(gyr, acc, mag, 1.0 / packets[0].rate_hz)
    return np.asarray(out["quat6D" if mag is None else "quat9D"])


def device_args(case_name: str, duration_s: float, still_s: float, seed: int, twist: float | None,
                link: common.LinkModel | None = None, crane_feed: bool = False, imu: str | None = None
                ) -> list[str]:  # fmt: skip
    args = ["--scenario", case_name, "--duration", str(duration_s), "--still", str(still_s), "--seed", str(seed)]
    args += [] if imu is None else ["--imu", imu]
    args += ["--crane-feed"] if crane_feed else []
    args += [] if link is None else ["--loss", str(link.loss_prob), "--burst", str(link.burst_len)]
    return args + ([] if twist is None else ["--twist-torque", str(twist)])


def run_session(duration_s: float, still_s: float, seed: int, work: Path, scenario: str = "free",
                twist_torque_n_m: float | None = None, record_imu: bool = False,
                link: common.LinkModel | None = None, tell_length: bool = True, crane_feed: bool = False,
                imu: str | None = None, iron_told: bool = False, length_factor: float = 1.0,
                rest_heading: bool = False) -> tuple[Recorder, int]:  # fmt: skip
    """Gateway + hook processes with an observer session; returns what it saw and the device's exit code
    (`tell_length` False: a suite crane's rope length is not set, the gateway's default; `crane_feed`: the device
    process also plays the crane, `rig/hook/{id}/crane`; `imu`: the board's preset instead of the scenario's;
    `iron_told`: a suite crane's compass calibration from its twist by hand (`twist_calibration`) is set over REST
    first, as a user would after `calibrate --hook-mount`; `length_factor`: the rope length set that many times the
    true one, a user's wrong measure; `rest_heading`: a suite crane's true rest heading set with it, as a user who
    measured it would)."""
    import subprocess

    zport, hport = free_port(), free_port()
    gw = start_gateway(work / "data", zport, hport, work / "gateway.log")
    rec = Recorder()
    selectors = ["gw/hook/*/swing", "gw/hook/*/attitude", "rig/hook/*/truth"]
    selectors += ["rig/hook/*/imu"] if record_imu else []
    try:
        wait_http(hport)
        case = make_case(scenario, duration_s, still_s, seed, twist_torque_n_m, imu)
        if case.physics is not None and tell_length:  # a suite crane: its rope length, as a user would set it
            set_rope_length(hport, work / "data", case.physics.rope_length_m * length_factor,
                            math.degrees(case.physics.rest_heading_rad) if rest_heading else None)  # fmt: skip
        if iron_told:
            cal = twist_calibration(scenario, duration_s, case.imu, seed)
            if cal is None:
                raise RuntimeError(f"{scenario}: the twist by hand gives no calibration")
            put_device_settings(hport, work / "data", fleet_settings(duration_s, seed).ids[0],
                                {"kind": "hook", "calibration": cal})
        with zenoh.open(observer_config(zport)) as session:
            subs = [session.declare_subscriber(sel, rec) for sel in selectors]
            time.sleep(0.5)
            dev = subprocess.run(
                [sys.executable, "-m", "bench.hook_e2e", "--device", "--port", str(zport),
                 *device_args(scenario, duration_s, still_s, seed, twist_torque_n_m, link, crane_feed, imu)],
                cwd=REPO, capture_output=True, timeout=duration_s + 120,
            )  # fmt: skip
            rec.wait_quiet()
            for s in subs:
                s.undeclare()  # type: ignore[no-untyped-call]
    finally:
        stop_process(gw)
    if dev.returncode != 0:
        print(dev.stderr.decode()[-2000:], file=sys.stderr)
    return rec, dev.returncode


def twist_calibration(scenario: str, duration_s: float, imu: str, seed: int) -> dict[str, object] | None:
    """A suite crane's device calibration as `calibrate --hook-mount` prints it from a twist by hand of that hook with
    the device process's board (`bench.hook_suite.twist_iron`); None when the fit refuses or leaves it out."""
    from bench.hook_suite import SUITE_VERSION, twist_iron
    from bench.hook_suite import make_case as suite_case

    _, seed_text, *version = scenario.split(":")
    sc = suite_case(int(seed_text), duration_s + 1.0, suite_version=int(version[0]) if version else SUITE_VERSION)
    return twist_iron(sc, imu, RATE_HZ, board_seed=seed)


def put_device_settings(http_port: int, data_dir: Path, device_id: str, body: dict[str, object]) -> None:
    """`PUT /api/devices/{id}/settings`."""
    _put(http_port, data_dir, f"/api/devices/{device_id}/settings", body)


def set_rope_length(http_port: int, data_dir: Path, rope_length_m: float, rest_heading_deg: float | None = None
                    ) -> None:  # fmt: skip
    """`PUT /api/thresholds/hook` with the rope length (and the rest heading, when given)."""
    body: dict[str, object] = {"rope_length_m": rope_length_m}
    if rest_heading_deg is not None:
        body["rest_heading_deg"] = rest_heading_deg
    _put(http_port, data_dir, "/api/thresholds/hook", body)


def _put(http_port: int, data_dir: Path, path: str, body: dict[str, object]) -> None:
    """A PUT to the gateway's REST API with the bearer token from its data directory; raises on an error status."""
    import httpx

    token = (data_dir / "api_token").read_text().strip()
    r = httpx.put(f"http://127.0.0.1:{http_port}{path}", json=body, headers={"Authorization": f"Bearer {token}"},
                  timeout=10.0)  # fmt: skip
    r.raise_for_status()


def run_in_process(case: Case, duration_s: float, seed: int, tell_length: bool = True, crane_feed: bool = False,
                   calibration: dict[str, object] | None = None, length_factor: float = 1.0,
                   rest_heading: bool = False) -> tuple[Recorder, float, int]:  # fmt: skip
    """The same packets straight into a `Pipeline` (no zenoh, no processes): recorder, pipeline CPU seconds, packets.
    `calibration`: the device's IMU calibration (`twist_calibration`), as `PUT /api/devices/{id}/settings` sets it;
    `rest_heading`: a suite crane's true rest heading configured with its rope length (`run_session`)."""
    from gateway.config import DeviceSettings, HookThresholds
    from gateway.pipeline import Pipeline

    fleet = fleet_settings(duration_s, seed)
    hooks = HookFleet(fleet, case, seed, crane_feed)
    pipe = Pipeline()
    if case.physics is not None and tell_length:
        rest = math.degrees(case.physics.rest_heading_rad) if rest_heading else None
        pipe.set_defaults("hook", HookThresholds(rope_length_m=case.physics.rope_length_m * length_factor,
                                                 rest_heading_deg=rest))  # fmt: skip
    if calibration is not None:
        pipe.set_device_settings(fleet.ids[0], "hook", DeviceSettings(calibration=calibration))
    pipe.warm_up()
    rec = Recorder()
    busy_s, n_packets = 0.0, int(round(duration_s * RATE_HZ / SAMPLES_PER_PACKET))
    for k in tqdm(range(n_packets), desc="packets", unit="pkt", file=sys.stderr):
        data, extra = hooks.tick(k)
        for m in [m for ms in data for m in ms] + extra:
            rec.samples.append((0.0, m.key, m.payload))
        packets = [schemas.decode(m.key, m.payload) for m in data[0]]
        t0 = time.process_time()  # CPU time: the box is shared, wall time would count other jobs
        out = pipe.process(packets, now_wall_s=1.0e9)
        busy_s += time.process_time() - t0
        for s in out.swings:
            rec.samples.append((0.0, schemas.swing_key(s.device_id), s.model_dump_json().encode()))
        for a in out.attitudes:
            rec.samples.append((0.0, schemas.attitude_key("hook", a.device_id), a.model_dump_json().encode()))
    return rec, busy_s, n_packets


def _print(label: str, r: dict[str, float]) -> None:
    if not r.get("n"):
        print(f"{label}: no matched samples")
        return
    print(f"{label:<34} n {r['n']:>5.0f}  swing RMSE {r['swing_angle_rmse_deg']:6.3f}° (max err "
          f"{r['swing_angle_maxerr_deg']:.2f}°, max swing {r['swing_angle_max_deg']:.1f}°)  direction RMSE "
          f"{r['direction_rmse_deg']:6.2f}° (rel. to start heading {r['direction_rel_rmse_deg']:5.2f}°, heading off "
          f"by {r['heading_offset_deg']:.1f}°)  torsion RMSE {r['torsion_rmse_deg']:6.2f}° (max "
          f"{r['torsion_max_deg']:.0f}°)")
    if r.get("n_sigma"):
        print(f"{'':<34} torsion within 1σ / 2σ / 3σ of its torsion_std_rad: {100 * r['torsion_within_1sigma']:.1f} / "
              f"{100 * r['torsion_within_2sigma']:.1f} / {100 * r['torsion_within_3sigma']:.1f} % of "
              f"{r['n_sigma']:.0f} Swings (Gaussian: 68 / 95 / 99.7 %)")


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m bench.hook_e2e", description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)  # fmt: skip
    p.add_argument("--scenario", default="free", help=f"what the hook does: {', '.join(SCENARIOS)} or suite:SEED "
                   "(a bench.hook_suite crane; its rope length is set over REST first; suite:SEED:1 its generator "
                   "version 1) (default: free)")
    p.add_argument("--duration", type=float, default=40.0, help="seconds of hook data (default: 40)")
    p.add_argument("--still", type=float, default=3.0, help="seconds hanging still before the trolley moves")
    p.add_argument("--settle", type=float, default=12.0, help="free-swing window starts this long after the "
                   "excitation, s (default: 12)")  # fmt: skip
    p.add_argument("--twist-torque", type=float, default=None, help="gust torque about the rope, std, N·m "
                   "(default: 2 for free, 10 for traverse)")  # fmt: skip
    p.add_argument("--seed", type=int, default=1)
    p.add_argument("--compare", action="store_true", help="also score VQF on the same received IMU samples")
    p.add_argument("--in-process", action="store_true", help="no zenoh: packets straight into a Pipeline; "
                   "prints the pipeline's cost per packet")  # fmt: skip
    p.add_argument("--loss", type=float, default=0.0, help="packets the device's link loses (Gilbert-Elliott, "
                   "devices.common.LinkSim), long-run share (default 0; zenoh runs only)")  # fmt: skip
    p.add_argument("--burst", type=float, default=2.0, help="with --loss: mean burst length, packets (default 2)")
    p.add_argument("--no-length", action="store_true",
                   help="suite:SEED: do not set the rope length (the gateway's default: the filter finds it)")
    p.add_argument("--length-factor", type=float, default=1.0,
                   help="a suite crane's rope length set over REST this many times the true one (default 1; 2: a "
                   "user's measure twice too long)")
    p.add_argument("--crane-feed", action="store_true",
                   help="the device also plays the crane: its boom tip's acceleration on rig/hook/{id}/crane")
    p.add_argument("--imu", default=None, help="the board's error preset (calibrated, uncalibrated, legacy, ideal; "
                   "default: legacy, calibrated for suite:SEED)")
    p.add_argument("--iron-told", action="store_true",
                   help="suite:SEED: set the compass calibration a twist by hand of that hook gives (`calibrate "
                   "--hook-mount`) over REST first")
    p.add_argument("--rest-heading", action="store_true",
                   help="suite:SEED: set the crane's true rest heading with its rope length over REST, so the torsion "
                   "is absolute and the Swings carry its 1σ (`torsion_std_rad`), which is scored too")
    p.add_argument("--device", action="store_true", help="(internal) run the hook device process")
    p.add_argument("--port", type=int, default=7447, help="(with --device) gateway zenoh port")
    args = p.parse_args(argv)
    case = make_case(args.scenario, args.duration, args.still, args.seed, args.twist_torque, args.imu)
    if args.iron_told and (case.physics is None or args.in_process):
        p.error("--iron-told needs a suite:SEED scenario through zenoh")
    if args.rest_heading and (case.physics is None or args.no_length):
        p.error("--rest-heading needs a suite:SEED scenario whose rope length is set")
    link = common.LinkModel(args.loss, args.burst) if args.loss > 0 else None
    if args.device:
        run_device(args.port, case, args.duration, args.seed, link, args.crane_feed)
        return 0
    if args.in_process and link is not None:
        p.error("--loss needs the zenoh run (the device process's link drops the packets)")
    if args.in_process:
        rec, busy_s, n_packets = run_in_process(case, args.duration, args.seed, not args.no_length, args.crane_feed,
                                                length_factor=args.length_factor,
                                                rest_heading=args.rest_heading)  # fmt: skip
        code = 0
        print(f"pipeline cost: {busy_s / n_packets * 1e3:.3f} CPU ms per hook packet of {SAMPLES_PER_PACKET} samples "
              f"({n_packets * SAMPLES_PER_PACKET / busy_s:,.0f} samples per CPU-second, one hook, after warm_up())")
    else:
        with tempfile.TemporaryDirectory() as tmp:
            print(f"running {args.duration:g} s of hook data through zenoh and the gateway ...", file=sys.stderr)
            rec, code = run_session(args.duration, args.still, args.seed, Path(tmp), args.scenario,
                                    args.twist_torque, record_imu=args.compare, link=link,
                                    tell_length=not args.no_length, crane_feed=args.crane_feed, imu=args.imu,
                                    iron_told=args.iron_told, length_factor=args.length_factor,
                                    rest_heading=args.rest_heading)  # fmt: skip
    if not args.compare:
        rec.samples = [s for s in rec.samples if not s[1].endswith("/imu")]
    r = analyse(rec, case.excitation_end_s, args.settle, args.rest_heading)
    start = case.excitation_end_s + args.settle
    print(f"scenario {args.scenario}, seed {args.seed}, {args.duration:g} s, device exit code {code}; excitation ends "
          f"at {case.excitation_end_s:g} s; free-swing window {start:g}-{args.duration:g} s")
    _print(f"gateway ({'in process' if args.in_process else 'zenoh'}), free swing", r["free"])
    _print("gateway, all after 1 s", r["all"])
    if "vqf_free" in r:
        _print("VQF on the same samples, free swing", r["vqf_free"])
        _print("VQF on the same samples, all", r["vqf_all"])
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
