"""THE gateway configuration: process `Settings` (env `RIG_*`) and the per-kind threshold models.

`Settings` is built once (in `__main__` or a test fixture) and passed down; nothing here reads the
environment at import. The threshold models are pydantic v2 so a bad REST body becomes a 422 with the
validator's message; they are frozen so the alarm layer can hold them as plain values.

Per-device configuration = the kind's defaults (stored in the DB, else the model defaults) with a
partial override dict merged on top and validated again: see `merge_thresholds`.
"""

from __future__ import annotations

import json
from collections.abc import Mapping
from pathlib import Path
from typing import Annotated, Any, Literal, Self, TypeVar

from pydantic import AfterValidator, BaseModel, ConfigDict, Field, model_validator
from pydantic_settings import BaseSettings, SettingsConfigDict

ZenohMode = Literal["peer", "client", "router"]


class Settings(BaseSettings):
    """Process-wide settings; every field can be set as `RIG_<FIELD>` (lists as JSON, e.g. `'["tcp/..."]'`)."""

    model_config = SettingsConfigDict(env_prefix="RIG_", extra="ignore")

    data_dir: Path = Field(default_factory=lambda: Path.cwd() / "var", description="Database, token file, logs.")
    zenoh_mode: ZenohMode = "peer"
    zenoh_listen: list[str] = Field(default_factory=lambda: ["tcp/127.0.0.1:7447"])
    zenoh_connect: list[str] = Field(default_factory=list)
    zenoh_multicast_scouting: bool = False
    http_host: str = "127.0.0.1"
    http_port: int = Field(default=8000, ge=0, le=65535)
    viser_host: str = "127.0.0.1"
    viser_port: int = Field(default=8080, ge=0, le=65535)
    default_filter: str = "default"
    attitude_interval_s: float = Field(default=0.02, ge=0.0, le=60.0, description="Least device time between two "
                                       "`attitude` messages of a device (0: the last sample of every packet).")
    attitude_blocks: bool = Field(default=False, description="Also publish every sample's attitude on "
                                  "`gw/{kind}/{id}/attitude/block`, one message per IMU packet, with BLOCK.")
    warmup_bias_seed: bool = Field(default=True, description="Seed a filter's gyro bias with the mean gyro of a "
                                   "resting warm-up window (False: start from zero bias, as offline evaluate).")
    ingest_queue_size: int = Field(default=10_000, ge=1, description="Packets buffered between zenoh and the pipeline.")
    ingest_coalesce_s: float = Field(default=0.01, ge=0.0, le=0.1, description="A batch waits up to this long after "
                                     "its oldest packet arrived for more packets to join it (the cost is paid mostly "
                                     "per device per batch; docs/gateway.md, Data path). 0: a batch per wake-up.")
    ws_queue_size: int = Field(default=256, ge=1, description="Messages buffered per websocket client before dropping.")
    max_devices: int = Field(default=1000, ge=1, description="Devices the gateway keeps state for; packets and tokens "
                             "of further new ids are dropped and counted (`device_limit`): ids are free to choose.")
    allowed_hosts: list[str] = Field(default_factory=list, description="Host names the HTTP server answers to besides "
                                     "IP literals, localhost, dotless and .local names (DNS-rebinding guard).")
    allowed_origins: list[str] = Field(default_factory=list, description="Browser origins (e.g. "
                                       "`https://ops.example`) that may open /ws/stream without the token.")
    shards: int = Field(default=0, ge=0, le=64, description="Gateway shard processes on this machine (`--shards`); "
                        "0 (default): one per core, at most 4. Each serves a share of the devices "
                        "(docs/gateway.md, Shards).")
    shard_id: str | None = Field(default=None, pattern=r"^[A-Za-z0-9_-]{1,64}$", description="This shard's id "
                                 "(default: host name and REST port); the devices it serves follow from the ids.")
    shard_devices: list[str] = Field(default_factory=list, description="Device-id glob patterns this shard serves "
                                     "(`--devices 'site1-*'`, repeatable); empty: every device.")
    shard_subscribe: Literal["all", "own"] = Field(default="all", description="`all`: a shard subscribes to every "
                                                   "device's data and drops the others' (no packet of a new device is "
                                                   "missed); `own`: beside other shards, only its own devices' keys, "
                                                   "found by their liveliness tokens (the router sends it nothing "
                                                   "else; a new device's first packets before its owner subscribes, "
                                                   "a few ms, are not received). docs/gateway.md, Shards.")
    shard_lease_s: float = Field(default=1.0, gt=0.0, le=60.0, description="zenoh lease of the shard's links: a "
                                 "shard whose machine vanishes without closing its links leaves the live set then.")
    shard_mirror_hz: float = Field(default=10.0, ge=0.0, le=100.0, description="Other shards' attitude and swing "
                                   "messages handed to this shard's dashboard stream, at most this often per device "
                                   "(0: none; their alarms always are).")
    zenoh_config_file: Path | None = Field(default=None, description="A zenoh JSON5 config file (TLS/mTLS, "
                                           "user/password, access control); the options above override its keys.")

    @property
    def db_path(self) -> Path:
        """SQLite file inside `data_dir`."""
        return self.data_dir / "gateway.sqlite3"

    def zenoh_config(self) -> dict[str, str]:
        """Key -> json5 text, for `conf.insert_json5(key, value)` on a fresh `zenoh.Config()`."""
        return {
            "mode": json.dumps(self.zenoh_mode),
            "listen/endpoints": json.dumps(self.zenoh_listen),
            "connect/endpoints": json.dumps(self.zenoh_connect),
            "scouting/multicast/enabled": json.dumps(self.zenoh_multicast_scouting),
        }


