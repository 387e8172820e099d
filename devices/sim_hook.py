"""Simulated crane hooks: `python -m devices.sim_hook --help`.

Each instance runs devices.hook_physics (spherical pendulum + torsion, 1 kHz RK4), passes the true rates,
specific force and field through the shared MPU-6050/HMC5883L error model (devices.common.SensorModel), and
publishes `rig/hook/{id}/imu` plus `rig/hook/{id}/truth` (attitude, swing angle Θ, displacement bearing as the
swing direction, torsion φ; unless --no-truth), holding the liveliness token `rig/hook/{id}`. With --crane-feed it
also plays the crane: `rig/hook/{id}/crane`, the boom tip's acceleration (trolley and slew moves) at the IMU's
sample times, one packet per IMU packet (docs/protocol.md, crane motion).

Examples:

    python -m devices.sim_hook                                        # one hook swinging 5°, twisting in gusts
    python -m devices.sim_hook --swing-deg 0 --trolley 5,4,90         # at rest, then a 4 m trolley move north
    python -m devices.sim_hook --count 3 --auto-trolley-s 40 --wind 0.2 --duration 120
    python -m devices.sim_hook --load-kg 2000 --pull 10,3,200,45 --hoist 20,10,0.5 --slew 40,20,60
    python -m devices.sim_hook --slew 10,40,60,30 --crane-feed       # the crane tells its slew to the gateway
"""

from __future__ import annotations

import argparse
import dataclasses
import math
from typing import Any

import numpy as np

from devices import _quat, common
from devices.common import FleetSettings, ImuErrorModel, Message, SensorModel
from devices.hook_physics import (
    Hoist,
    HookPhysicsSettings,
    HookScenario,
    HookStream,
    HookTruth,
    Pull,
    SlewMove,
    TrolleyMove,
    suspension_acceleration,
    trolley_traverse,
)
from gateway import schemas


