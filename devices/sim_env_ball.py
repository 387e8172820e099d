"""Simulated environment balls: `python -m devices.sim_env_ball --help`.

A ball floats at a fishing spot with its probe hanging below it. About once a second it publishes
`rig/ball/{id}/env` (air temperature, humidity, light at the surface; water temperature, dissolved oxygen and
depth at the probe) and, with its GNSS receiver, where it floats (`gnss`, 2.5 m noise around the spot it was thrown
to); the first packet after a throw also carries the profile measured while the probe sank.
It holds the token `rig/ball/{id}`, publishes `rig/ball/{id}/truth` (noise-free values) and obeys
`rig/ball/{id}/cmd` (re-throw), or re-throws itself every `--rethrow-every` seconds.

Water model per spot: surface temperature with a daily cycle; a thermocline at `thermocline_m` (tanh step of
half-width `thermocline_width_m`) down to the deep temperature; dissolved oxygen = saturation at the local
temperature (Benson & Krause fit, fresh water, sea level) times a surface factor (photosynthesis by day,
respiration at night) above the thermocline and the spot's hypolimnion fraction below it.
"""

from __future__ import annotations

import argparse
import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from devices import common
from devices.common import FleetSettings, Message
from gateway import schemas


@dataclass(frozen=True)
class Spot:
    """A fishing spot's water column and surroundings."""

    name: str
    bottom_m: float
    thermocline_m: float
    thermocline_width_m: float
    surface_offset_c: float  # surface water warmer (+) or cooler (-) than the lake mean
    deep_temp_c: float
    deep_oxygen_frac: float  # oxygen below the thermocline as a fraction of saturation
    shade: float  # 0 = open sky, 1 = full shade
    probe_m: float  # probe line length below the ball
    lat_deg: float = 30.2460  # where a throw lands (WGS-84); defaults: West Lake, Hangzhou (seed 000's city)
    lon_deg: float = 120.1480


LAKE_SURFACE_ALT_M = 7.2
SPOTS: tuple[Spot, ...] = (
    Spot("reed_bay", 2.5, 1.8, 0.4, +1.5, 16.0, 0.55, 0.4, 1.5, 30.2551, 120.1402),
    Spot("deep_hole", 12.0, 5.0, 1.0, 0.0, 8.0, 0.10, 0.0, 6.0, 30.2468, 120.1473),
    Spot("inlet", 4.0, 3.0, 1.0, -3.0, 11.0, 0.90, 0.2, 2.0, 30.2396, 120.1385),
    Spot("dam_wall", 18.0, 7.0, 1.5, -0.5, 7.0, 0.30, 0.1, 4.0, 30.2417, 120.1556),
    Spot("sand_flat", 1.5, 1.2, 0.3, +2.5, 17.0, 0.85, 0.0, 1.0, 30.2523, 120.1531),
)
SPOT_BY_NAME = {s.name: s for s in SPOTS}


@dataclass(frozen=True)
class Weather:
    """Daily cycle parameters (a fair summer day)."""

    air_mean_c: float = 18.0
    air_amplitude_c: float = 6.0
    water_mean_c: float = 20.0
    water_amplitude_c: float = 1.5
    humidity_mean_pct: float = 70.0
    humidity_amplitude_pct: float = 20.0
    noon_lux: float = 100_000.0
    night_lux: float = 0.2


def oxygen_saturation_mg_l(temp_c: float | np.ndarray) -> Any:
    """Dissolved-oxygen saturation in fresh water at sea level, mg/L (Benson & Krause 1984 polynomial fit)."""
    t = np.asarray(temp_c, dtype=np.float64)
    return 14.62 - 0.3898 * t + 0.006969 * t**2 - 5.897e-5 * t**3


def sun(hour: float) -> float:
    """Relative sunlight 0..1: half-sine between 06:00 and 18:00."""
    return max(0.0, math.sin(math.pi * (hour - 6.0) / 12.0))


def surface(hour: float, weather: Weather, spot: Spot) -> dict[str, float]:
    """Air temperature (°C, peak 15:00), humidity (%), light (lux) and surface water temperature (°C, peak 16:00)."""
    c_air = math.cos(2 * math.pi * (hour - 15.0) / 24.0)
    return {
        "air_temp_c": weather.air_mean_c + weather.air_amplitude_c * c_air,
        "humidity_pct": min(100.0, max(0.0, weather.humidity_mean_pct - weather.humidity_amplitude_pct * c_air)),
        "light_lux": weather.night_lux + weather.noon_lux * (1.0 - 0.8 * spot.shade) * sun(hour) ** 1.3,
        "surface_temp_c": weather.water_mean_c + spot.surface_offset_c
        + weather.water_amplitude_c * math.cos(2 * math.pi * (hour - 16.0) / 24.0),
    }