class _Thresholds(BaseModel):
    model_config = ConfigDict(frozen=True, extra="forbid")


# Bite-alarm sensitivity steps, 1 (least sensitive) .. 5 (most), like the dial on commercial bite alarms.
# Each step changes three things together (see docs/alarms.md):
#   theta1_scale   effective bite deviation = bite_deviation_deg * scale
#   confirm_s      the pitch must stay beyond the threshold this long (rejects single-sample spikes)
#   cue_fraction   the acceleration cue alarms early once pitch has dropped by this fraction of theta1 ...
#   cue_acc_m_s2   ... while the tip accelerates downwards by at least this much (0 fraction = cue off)
SENSITIVITY_STEPS: dict[int, tuple[float, float, float, float]] = {
    # step: (theta1_scale, confirm_s, cue_fraction, cue_acc_m_s2)
    1: (1.5, 0.05, 0.0, 0.0),
    2: (1.25, 0.03, 0.3, 4.0),
    3: (1.0, 0.02, 0.2, 3.0),
    4: (0.8, 0.01, 0.15, 2.5),
    5: (0.6, 0.0, 0.1, 2.0),
}


class RodThresholds(_Thresholds):
    """Smart-rod alarm thresholds (seed 000 §3.3: theta1 bite, theta2 reel switch, theta3 line limit).

    theta1 = 10 deg is the paper's. The paper defines theta2/theta3 but gives no values; they depend on the rod and
    line, so the defaults fit the rod the project ships, `devices.rod_physics.RodSettings` (the simulator stands in
    for the hardware): bend = 60 deg * tanh(T / 15 N), resting at T = 1 N (bend 4.0 deg), 40 N line. As pitch drops
    below rest: theta3 = drop at the breaking load (55.4 deg -> 55), theta2 = drop at half of it (20 N: 48.2 deg
    -> 48), as `bench.fights` sets them. Auto reel then asks for a drag of 60 % of `line_breaking_n` (24 N).
    Another rod or line needs its own values (docs/control.md, "Gateway defaults").
    """

    bite_deviation_deg: float = Field(default=10.0, gt=0.0, le=45.0, description="theta1: pitch drop = bite.")
    sensitivity: int = Field(default=3, ge=1, le=5, description="1 least .. 5 most sensitive; scales theta1, see docs.")
    line_switch_deg: float = Field(default=48.0, gt=0.0, le=80.0, description="theta2: pay out line above this drop.")
    line_limit_deg: float = Field(default=55.0, gt=0.0, le=85.0, description="theta3: drop at breaking load.")
    line_critical_fraction: float = Field(default=0.9, gt=0.5, le=1.0, description="Critical at this share of theta3.")
    drop_back_rise_deg: float = Field(default=5.0, gt=0.0, le=45.0, description="Pitch rise above rest = slack line.")
    line_breaking_n: float = Field(default=40.0, gt=0.0, description="Breaking load of the line in newtons.")
    tension_warn_fraction: float = Field(default=0.8, gt=0.0, le=1.0, description="Critical at this share of breaking.")
    rearm_quiet_s: float = Field(default=5.0, ge=0.0, le=600.0, description="Pitch near rest this long re-arms.")
    baseline_tau_s: float = Field(default=5.0, gt=0.0, le=600.0, description="Rest-pitch tracking time constant.")

    @property
    def effective_bite_deg(self) -> float:
        """theta1 after the sensitivity scale."""
        return self.bite_deviation_deg * SENSITIVITY_STEPS[self.sensitivity][0]

    @model_validator(mode="after")
    def _ordered(self) -> Self:
        if not self.effective_bite_deg < self.line_switch_deg < self.line_limit_deg:
            raise ValueError(
                f"need theta1 < theta2 < theta3 (theta1 after sensitivity {self.sensitivity}: "
                f"{self.effective_bite_deg:g} deg, theta2 {self.line_switch_deg:g}, theta3 {self.line_limit_deg:g})"
            )
        return self