class HookFleet:
    """`count` hooks in one process; implements `devices.common.Fleet` (hooks take no commands)."""

    kind = "hook"
    command_selectors: tuple[str, ...] = ()

    def __init__(self, fleet: FleetSettings, physics: HookPhysicsSettings, scenario: HookScenario, *,
                 error_model: ImuErrorModel | None = None, with_mag: bool = True, load_kg: float | None = None,
                 imu_tilt_deg: tuple[float, float] = (0.0, 0.0), crane_feed: bool = False) -> None:  # fmt: skip
        self.fleet, self.physics, self.with_mag, self.load_kg = fleet, physics, with_mag, load_kg
        self.crane_feed = crane_feed  # also publish what the crane knows of its boom tip (`schemas.CraneMotion`)
        # the IMU tilted on the hook (`HookThresholds.imu_tilt_deg` undoes it): it reads each hook vector v as Mᵀ v
        self.tilt = tilt_matrix(*(math.radians(a) for a in imu_tilt_deg))
        self.ids = fleet.ids
        rng = np.random.default_rng(fleet.seed)
        sub = max(1, round(physics.internal_rate_hz / fleet.rate_hz))
        physics = dataclasses.replace(physics, internal_rate_hz=sub * fleet.rate_hz)
        self.streams = []
        for i in range(fleet.count):
            # each hook its own wind and swing bearing; seeded runs are reproducible
            turn = float(rng.uniform(0.0, 2.0 * math.pi)) if i else 0.0
            sc = dataclasses.replace(
                scenario, output_rate_hz=fleet.rate_hz, seed=int(rng.integers(0, 2**31)),
                initial_swing_bearing_rad=scenario.initial_swing_bearing_rad + turn,
            )  # fmt: skip
            self.streams.append(HookStream(physics, sc))
        self.sensor = SensorModel(error_model or ImuErrorModel.calibrated(), fleet.count, rng)
        self.clocks = [common.DeviceClock.start(rng) for _ in self.ids]
        self.boot_ids = [common.new_boot_id(rng) for _ in self.ids]
        self.seq = [0] * fleet.count
        self._imu_keys = [schemas.imu_key("hook", i) for i in self.ids]
        self._truth_keys = [schemas.truth_key("hook", i) for i in self.ids]
        self._crane_boot_id = common.new_boot_id(rng)

    def on_command(self, key: str, payload: bytes) -> None:
        """Hooks have no command channel."""

    def tick(self, k: int) -> tuple[list[list[Message]], list[Message]]:
        """Simulate one packet period for every hook and build its IMU (and truth) messages."""
        fl = self.fleet
        n, dt = fl.samples_per_packet, 1.0 / fl.rate_hz
        truths = [s.advance(n) for s in self.streams]
        m = self.tilt  # rows @ M: each hook vector as the tilted IMU reads it
        gyr, acc, mag = self.sensor.measure(
            np.stack([t.gyr_rad_s for t in truths]) @ m, np.stack([t.acc_m_s2 for t in truths]) @ m,
            np.stack([t.mag_uT for t in truths]) @ m if self.with_mag else None, dt,
        )  # fmt: skip
        gyr_l, acc_l = common.rows(gyr, 6), common.rows(acc, 5)
        mag_l = None if mag is None else common.rows(mag, 3)
        data: list[list[Message]] = []
        extra: list[Message] = []
        t0_rel_us = int(round(float(truths[0].t_s[0]) * 1e6))
        for i, dev in enumerate(self.ids):
            t0_us = self.clocks[i].boot_offset_us + t0_rel_us
            wall = self.clocks[i].wall_us(t0_us)
            data.append([common.imu_message(
                self._imu_keys[i], fl.imu_encoding,
                device_id=dev, kind="hook", boot_id=self.boot_ids[i], seq=self.seq[i], t0_us=t0_us,
                rate_hz=fl.rate_hz, gyr_rad_s=gyr_l[i], acc_m_s2=acc_l[i], mag_uT=None if mag_l is None else mag_l[i],
                wall_t0_us=wall,
            )])  # fmt: skip
            if self.crane_feed:
                data[i].append(crane_message(self.streams[i].scenario, truths[i].t_s, device_id=dev,
                                             boot_id=self._crane_boot_id, seq=self.seq[i], wall_t0_us=wall,
                                             rate_hz=fl.rate_hz))  # fmt: skip
            if fl.truth:
                extra.append(Message(self._truth_keys[i], truth_payload(
                    truths[i], device_id=dev, boot_id=self.boot_ids[i], seq=self.seq[i], t0_us=t0_us,
                    rate_hz=fl.rate_hz, wall_t0_us=wall, rope_length_m=self.physics.rope_length_m, load_kg=self.load_kg,
                ), schemas.ENCODING_TRUTH))  # fmt: skip
            self.seq[i] = (self.seq[i] + 1) % schemas.UINT32
        return data, extra


def crane_message(scenario: HookScenario, t_s: np.ndarray, *, device_id: str, boot_id: int, seq: int,
                  wall_t0_us: int, rate_hz: float) -> Message:  # fmt: skip
    """What the crane of `scenario` publishes on `rig/hook/{device_id}/crane` for the IMU samples at scenario times
    `t_s` (s): its boom tip's horizontal acceleration there (trolley and slew moves), East/North, 0.1 mm/s²."""
    tip = suspension_acceleration(scenario.trolley_moves, t_s, scenario.slews)[:, :2]
    return Message(schemas.crane_key(device_id), schemas.CraneMotion(
        v=1, device_id=device_id, boot_id=boot_id, seq=seq, wall_t0_us=wall_t0_us, rate_hz=rate_hz,
        tip_acc_m_s2=[(round(float(x), 4), round(float(y), 4)) for x, y in tip]).to_json(), schemas.ENCODING_CRANE)


def truth_payload(truth: HookTruth, *, device_id: str, boot_id: int, seq: int, t0_us: int, rate_hz: float,
                  wall_t0_us: int | None, rope_length_m: float, load_kg: float | None) -> bytes:
    """JSON bytes of a `schemas.HookTruth` packet; swing direction = displacement bearing (ENU, CCW from East)."""
    d: dict[str, Any] = {
        "v": schemas.PROTOCOL_VERSION, "device_id": device_id, "kind": "hook", "boot_id": boot_id, "seq": seq,
        "t0_us": t0_us, "rate_hz": rate_hz, "events": [],
        "quat_wxyz": common.rows(truth.quat, 9), "swing_angle_rad": common.rows(truth.swing_rad, 7),
        "swing_direction_rad": common.rows(truth.swing_bearing_rad, 6),
        "torsion_rad": common.rows(np.remainder(truth.torsion_rad + math.pi, 2 * math.pi) - math.pi, 7),
        "rope_length_m": rope_length_m,
    }  # fmt: skip
    if wall_t0_us is not None:
        d["wall_t0_us"] = wall_t0_us
    if load_kg is not None:
        d["load_kg"] = load_kg
    return common.encode_json(d)