def water_at(depth_m: float | np.ndarray, hour: float, weather: Weather, spot: Spot) -> tuple[Any, Any]:
    """Water temperature (°C) and dissolved oxygen (mg/L) at a depth, from the thermocline model."""
    z = np.asarray(depth_m, dtype=np.float64)
    t_s = surface(hour, weather, spot)["surface_temp_c"]
    upper = 0.5 * (1.0 - np.tanh((z - spot.thermocline_m) / spot.thermocline_width_m))
    temp = spot.deep_temp_c + (t_s - spot.deep_temp_c) * upper
    day = sun(hour)
    surface_frac = 1.0 + 0.15 * day - 0.1 * (1.0 - day)  # photosynthesis by day, respiration at night
    frac = spot.deep_oxygen_frac + (surface_frac - spot.deep_oxygen_frac) * upper
    return temp, oxygen_saturation_mg_l(temp) * frac


def profile(hour: float, weather: Weather, spot: Spot, step_m: float = 0.5) -> list[dict[str, float]]:
    """Noise-free water-column profile from the surface to the probe depth, every `step_m`."""
    depths = np.arange(0.0, probe_depth(spot) + 1e-9, step_m)
    temp, oxy = water_at(depths, hour, weather, spot)
    return [{"depth_m": round(float(d), 3), "water_temp_c": round(float(t), 3), "oxygen_mg_l": round(float(o), 3)}
            for d, t, o in zip(depths, temp, oxy, strict=True)]


def gnss_fix(spot: Spot, std_m: float, rng: np.random.Generator) -> dict[str, Any]:
    """Where the ball floats: the spot's position plus receiver noise of `std_m` per horizontal axis (m)."""
    north, east = rng.normal(0.0, std_m, 2)
    lat = spot.lat_deg + north / 111_320.0
    lon = spot.lon_deg + east / (111_320.0 * math.cos(math.radians(spot.lat_deg)))
    return {"lat_deg": round(float(lat), 7), "lon_deg": round(float(lon), 7), "alt_m": LAKE_SURFACE_ALT_M,
            "speed_m_s": 0.0,
            "fix_quality": 1}


def probe_depth(spot: Spot) -> float:
    """Where the probe hangs: its line length, but at least 0.2 m above the bottom."""
    return max(0.1, min(spot.probe_m, spot.bottom_m - 0.2))


@dataclass(frozen=True)
class BallNoise:
    """Sensor noise std (DHT22 air, BH1750 light, DS18B20 water, galvanic DO probe, pressure depth sensor)."""

    air_temp_c: float = 0.2
    humidity_pct: float = 1.5
    light_rel: float = 0.03
    water_temp_c: float = 0.05
    oxygen_mg_l: float = 0.1
    depth_m: float = 0.03
    gnss_m: float = 2.5  # horizontal position std of a consumer GNSS receiver (0: the ball has none)