OffsetM = Annotated[float, Field(ge=-1.0, le=1.0, allow_inf_nan=False)]
"""One coordinate of a mounting offset, m: a hook's IMU sits within a metre of its rope axis."""
TiltDeg = Annotated[float, Field(ge=-15.0, le=15.0, allow_inf_nan=False)]
"""One angle of a mounting tilt, degrees: more than 15° off square is a mount to fix, not to correct."""
AccBiasM_S2 = Annotated[float, Field(ge=-1.0, le=1.0, allow_inf_nan=False)]
"""One axis of an accelerometer's offset, m/s²: a raw MPU-6050 is within ±80 mg; more is a broken board."""


class HookThresholds(_Thresholds):
    """Crane-hook swing angle (Theta, seed 001 eq. 6) and torsion (phi) limits, with clearing hysteresis."""

    swing_warn_deg: float = Field(default=5.0, gt=0.0, le=90.0)
    swing_critical_deg: float = Field(default=10.0, gt=0.0, le=90.0)
    torsion_warn_deg: float = Field(default=30.0, gt=0.0, le=180.0)
    torsion_critical_deg: float = Field(default=60.0, gt=0.0, le=180.0)
    hysteresis_deg: float = Field(default=1.0, ge=0.0, le=30.0, description="An alarm clears below threshold - this.")
    # Not limits but the hook's geometry, kept here so they follow the same defaults/override/REST path.
    rope_length_m: float | None = Field(default=None, ge=0.5, le=500.0, description="Boom tip to hook (and load "
                                        "centre), m, as measured: the hook filter's pendulum length, a prior it "
                                        "trusts to 15 %. None: not configured, the filter finds it from the "
                                        "pendulum frequency (from 10 m, a wide prior; its estimate is in the swing "
                                        "messages). A change restarts fusion.")
    imu_offset_m: tuple[OffsetM, OffsetM, OffsetM] | None = Field(default=None, description="Where the IMU sits "
                                                                  "from the rope axis, m, in its own axes (x, y, z; "
                                                                  "z up the rope), as measured on the hook: the hook "
                                                                  "filter's lever arm, a prior it trusts to 1 cm. "
                                                                  "None: 0.1 m on x, learnt from the data (less "
                                                                  "well). A change restarts fusion.")
    imu_tilt_deg: tuple[TiltDeg, TiltDeg] | None = Field(default=None, description="How the IMU is tilted on the "
                                                           "hook: the rotation about its x and y axes (degrees) "
                                                           "that takes its axes onto the hook's (z up the rope), as "
                                                           "`python -m gateway.calibrate --hook-mount` fits it. None: "
                                                           "square to the rope. A change restarts fusion.")
    acc_bias_xy_m_s2: tuple[AccBiasM_S2, AccBiasM_S2] | None = Field(default=None, description="The "
                                                                    "accelerometer's x/y offset on the hook, m/s², "
                                                                    "in the hook's axes, as `python -m gateway."
                                                                    "calibrate --hook-mount` fits it (a twist in calm "
                                                                    "air): the hook filter then takes a steady force "
                                                                    "at its start beyond it for wind, which leans the "
                                                                    "rope, instead of for more offset. Measure it near "
                                                                    "the working temperature. None: not measured. A "
                                                                    "change restarts fusion.")
    rest_heading_deg: float | None = Field(default=None, ge=-180.0, le=180.0, description="Heading of the untwisted "
                                           "hook's body x, CCW from East, in the gateway's heading frame (9D: "
                                           "magnetic); torsion is measured from it. None: the first fused heading.")

    @model_validator(mode="after")
    def _ordered(self) -> Self:
        for name, warn, crit in (
            ("swing", self.swing_warn_deg, self.swing_critical_deg),
            ("torsion", self.torsion_warn_deg, self.torsion_critical_deg),
        ):
            if not warn < crit:
                raise ValueError(f"{name}: warn ({warn:g} deg) must be below critical ({crit:g} deg)")
            if self.hysteresis_deg >= warn:
                raise ValueError(f"hysteresis ({self.hysteresis_deg:g} deg) must be below {name} warn ({warn:g} deg)")
        return self