def tilt_matrix(tx_rad: float, ty_rad: float) -> np.ndarray:
    """The rotation by the vector (tx, ty, 0): hook axes = M @ IMU axes (a quaternion's matrix, `devices._quat`)."""
    angle = math.hypot(tx_rad, ty_rad)
    if angle == 0.0:
        return np.eye(3)
    s = math.sin(angle / 2.0) / angle
    return _quat.to_matrix([math.cos(angle / 2.0), tx_rad * s, ty_rad * s, 0.0])


def parse_trolley(text: str) -> tuple[TrolleyMove, ...]:
    """`T,DIST,BEARING_DEG`: start at T s, travel DIST m towards BEARING_DEG (CCW from East), 0.3 m/s², 0.5 m/s."""
    t_s, dist_m, bearing_deg = (float(x) for x in text.split(","))
    return trolley_traverse(t_s, dist_m, math.radians(bearing_deg))


def parse_pull(text: str) -> Pull:
    """`T,DUR,FORCE_N,BEARING_DEG`: a tag line pulls the load with FORCE_N towards BEARING_DEG (CCW from East)."""
    t_s, dur_s, force_n, bearing_deg = (float(x) for x in text.split(","))
    b = math.radians(bearing_deg)
    return Pull(t_s, dur_s, (force_n * math.cos(b), force_n * math.sin(b)))


def parse_hoist(text: str) -> Hoist:
    """`T,DUR,SPEED_M_S`: pay rope out (> 0, lowering) or in (< 0, hoisting) for DUR s, 1 s ramps."""
    t_s, dur_s, speed = (float(x) for x in text.split(","))
    return Hoist(t_s, dur_s, speed)


def parse_slew(text: str) -> SlewMove:
    """`T,DUR,ANGLE_DEG[,RADIUS_M]`: turn the jib by ANGLE_DEG (CCW from above) in DUR s, the tip RADIUS_M (30) out."""
    parts = [float(x) for x in text.split(",")]
    return SlewMove(parts[0], parts[1], math.radians(parts[2]), parts[3] if len(parts) > 3 else 30.0)


def auto_trolley(period_s: float, horizon_s: float, rng: np.random.Generator) -> tuple[TrolleyMove, ...]:
    """A traverse of 1-6 m in a random direction every `period_s` up to `horizon_s`."""
    moves: list[TrolleyMove] = []
    t = period_s
    while t < horizon_s:
        moves += trolley_traverse(t, float(rng.uniform(1.0, 6.0)), float(rng.uniform(-math.pi, math.pi)))
        t += period_s
    return tuple(moves)