class BallFleet:
    """`count` balls in one process; implements `devices.common.Fleet` (one packet per tick, ~1 Hz)."""

    kind = "ball"

    def __init__(self, fleet: FleetSettings, *, time_scale: float = 1.0, start_hour: float = 6.0,
                 rethrow_every_s: float | None = None, spots: Sequence[Spot] = SPOTS,
                 weather: Weather | None = None, noise: BallNoise | None = None) -> None:
        self.fleet, self.ids = fleet, fleet.ids
        self.command_selectors = tuple(schemas.ball_cmd_key(i) for i in self.ids) if len(self.ids) <= 16 else (
            schemas.SEL_BALL_CMD,)
        self.time_scale, self.start_hour, self.rethrow_every_s = time_scale, start_hour, rethrow_every_s
        self.spots, self.weather, self.noise = tuple(spots), weather or Weather(), noise or BallNoise()
        self.rng = np.random.default_rng(fleet.seed)
        self.clocks = [common.DeviceClock.start(self.rng) for _ in self.ids]
        self.boot_ids = [common.new_boot_id(self.rng) for _ in self.ids]
        self.index = {d: i for i, d in enumerate(self.ids)}
        self.spot = [self.spots[i % len(self.spots)] for i in range(len(self.ids))]
        self.fresh = [True] * len(self.ids)  # next packet carries the sinking profile
        self.pending_spot: list[str | None] = [None] * len(self.ids)
        self.events: list[list[dict[str, Any]]] = [[] for _ in self.ids]
        self.last_throw_s = [0.0] * len(self.ids)
        self.seq = [0] * len(self.ids)

    def hour_at(self, t_s: float) -> float:
        """Simulated hour of day at device time t_s since start."""
        return (self.start_hour + t_s * self.time_scale / 3600.0) % 24.0

    def on_command(self, key: str, payload: bytes) -> None:
        """Queue a re-throw from a BallCommand."""
        got = common.decode_command(key, payload, self.index)
        if got is not None and isinstance(got[1], schemas.BallCommand):
            self.pending_spot[got[0]] = got[1].spot or ""

    def rethrow(self, i: int, t_s: float, spot_name: str = "") -> None:
        """Throw ball i to `spot_name` (unknown or empty: a random other spot)."""
        spot = SPOT_BY_NAME.get(spot_name) if spot_name else None
        if spot is None:
            others = [s for s in self.spots if s is not self.spot[i]] or list(self.spots)
            spot = others[int(self.rng.integers(len(others)))]
        self.spot[i], self.fresh[i], self.last_throw_s[i] = spot, True, t_s
        self.events[i].append({"label": "rethrow", "phase": "instant", "t_us": self._t_us(i, t_s)})

    def _t_us(self, i: int, t_s: float) -> int:
        return self.clocks[i].boot_offset_us + int(round(t_s * 1e6))

    def tick(self, k: int) -> tuple[list[list[Message]], list[Message]]:
        """One reading per ball."""
        t_s = k * self.fleet.period_s
        hour = self.hour_at(t_s)
        nz, r = self.noise, self.rng
        data: list[list[Message]] = []
        extra: list[Message] = []
        for i, dev in enumerate(self.ids):
            if self.pending_spot[i] is not None:
                self.rethrow(i, t_s, self.pending_spot[i] or "")
                self.pending_spot[i] = None
            elif self.rethrow_every_s and t_s - self.last_throw_s[i] >= self.rethrow_every_s:
                self.rethrow(i, t_s)
            spot = self.spot[i]
            sf = surface(hour, self.weather, spot)
            depth = probe_depth(spot)
            temp, oxy = water_at(depth, hour, self.weather, spot)
            t_us = self._t_us(i, t_s)
            wall = self.clocks[i].wall_us(t_us)
            pkt: dict[str, Any] = {
                "v": 1, "device_id": dev, "kind": "ball", "boot_id": self.boot_ids[i], "seq": self.seq[i],
                "t_us": t_us, "wall_t_us": wall, "spot": spot.name,
                "air_temp_c": round(sf["air_temp_c"] + r.normal(0, nz.air_temp_c), 2),
                "humidity_pct": round(float(np.clip(sf["humidity_pct"] + r.normal(0, nz.humidity_pct), 0, 100)), 1),
                "light_lux": round(max(0.0, sf["light_lux"] * (1 + r.normal(0, nz.light_rel))), 1),
                "water_temp_c": round(float(temp) + r.normal(0, nz.water_temp_c), 3),
                "oxygen_mg_l": round(max(0.0, float(oxy) + r.normal(0, nz.oxygen_mg_l)), 3),
                "probe_depth_m": round(max(0.0, depth + r.normal(0, nz.depth_m)), 3),
                "bottom_depth_m": spot.bottom_m,
                "battery_v": round(3.9 - 2e-6 * t_s, 3), "rssi_dbm": float(-70 + round(r.normal(0, 3))),
            }
            if nz.gnss_m > 0:
                pkt["gnss"] = gnss_fix(spot, nz.gnss_m, r)
            if self.fresh[i]:
                pkt["profile"] = profile(hour, self.weather, spot)
                self.fresh[i] = False
            data.append([Message(schemas.env_key(dev), common.encode_json(pkt), schemas.ENCODING_ENV)])
            if self.fleet.truth:
                truth = {
                    "v": 1, "device_id": dev, "kind": "ball", "boot_id": self.boot_ids[i], "seq": self.seq[i],
                    "t_us": t_us, "wall_t_us": wall, "spot": spot.name, "air_temp_c": round(sf["air_temp_c"], 4),
                    "water_temp_c": round(float(temp), 4), "oxygen_mg_l": round(float(oxy), 4),
                    "light_lux": round(sf["light_lux"], 3), "humidity_pct": round(sf["humidity_pct"], 3),
                    "sim_hour_of_day": round(hour, 6) % 24.0, "events": self.events[i],
                }
                extra.append(Message(schemas.truth_key("ball", dev), common.encode_json(truth), schemas.ENCODING_TRUTH))
            self.events[i] = []
            self.seq[i] = (self.seq[i] + 1) % schemas.UINT32
        return data, extra


def build_parser() -> argparse.ArgumentParser:
    """CLI of the environment-ball simulator."""
    p = argparse.ArgumentParser(prog="python -m devices.sim_env_ball", description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    common.add_zenoh_args(p)
    common.add_fleet_args(p, id_prefix="ball", rate_hz=1.0, samples_per_packet=1)
    g = p.add_argument_group("ball")
    g.add_argument("--time-scale", type=float, default=1.0, help="simulated seconds per real second (default: 1)")
    g.add_argument("--start-hour", type=float, default=6.0, help="simulated hour of day at start (default: 6)")
    g.add_argument("--rethrow-every", type=float, default=None, help="re-throw to another spot every N seconds")
    g.add_argument("--no-gnss", action="store_true", help="balls without a GNSS receiver (no `gnss` in packets)")
    return p


def make_fleet(args: argparse.Namespace, fleet: FleetSettings) -> BallFleet:
    """BallFleet from parsed CLI options."""
    noise = BallNoise(gnss_m=0.0) if getattr(args, "no_gnss", False) else None
    return BallFleet(fleet, time_scale=args.time_scale, start_hour=args.start_hour,
                     rethrow_every_s=args.rethrow_every, noise=noise)


def main(argv: list[str] | None = None) -> int:
    """Run balls until --duration elapses or Ctrl-C."""
    return common.run_main(make_fleet, build_parser().parse_args(argv))


if __name__ == "__main__":
    raise SystemExit(main())
