"""Simulated smart fishing rods: `python -m devices.sim_rod --help`.

Each instance publishes `rig/rod/{id}/imu` (5 samples per packet at 100 Hz by default, so a bite reaches the
gateway within ~50 ms plus transport), `rig/rod/{id}/reel` at 10 Hz, `rig/rod/{id}/truth` (unless --no-truth),
holds the liveliness token `rig/rod/{id}` and obeys `rig/rod/{id}/reel/cmd`.

Examples:

    python -m devices.sim_rod                                   # one rod, quiet water, connects to the gateway
    python -m devices.sim_rod --random-events --count 5          # five rods with bites, fights, wind, handling
    python -m devices.sim_rod --script '[{"type": "bite", "t_s": 5, "depth_deg": 20, "duration_s": 2}]'
    python -m devices.sim_rod --script events.json --duration 60
    python -m devices.sim_rod --imu uncalibrated                 # raw IMU: hard iron tens of µT, heading far off
    python -m devices.sim_rod --scenario 1000 --count 24 --duration 300   # play the rod scenario suite

With `--scenario SEED`, rod i plays the recording `devices.rod_scenarios.make_scenario(SEED + i)` (bites, runs,
nibbles, knocks, wind, handling, drop-backs; MPU-6050 errors at ±2 g) instead of the physics: its IMU samples,
and truth packets with the true attitude and the events as `<family>` start/end labels. No reel.

Script items: `{"type": bite|drop_back|fight|handling|wind|waves, "t_s": ..., <fields of the event class in
devices.rod_physics, angles as *_rad or *_deg>, "device": "rod-2" (optional; default all rods)}`.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
import time
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from devices import common
from devices.common import FleetSettings, ImuErrorModel, Message, SensorModel
from devices.rod_physics import (
    FISH_STATES,
    RandomEventRates,
    RodBank,
    RodSettings,
    parse_script,
    reel_speed_for,
)
from gateway import schemas

if TYPE_CHECKING:
    from devices.rod_scenarios import Scenario

REEL_STATUS_HZ = 10.0


class RodFleet:
    """`count` rods in one process, vectorised physics and sensors; implements `devices.common.Fleet`."""

    kind = "rod"

    def __init__(self, fleet: FleetSettings, rod: RodSettings | None = None, *, script: Sequence[dict[str, Any]] = (),
                 rates: RandomEventRates | None = None, error_model: ImuErrorModel | None = None,
                 with_mag: bool = True) -> None:
        self.fleet, self.rod = fleet, rod or RodSettings()
        self.ids = fleet.ids
        # few devices: exact keys; many: one wildcard (on_command ignores ids that are not ours)
        self.command_selectors = tuple(schemas.reel_cmd_key(i) for i in self.ids) if len(self.ids) <= 16 else (
            schemas.SEL_REEL_CMD,)
        seed = fleet.seed
        self.rng = np.random.default_rng(seed)
        self.bank = RodBank(self.rod, fleet.count, None if seed is None else seed + 1, rates)
        self.sensor = SensorModel(error_model or ImuErrorModel.calibrated(), fleet.count, np.random.default_rng(
            None if seed is None else seed + 2))
        self.with_mag = with_mag
        self.clocks = [common.DeviceClock.start(self.rng) for _ in self.ids]
        self.boot_ids = [common.new_boot_id(self.rng) for _ in self.ids]
        self.seq = [0] * fleet.count
        self.reel_seq = [0] * fleet.count
        self.cmd_speed = np.zeros(fleet.count)
        self.mode: list[str] = ["stop"] * fleet.count
        self.last_cmd: list[int | None] = [None] * fleet.count
        self.index = {d: i for i, d in enumerate(self.ids)}
        self.reel_every = max(1, round(1.0 / (REEL_STATUS_HZ * fleet.period_s)))
        self._reel_now: set[int] = set()
        rest = self.bank.holder_pitch - self.rod.bend_rad(self.rod.baseline_tension_n)
        self._rest_pitch: list[float] = np.round(rest, 9).tolist()
        self._imu_keys = [schemas.imu_key("rod", d) for d in self.ids]
        self._truth_keys = [schemas.truth_key("rod", d) for d in self.ids]
        for item in script:
            item = dict(item)
            target = item.pop("device", None)
            rods = None if target is None else [self.index[target]] if target in self.index else []
            for e in parse_script([item]):
                self.bank.inject(e, rods)

    def on_command(self, key: str, payload: bytes) -> None:
        """Apply a ReelCommand (decoded and validated with gateway.schemas); anything else is logged and ignored."""
        got = common.decode_command(key, payload, self.index)
        if got is None or not isinstance(got[1], schemas.ReelCommand):
            return
        i, cmd = got[0], got[1]
        if cmd.drag_n is not None:
            self.bank.set_drag(cmd.drag_n, i)
        self.cmd_speed[i] = reel_speed_for(cmd.action, cmd.speed_m_s, self.rod)
        self.mode[i], self.last_cmd[i] = cmd.action, cmd.cmd_id
        self._reel_now.add(i)  # acknowledge in the next tick

    def tick(self, k: int) -> tuple[list[list[Message]], list[Message]]:
        """Simulate one packet period for every rod and build its messages."""
        fl = self.fleet
        n, dt = fl.samples_per_packet, 1.0 / fl.rate_hz
        blk = self.bank.run_block(n, dt, self.cmd_speed)
        gyr, acc, mag = self.sensor.measure(blk.gyr_rad_s, blk.acc_m_s2, blk.mag_uT if self.with_mag else None, dt)
        gyr_l, acc_l = common.rows(gyr, 6), common.rows(acc, 5)
        mag_l = None if mag is None else common.rows(mag, 3)
        quat_l, ten_l = common.rows(blk.quat_wxyz, 9), common.rows(blk.tension_n, 4)
        t0_s = float(blk.t_s[0])
        labels: dict[int, list[dict[str, Any]]] = {}
        for lab in self.bank.drain_labels():
            labels.setdefault(lab.rod, []).append(
                {"label": lab.label, "phase": lab.phase, "t_us": self._t_us(lab.rod, lab.t_s)}
                | ({} if lab.value is None else {"value": round(lab.value, 6)})
            )
        send_reel = k % self.reel_every == 0
        data: list[list[Message]] = []
        extra: list[Message] = []
        temp_c, battery_v = round(24.0 + 0.5 * math.sin(t0_s / 600.0), 2), round(4.1 - 1e-5 * t0_s, 3)
        rssi = (-60.0 + np.round(self.rng.normal(0.0, 2.0, len(self.ids)))).tolist()
        t0_rel_us = int(round(t0_s * 1e6))
        for i, dev in enumerate(self.ids):
            t0_us = self.clocks[i].boot_offset_us + t0_rel_us
            wall = self.clocks[i].wall_us(t0_us)
            msgs = [common.imu_message(
                self._imu_keys[i], fl.imu_encoding,
                device_id=dev, kind="rod", boot_id=self.boot_ids[i], seq=self.seq[i], t0_us=t0_us,
                rate_hz=fl.rate_hz, gyr_rad_s=gyr_l[i], acc_m_s2=acc_l[i], mag_uT=None if mag_l is None else mag_l[i],
                wall_t0_us=wall, temp_c=temp_c, battery_v=battery_v, rssi_dbm=rssi[i],
            )]
            if send_reel or i in self._reel_now:
                msgs.append(self._reel_message(i, t0_us, wall))
            data.append(msgs)
            if fl.truth:
                extra.append(self._truth_message(i, t0_us, wall, quat_l[i], ten_l[i], labels.get(i)))
            self.seq[i] = (self.seq[i] + 1) % schemas.UINT32
        self._reel_now.clear()
        return data, extra

    def _t_us(self, i: int, t_s: float) -> int:
        return self.clocks[i].boot_offset_us + int(round(t_s * 1e6))

    def _reel_message(self, i: int, t_us: int, wall: int) -> Message:
        b = self.bank
        motor = float(b.motor[i])
        state = "stopped" if abs(motor) < 0.01 else "reeling_in" if motor > 0 else "paying_out"
        status = schemas.ReelStatus(
            v=1, device_id=self.ids[i], boot_id=self.boot_ids[i], seq=self.reel_seq[i], t_us=t_us, wall_t_us=wall,
            line_out_m=round(float(b.line_out[i]), 4), line_in_speed_m_s=round(float(-b.line_rate[i]), 4),
            motor=state, mode=self.mode[i], cmd_speed_m_s=float(self.cmd_speed[i]),  # type: ignore[arg-type]
            drag_n=float(b.drag[i]), tension_n=round(float(b.tension[i]), 3), last_cmd_id=self.last_cmd[i],
        )
        self.reel_seq[i] = (self.reel_seq[i] + 1) % schemas.UINT32
        return Message(schemas.reel_key(self.ids[i]), status.to_json(), schemas.ENCODING_REEL)

    def _truth_message(self, i: int, t0_us: int, wall: int, quat: list[Any], tension: list[Any],
                       events: list[dict[str, Any]] | None) -> Message:
        b = self.bank
        fish = int(b.fish[i])
        d: dict[str, Any] = {
            "v": 1, "device_id": self.ids[i], "kind": "rod", "boot_id": self.boot_ids[i], "seq": self.seq[i],
            "t0_us": t0_us, "rate_hz": self.fleet.rate_hz, "wall_t0_us": wall, "events": events or [],
            "quat_wxyz": quat, "tension_n": tension,
            "breaking_strength_n": float(b.breaking[i]), "line_out_m": round(float(b.line_out[i]), 4),
            "fish_state": FISH_STATES[fish],
            "rest_pitch_rad": self._rest_pitch[i],
        }
        if FISH_STATES[fish] in ("hooked", "fighting", "tired"):
            d["fish_mass_kg"] = float(b.fish_mass[i])
            d["fish_stamina"] = round(float(b.fish_stamina[i]), 4)
        return Message(self._truth_keys[i], common.encode_json(d), schemas.ENCODING_TRUTH)


class ScenarioFleet:
    """`count` rods playing rod-scenario recordings (rod i: seed first_seed + i); implements `devices.common.Fleet`.

    Device time of sample k is the clock's boot offset + the recording time of sample k; after the recording the
    rods fall silent. Reel commands are accepted and ignored (the recordings have no reel)."""

    kind = "rod"

    def __init__(self, fleet: FleetSettings, first_seed: int) -> None:
        from devices.rod_scenarios import make_scenario  # scipy: only when scenarios are played

        if fleet.rate_hz != 100.0:
            raise ValueError("rod scenarios are recorded at 100 Hz")
        self.fleet, self.ids = fleet, fleet.ids
        self.command_selectors: tuple[str, ...] = ()
        rng = np.random.default_rng(first_seed)
        self.scenarios: list[Scenario] = [make_scenario(first_seed + i) for i in range(fleet.count)]
        self.clocks = [common.DeviceClock.start(rng) for _ in self.ids]
        self.boot_ids = [common.new_boot_id(rng) for _ in self.ids]
        self._imu_keys = [schemas.imu_key("rod", d) for d in self.ids]
        self._truth_keys = [schemas.truth_key("rod", d) for d in self.ids]
        self._labels = [sorted((t, e.family, phase) for e in sc.events
                               for t, phase in ((e.t_start_s, "start"), (e.t_end_s, "end")))
                        for sc in self.scenarios]  # fmt: skip

    def on_command(self, key: str, payload: bytes) -> None:
        """No reel: commands are ignored."""

    def tick(self, k: int) -> tuple[list[list[Message]], list[Message]]:
        """The next `samples_per_packet` samples of every recording (none once it has ended)."""
        n = self.fleet.samples_per_packet
        if k == 0:  # the first packet goes out as its last sample is taken: the device's wall clock says so
            now_us = time.time_ns() // 1000
            self.clocks = [common.DeviceClock(c.boot_offset_us, now_us - c.boot_offset_us - int(round(
                sc.t_s[min(n, sc.t_s.size) - 1] * 1e6))) for c, sc in zip(self.clocks, self.scenarios, strict=True)]
        data: list[list[Message]] = []
        extra: list[Message] = []
        for i, (dev, sc) in enumerate(zip(self.ids, self.scenarios, strict=True)):
            a, b = k * n, min((k + 1) * n, sc.t_s.size)
            if a >= b:
                data.append([])
                continue
            t0_us = self.clocks[i].boot_offset_us + int(round(sc.t_s[a] * 1e6))
            wall = self.clocks[i].wall_us(t0_us)
            data.append([common.imu_message(
                self._imu_keys[i], self.fleet.imu_encoding,
                device_id=dev, kind="rod", boot_id=self.boot_ids[i], seq=k, t0_us=t0_us, rate_hz=100.0,
                gyr_rad_s=sc.gyr_rad_s[a:b], acc_m_s2=sc.acc_m_s2[a:b], mag_uT=sc.mag_uT[a:b], wall_t0_us=wall,
            )])  # fmt: skip
            if self.fleet.truth:
                t_end = float(sc.t_s[b - 1])
                events = [{"label": lab, "phase": ph, "t_us": self.clocks[i].boot_offset_us + int(round(t * 1e6))}
                          for t, lab, ph in self._labels[i] if float(sc.t_s[a]) - 0.01 < t <= t_end]  # fmt: skip
                truth = {"v": 1, "device_id": dev, "kind": "rod", "boot_id": self.boot_ids[i], "seq": k,
                         "t0_us": t0_us, "rate_hz": 100.0, "wall_t0_us": wall, "events": events,
                         "quat_wxyz": common.rows(sc.quat_wxyz[a:b], 9), "tension_n": [0.0] * (b - a),
                         "breaking_strength_n": 40.0, "line_out_m": 30.0, "fish_state": "none",
                         "rest_pitch_rad": round(sc.rest_pitch_rad, 9)}  # fmt: skip
                extra.append(Message(self._truth_keys[i], common.encode_json(truth), schemas.ENCODING_TRUTH))
        return data, extra


def load_script(text: str | None) -> list[dict[str, Any]]:
    """A script from inline JSON or a JSON file path (a list of event dicts)."""
    if not text:
        return []
    raw = text if text.lstrip()[:1] in ("[", "{") else Path(text).read_text()
    items = json.loads(raw)
    if not isinstance(items, list):
        raise ValueError("script must be a JSON list of events")
    return items


def build_parser() -> argparse.ArgumentParser:
    """CLI of the rod simulator."""
    p = argparse.ArgumentParser(prog="python -m devices.sim_rod", description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    common.add_zenoh_args(p)
    common.add_fleet_args(p, id_prefix="rod", samples_per_packet=5)
    common.add_imu_args(p)
    g = p.add_argument_group("rod")
    g.add_argument("--script", default=None, help="events: inline JSON list or a path to a JSON file")
    g.add_argument("--random-events", action="store_true", help="random bites, fights, drop-backs, wind, handling")
    g.add_argument("--bite-per-h", type=float, default=None, help="random bite rate per rod and hour")
    g.add_argument("--holder-pitch-deg", type=float, default=35.0, help="rod holder elevation, degrees")
    g.add_argument("--breaking-strength-n", type=float, default=40.0, help="line breaking strength, N")
    g.add_argument("--drag-n", type=float, default=25.0, help="initial reel drag, N")
    g.add_argument("--no-mag", action="store_true", help="no magnetometer (6-axis IMU)")
    g.add_argument("--scenario", type=int, default=None, metavar="SEED",
                   help="play rod-scenario recordings SEED, SEED+1, .. (devices.rod_scenarios) instead of physics")
    return p


def make_fleet(args: argparse.Namespace, fleet: FleetSettings) -> RodFleet | ScenarioFleet:
    """RodFleet (or ScenarioFleet with --scenario) from parsed CLI options."""
    if args.scenario is not None:
        return ScenarioFleet(fleet, args.scenario)
    rates = RandomEventRates.lively() if args.random_events else RandomEventRates()
    if args.bite_per_h is not None:
        rates = dataclasses.replace(rates, bite_per_h=args.bite_per_h)
    rod = RodSettings(holder_pitch_rad=math.radians(args.holder_pitch_deg),
                      breaking_strength_n=args.breaking_strength_n, drag_n=args.drag_n)
    return RodFleet(fleet, rod, script=load_script(args.script), rates=rates, with_mag=not args.no_mag,
                    error_model=ImuErrorModel.preset(args.imu))


def main(argv: list[str] | None = None) -> int:
    """Run rods until --duration elapses or Ctrl-C."""
    args = build_parser().parse_args(argv)
    return common.run_main(make_fleet, args)


if __name__ == "__main__":
    raise SystemExit(main())