class ImuSettings(_Thresholds):
    """A plain IMU (kind `imu`) has no limits of its own: attitude and height only. Its filter, calibration and
    magnetometer use are device settings like any kind's (`PUT /api/devices/{id}/settings`)."""


# Preferred water temperature (deg C) per species: typical ranges from temperature-preference compilations
# (Coutant 1977, J. Fish. Res. Board Can. 34:739; Wismer & Christie 1987, GLFC Spec. Pub. 87-3):
# common carp ~ 18-26, northern pike ~ 10-20 (large pike prefer the cool end), perch ~ 17-24,
# rainbow/brown trout ~ 10-16, largemouth bass ~ 21-27.
SPECIES_TEMP_C: dict[str, tuple[float, float]] = {
    "carp": (18.0, 26.0),
    "pike": (10.0, 20.0),
    "perch": (17.0, 24.0),
    "trout": (10.0, 16.0),
    "bass": (21.0, 27.0),
}


class SpotPreferences(_Thresholds):
    """What the angler fishes for; spot scoring uses the species' preferred temperature ranges."""

    species: tuple[str, ...] = Field(default=("carp",), min_length=1)

    @model_validator(mode="after")
    def _known(self) -> Self:
        unknown = sorted(set(self.species) - SPECIES_TEMP_C.keys())
        if unknown:
            raise ValueError(f"unknown species {unknown}; known: {sorted(SPECIES_TEMP_C)}")
        return self

    def temp_ranges_c(self) -> dict[str, tuple[float, float]]:
        """Preferred temperature range (deg C) for each target species."""
        return {s: SPECIES_TEMP_C[s] for s in self.species}


ThresholdModel = RodThresholds | HookThresholds | SpotPreferences | ImuSettings
T = TypeVar("T", bound=BaseModel)
THRESHOLD_MODELS: dict[str, type[ThresholdModel]] = {
    "rod": RodThresholds,
    "hook": HookThresholds,
    "ball": SpotPreferences,
    "imu": ImuSettings,
}


def _check_calibration(cal: dict[str, Any] | None) -> dict[str, Any] | None:
    """A calibration JSON must load with `DeviceCalibration.from_json` (its ValueError becomes the 422 message)."""
    if cal is not None:
        from gateway.calibrate import DeviceCalibration  # lazy: keeps config importable without numpy/fusion

        DeviceCalibration.from_json(cal)
    return cal


# The JSON `python -m gateway.calibrate` writes (docs/calibration.md), None = raw sensor values.
CalibrationJson = Annotated[dict[str, Any] | None, AfterValidator(_check_calibration)]


class DeviceSettings(BaseModel):
    """Per-device settings: filter (None = `Settings.default_filter`), a partial thresholds override, for a rod
    whether the reel is in auto (fish-walking) mode, so the mode survives a restart, and the IMU calibration applied
    to the device's accelerometer and magnetometer before fusion (None: none)."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    filter_name: str | None = None
    thresholds: dict[str, Any] = Field(default_factory=dict)
    auto_reel: bool = False
    calibration: CalibrationJson = None


def merge_thresholds(defaults: T, override: Mapping[str, Any]) -> T:
    """Defaults with `override` fields replaced, validated again (raises pydantic.ValidationError)."""
    return type(defaults).model_validate({**defaults.model_dump(), **override})


def default_thresholds(kind: str) -> ThresholdModel:
    """Model defaults for a device kind ("rod", "hook", "ball"); KeyError for an unknown kind."""
    return THRESHOLD_MODELS[kind]()


def effective_settings(
    kind: str, device: DeviceSettings | None, default_filter: str, defaults: ThresholdModel | None = None
) -> tuple[str, ThresholdModel]:
    """(filter name, thresholds) of one device: the kind's defaults (`defaults`, else the model's) with the device's
    override merged on top; its filter, else `default_filter` (the kind's: the pipeline passes the hook filter for
    hooks). The one place configuration is merged (`Pipeline.effective` calls it)."""
    base = defaults if defaults is not None else default_thresholds(kind)
    if device is None:
        return default_filter, base
    return device.filter_name or default_filter, merge_thresholds(base, device.thresholds)