def build_parser() -> argparse.ArgumentParser:
    """CLI of the hook simulator."""
    p = argparse.ArgumentParser(prog="python -m devices.sim_hook", description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    common.add_zenoh_args(p)
    common.add_fleet_args(p, id_prefix="hook", samples_per_packet=10)
    common.add_imu_args(p)
    g = p.add_argument_group("hook")
    g.add_argument("--rope-length", type=float, default=10.0, help="rope length boom tip -> hook, m (default: 10)")
    g.add_argument("--swing-deg", type=float, default=5.0, help="initial swing angle, degrees (default: 5)")
    g.add_argument("--swing-bearing-deg", type=float, default=30.0, help="initial swing bearing, degrees CCW from East")
    g.add_argument("--hold", type=float, default=0.0, help="hold the hook at its initial swing for this long, s")
    g.add_argument("--twist-deg", type=float, default=0.0, help="initial torsion about the rope, degrees")
    g.add_argument("--trolley", action="append", default=[], metavar="T,DIST,BEARING_DEG",
                   help="trolley traverse at T s over DIST m towards BEARING_DEG (repeatable)")
    g.add_argument("--pull", action="append", default=[], metavar="T,DUR,FORCE_N,BEARING_DEG",
                   help="tag-line pull on the load (repeatable; force per unit mass uses --load-kg, default 500 kg)")
    g.add_argument("--hoist", action="append", default=[], metavar="T,DUR,SPEED_M_S",
                   help="rope paid out (> 0) or in (< 0) at SPEED for DUR s from T (repeatable)")
    g.add_argument("--slew", action="append", default=[], metavar="T,DUR,ANGLE_DEG[,RADIUS_M]",
                   help="slew the jib by ANGLE_DEG in DUR s from T (repeatable)")
    g.add_argument("--auto-trolley-s", type=float, default=0.0, help="random traverse every this many s (0: off)")
    g.add_argument("--wind", type=float, default=0.05, help="gust force per unit mass, std, m/s² (default: 0.05)")
    g.add_argument("--wind-tau", type=float, default=2.0, help="gust correlation time, s")
    g.add_argument("--wind-mean", type=float, nargs=2, default=(0.0, 0.0), metavar=("EAST", "NORTH"),
                   help="steady wind force per unit mass, m/s²")
    g.add_argument("--twist-torque", type=float, default=2.0, help="gust torque about the rope, std, N·m")
    g.add_argument("--damping", type=float, default=0.002, help="swing air damping, 1/s")
    g.add_argument("--lever-arm", type=float, nargs=3, default=(0.1, 0.0, 0.0), metavar=("X", "Y", "Z"),
                   help="IMU position from the rope axis, body frame, m")
    g.add_argument("--imu-tilt", type=float, nargs=2, default=(0.0, 0.0), metavar=("TX", "TY"),
                   help="the IMU tilted on the hook: the rotation about its x and y, degrees, that takes its axes onto "
                   "the hook's (the gateway's hook setting imu_tilt_deg undoes it; default square)")
    g.add_argument("--load-kg", type=float, default=None, help="hook + load mass, kg (default 500; also in the truth)")
    g.add_argument("--no-mag", action="store_true", help="no magnetometer (6-axis IMU)")
    g.add_argument("--crane-feed", action="store_true",
                   help="also publish the crane's feed of its boom tip's acceleration (trolley and slew moves) on "
                   "rig/hook/{id}/crane, which the gateway's hook filter takes as a known input")
    return p


def make_fleet(args: argparse.Namespace, fleet: FleetSettings) -> HookFleet:
    """HookFleet from parsed CLI options."""
    physics = HookPhysicsSettings(
        rope_length_m=args.rope_length, gravity_m_s2=common.G_M_S2, earth_field_uT=common.EARTH_FIELD_ENU_UT,
        swing_damping_1_s=args.damping, lever_arm_m=tuple(args.lever_arm),
        **({} if args.load_kg is None else {"hook_mass_kg": args.load_kg}),
    )  # fmt: skip
    moves: tuple[TrolleyMove, ...] = tuple(m for t in args.trolley for m in parse_trolley(t))
    if args.auto_trolley_s > 0:
        horizon = args.duration if args.duration is not None else 3600.0
        moves += auto_trolley(args.auto_trolley_s, horizon, np.random.default_rng(args.seed))
    scenario = HookScenario(
        duration_s=0.0, initial_swing_rad=math.radians(args.swing_deg),
        initial_swing_bearing_rad=math.radians(args.swing_bearing_deg), hold_s=args.hold,
        initial_torsion_rad=math.radians(args.twist_deg), trolley_moves=moves, wind_mean_m_s2=tuple(args.wind_mean),
        wind_std_m_s2=args.wind, wind_tau_s=args.wind_tau, wind_torque_std_n_m=args.twist_torque,
        pulls=tuple(parse_pull(t) for t in args.pull), hoists=tuple(parse_hoist(t) for t in args.hoist),
        slews=tuple(parse_slew(t) for t in args.slew),
    )  # fmt: skip
    return HookFleet(fleet, physics, scenario, with_mag=not args.no_mag, load_kg=args.load_kg,
                     error_model=ImuErrorModel.preset(args.imu), imu_tilt_deg=tuple(args.imu_tilt),
                     crane_feed=args.crane_feed)  # fmt: skip


def main(argv: list[str] | None = None) -> int:
    """Run hooks until --duration elapses or Ctrl-C."""
    return common.run_main(make_fleet, build_parser().parse_args(argv))


if __name__ == "__main__":
    raise SystemExit(main())
