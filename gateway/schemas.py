"""THE wire protocol: pydantic models, key expressions, encodings, `decode()` and `SequenceTracker`.

Devices import this module as well as the gateway; `docs/protocol.md` documents it for non-Python devices.

Error tree: `DecodeError(reason, detail)` is the only exception `decode()` raises; `reason` is one of
`REASONS` (a small fixed set, used as counter labels on `gw/diag/ingest`).

Key layout (`{kind}` in `rod`, `hook`, `ball`; `{device_id}` matches `DEVICE_ID_PATTERN`):

    rig/{rod|hook}/{id}/imu        ImuPacket         device -> gateway
    rig/ball/{id}/env              EnvPacket         device -> gateway
    rig/rod/{id}/reel              ReelStatus        device -> gateway
    rig/rod/{id}/truth             RodTruth          simulator -> tests/benches (ground truth)
    rig/hook/{id}/truth            HookTruth         simulator -> tests/benches
    rig/ball/{id}/truth            BallTruth         simulator -> tests/benches
    rig/{kind}/{id}                liveliness token of a device
    rig/rod/{id}/reel/cmd          ReelCommand       gateway/app -> device (CongestionControl.BLOCK)
    rig/ball/{id}/cmd              BallCommand       gateway/app -> device (CongestionControl.BLOCK)
    gw/{rod|hook}/{id}/attitude    Attitude          gateway -> apps
    gw/{rod|hook}/{id}/attitude/block  AttitudeBlock  gateway -> apps (opt-in `--attitude-blocks`, BLOCK)
    gw/hook/{id}/swing             Swing             gateway -> apps
    gw/{rod|hook}/{id}/height      Height            gateway -> apps (vertical velocity and heave, seed 002)
    gw/{kind}/{id}/alarm           AlarmEvent        gateway -> apps (BLOCK)
    gw/spots                       SpotRanking       gateway -> apps
    gw/diag/ingest                 IngestStats       gateway -> apps
    gw/diag/rejected               RejectedPacket    gateway -> apps
    gw/config/{kind}/{id}          DeviceConfig      gateway queryable
    gw/alive                       liveliness token of the gateway
"""

from __future__ import annotations

import inspect
import json
import math
import re
from dataclasses import dataclass, field
from typing import Annotated, Any, Final, Literal, TypeAlias

import numpy as np
from numpy.typing import NDArray
from pydantic import BaseModel, ConfigDict, Field, ValidationError, model_validator
from pydantic_core import PydanticCustomError

PROTOCOL_VERSION: Final = 1
MAX_PAYLOAD_BYTES: Final = 512 * 1024
MAX_SAMPLES: Final = 1000
UINT32: Final = 2**32
DEVICE_ID_PATTERN: Final = r"^[A-Za-z0-9_-]{1,64}$"
_DEVICE_ID_RE = re.compile(DEVICE_ID_PATTERN)

GYR_LIMIT_RAD_S: Final = 50.0
ACC_LIMIT_M_S2: Final = 400.0
MAG_LIMIT_UT: Final = 5000.0
RATE_MIN_HZ: Final = 1.0
RATE_MAX_HZ: Final = 2000.0

DeviceKind: TypeAlias = Literal["rod", "hook", "ball"]
ImuKind: TypeAlias = Literal["rod", "hook"]
KINDS: Final[tuple[str, ...]] = ("rod", "hook", "ball")
IMU_KINDS: Final[tuple[str, ...]] = ("rod", "hook")

ENCODING_IMU: Final = "application/json;schema=rig.imu.v1"
ENCODING_ENV: Final = "application/json;schema=rig.env.v1"
ENCODING_REEL: Final = "application/json;schema=rig.reel.v1"
ENCODING_TRUTH: Final = "application/json;schema=rig.truth.v1"
ENCODING_REEL_CMD: Final = "application/json;schema=rig.reel_cmd.v1"
ENCODING_BALL_CMD: Final = "application/json;schema=rig.ball_cmd.v1"
ENCODING_GW: Final = "application/json;schema=rig.gw.v1"

Reason: TypeAlias = Literal[
    "too_large", "unknown_key", "bad_json", "version", "schema", "non_finite", "out_of_range", "key_mismatch"
]
REASONS: Final[tuple[str, ...]] = (
    "too_large", "unknown_key", "bad_json", "version", "schema", "non_finite", "out_of_range", "key_mismatch"
)


class DecodeError(Exception):
    """A packet the gateway must count and drop; `reason` is one of `REASONS`, `detail` is for humans."""

    def __init__(self, reason: Reason, detail: str = "") -> None:
        super().__init__(f"{reason}: {detail}" if detail else reason)
        self.reason: Reason = reason
        self.detail = detail


# ---------------------------------------------------------------------------------------------------------------
# Key expressions
# ---------------------------------------------------------------------------------------------------------------


def valid_device_id(device_id: str) -> bool:
    """True when `device_id` matches DEVICE_ID_PATTERN (1-64 of A-Z a-z 0-9 _ -)."""
    return _DEVICE_ID_RE.fullmatch(device_id) is not None


def _check_id(device_id: str) -> str:
    if not _DEVICE_ID_RE.fullmatch(device_id):
        raise ValueError(f"device id {device_id!r} does not match {DEVICE_ID_PATTERN}")
    return device_id


def imu_key(kind: str, device_id: str) -> str:
    """`rig/{kind}/{device_id}/imu` (kind rod or hook)."""
    return f"rig/{kind}/{_check_id(device_id)}/imu"


def env_key(device_id: str) -> str:
    """`rig/ball/{device_id}/env`."""
    return f"rig/ball/{_check_id(device_id)}/env"


def reel_key(device_id: str) -> str:
    """`rig/rod/{device_id}/reel`: reel status."""
    return f"rig/rod/{_check_id(device_id)}/reel"


def truth_key(kind: str, device_id: str) -> str:
    """`rig/{kind}/{device_id}/truth`: simulator ground truth."""
    return f"rig/{kind}/{_check_id(device_id)}/truth"


def device_token_key(kind: str, device_id: str) -> str:
    """`rig/{kind}/{device_id}`: the device's liveliness token."""
    return f"rig/{kind}/{_check_id(device_id)}"


def reel_cmd_key(device_id: str) -> str:
    """`rig/rod/{device_id}/reel/cmd`: ReelCommand to a rod."""
    return f"rig/rod/{_check_id(device_id)}/reel/cmd"


def ball_cmd_key(device_id: str) -> str:
    """`rig/ball/{device_id}/cmd`: BallCommand to an environment ball."""
    return f"rig/ball/{_check_id(device_id)}/cmd"


def attitude_key(kind: str, device_id: str) -> str:
    """`gw/{kind}/{device_id}/attitude`."""
    return f"gw/{kind}/{_check_id(device_id)}/attitude"


def attitude_block_key(kind: str, device_id: str) -> str:
    """`gw/{kind}/{device_id}/attitude/block`: every sample's attitude, one message per IMU packet (opt-in)."""
    return f"gw/{kind}/{_check_id(device_id)}/attitude/block"


def height_key(kind: str, device_id: str) -> str:
    """Gateway height / heave of an IMU device (seed 002 eq. 8)."""
    return f"gw/{kind}/{_check_id(device_id)}/height"


def swing_key(device_id: str) -> str:
    """`gw/hook/{device_id}/swing`."""
    return f"gw/hook/{_check_id(device_id)}/swing"


def alarm_key(kind: str, device_id: str) -> str:
    """`gw/{kind}/{device_id}/alarm`."""
    return f"gw/{kind}/{_check_id(device_id)}/alarm"


def config_key(kind: str, device_id: str) -> str:
    """`gw/config/{kind}/{device_id}`: queryable with the device's current thresholds."""
    return f"gw/config/{kind}/{_check_id(device_id)}"


SPOTS_KEY: Final = "gw/spots"
DIAG_INGEST_KEY: Final = "gw/diag/ingest"
DIAG_REJECTED_KEY: Final = "gw/diag/rejected"
GW_ALIVE_KEY: Final = "gw/alive"

# Selectors (key expressions with wildcards) for subscribers.
SEL_IMU: Final = "rig/*/*/imu"
SEL_ENV: Final = "rig/ball/*/env"
SEL_REEL: Final = "rig/rod/*/reel"
SEL_TRUTH: Final = "rig/*/*/truth"
SEL_DEVICE_DATA: Final[tuple[str, ...]] = (SEL_IMU, SEL_ENV, SEL_REEL)
SEL_DEVICE_TOKENS: Final = "rig/*/*"
SEL_REEL_CMD: Final = "rig/rod/*/reel/cmd"
SEL_BALL_CMD: Final = "rig/ball/*/cmd"
SEL_GW_CONFIG: Final = "gw/config/**"


@dataclass(frozen=True, slots=True)
class ParsedKey:
    """A device key split into its parts; `topic` is the suffix (`imu`, `env`, `reel`, `truth`, `reel/cmd`, `cmd`)."""

    kind: str
    device_id: str
    topic: str


_TOPICS: Final[dict[str, tuple[str, ...]]] = {
    "imu": ("rod", "hook"),
    "env": ("ball",),
    "reel": ("rod",),
    "truth": ("rod", "hook", "ball"),
    "reel/cmd": ("rod",),
    "cmd": ("ball",),
}


def parse_key(key: str) -> ParsedKey:
    """Split a device key `rig/{kind}/{id}/{topic}`; raises DecodeError('unknown_key') for anything else."""
    parts = key.split("/")
    if len(parts) < 4 or parts[0] != "rig":
        raise DecodeError("unknown_key", key[:200])
    kind, device_id, topic = parts[1], parts[2], "/".join(parts[3:])
    kinds = _TOPICS.get(topic)
    if kinds is None or kind not in kinds or not _DEVICE_ID_RE.fullmatch(device_id):
        raise DecodeError("unknown_key", key[:200])
    return ParsedKey(kind, device_id, topic)


# ---------------------------------------------------------------------------------------------------------------
# Field types (constraints run in pydantic-core, so validation stays fast)
# ---------------------------------------------------------------------------------------------------------------

_Gyr = Annotated[float, Field(ge=-GYR_LIMIT_RAD_S, le=GYR_LIMIT_RAD_S, allow_inf_nan=False)]
_Acc = Annotated[float, Field(ge=-ACC_LIMIT_M_S2, le=ACC_LIMIT_M_S2, allow_inf_nan=False)]
_Mag = Annotated[float, Field(ge=-MAG_LIMIT_UT, le=MAG_LIMIT_UT, allow_inf_nan=False)]
_Unit = Annotated[float, Field(ge=-1.0, le=1.0, allow_inf_nan=False)]
_Angle = Annotated[float, Field(ge=-2 * math.pi, le=2 * math.pi, allow_inf_nan=False)]
Finite = Annotated[float, Field(allow_inf_nan=False)]
NonNeg = Annotated[float, Field(ge=0.0, allow_inf_nan=False)]
Uint32 = Annotated[int, Field(ge=0, lt=UINT32)]
TimeUs = Annotated[int, Field(ge=0, lt=2**63)]
DeviceId = Annotated[str, Field(pattern=DEVICE_ID_PATTERN)]
Name = Annotated[str, Field(min_length=1, max_length=64)]
Vec3Gyr = tuple[_Gyr, _Gyr, _Gyr]
Vec3Acc = tuple[_Acc, _Acc, _Acc]
Vec3Mag = tuple[_Mag, _Mag, _Mag]
QuatWxyz = tuple[_Unit, _Unit, _Unit, _Unit]
RateHz = Annotated[float, Field(ge=RATE_MIN_HZ, le=RATE_MAX_HZ, allow_inf_nan=False)]
TempC = Annotated[float, Field(ge=-60.0, le=150.0, allow_inf_nan=False)]
BatteryV = Annotated[float, Field(ge=0.0, le=60.0, allow_inf_nan=False)]
RssiDbm = Annotated[float, Field(ge=-150.0, le=0.0, allow_inf_nan=False)]
Version = Literal[1]


def _samples(max_len: int = MAX_SAMPLES) -> Any:
    return Field(min_length=1, max_length=max_len)


class WireModel(BaseModel):
    """Base of every wire model: strict types, unknown fields rejected, immutable."""

    model_config = ConfigDict(strict=True, frozen=True, extra="forbid")

    def to_json(self) -> bytes:
        """Compact JSON bytes, optional fields left out when None."""
        return self.model_dump_json(exclude_none=True).encode()


def _check_lengths(n: int, **arrays: list[Any] | None) -> None:
    for name, arr in arrays.items():
        if arr is not None and len(arr) != n:
            raise PydanticCustomError("length_mismatch", f"{name} has {len(arr)} samples, expected {n}")


def _check_unit_quats(quats: list[tuple[float, float, float, float]]) -> None:
    for i, q in enumerate(quats):
        norm2 = q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3]
        if abs(norm2 - 1.0) > 1e-3:
            raise PydanticCustomError("out_of_range", f"quaternion {i} has norm {math.sqrt(norm2):.4f}, expected 1")


# ---------------------------------------------------------------------------------------------------------------
# Device -> gateway
# ---------------------------------------------------------------------------------------------------------------


class GnssFix(WireModel):
    """A position fix from the device's GNSS receiver (seed 004's BeiDou module), for devices that carry one."""

    lat_deg: Annotated[float, Field(ge=-90.0, le=90.0, allow_inf_nan=False)]
    lon_deg: Annotated[float, Field(ge=-180.0, le=180.0, allow_inf_nan=False)]
    alt_m: Annotated[float, Field(ge=-1000.0, le=20_000.0, allow_inf_nan=False)] | None = None
    speed_m_s: Annotated[float, Field(ge=0.0, le=500.0, allow_inf_nan=False)] | None = None
    fix_quality: Annotated[int, Field(ge=0, le=8)] = 1


class ImuPacket(WireModel):
    """A batch of n IMU samples at `rate_hz`; sample i was taken at `t0_us + i * 1e6 / rate_hz` (device clock)."""

    v: Version
    device_id: DeviceId
    kind: ImuKind
    boot_id: Uint32
    seq: Uint32
    t0_us: TimeUs
    rate_hz: RateHz
    gyr_rad_s: list[Vec3Gyr] = _samples()
    acc_m_s2: list[Vec3Acc] = _samples()
    mag_uT: list[Vec3Mag] | None = Field(default=None, min_length=1, max_length=MAX_SAMPLES)
    temp_c: TempC | None = None
    battery_v: BatteryV | None = None
    rssi_dbm: RssiDbm | None = None
    wall_t0_us: TimeUs | None = None
    gnss: GnssFix | None = None
    depth_m: Annotated[float, Field(ge=0.0, le=1000.0, allow_inf_nan=False)] | None = None

    @model_validator(mode="after")
    def _equal_lengths(self) -> ImuPacket:
        _check_lengths(len(self.gyr_rad_s), acc_m_s2=self.acc_m_s2, mag_uT=self.mag_uT)
        return self

    @property
    def n(self) -> int:
        """Samples in the packet."""
        return len(self.gyr_rad_s)

    def arrays(self) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64] | None]:
        """(gyr_rad_s, acc_m_s2, mag_uT or None) as float64 arrays of shape (n, 3)."""
        mag = None if self.mag_uT is None else np.asarray(self.mag_uT, dtype=np.float64)
        return np.asarray(self.gyr_rad_s, dtype=np.float64), np.asarray(self.acc_m_s2, dtype=np.float64), mag

    def sample_times_us(self) -> NDArray[np.float64]:
        """Device time of each sample, µs: t0_us + i · 1e6 / rate_hz."""
        times: NDArray[np.float64] = self.t0_us + np.arange(self.n, dtype=np.float64) * (1e6 / self.rate_hz)
        return times


class ProfilePoint(WireModel):
    """One level of a water-column profile measured while the ball's probe sank."""

    depth_m: NonNeg
    water_temp_c: TempC
    oxygen_mg_l: Annotated[float, Field(ge=0.0, le=30.0, allow_inf_nan=False)]


class EnvPacket(WireModel):
    """Environment-ball reading (about 1 Hz). Air values at the surface, water values at the probe depth."""

    v: Version
    device_id: DeviceId
    kind: Literal["ball"] = "ball"
    boot_id: Uint32
    seq: Uint32
    t_us: TimeUs
    wall_t_us: TimeUs | None = None
    spot: Name
    air_temp_c: TempC
    humidity_pct: Annotated[float, Field(ge=0.0, le=100.0, allow_inf_nan=False)]
    light_lux: Annotated[float, Field(ge=0.0, le=200_000.0, allow_inf_nan=False)]
    water_temp_c: TempC
    oxygen_mg_l: Annotated[float, Field(ge=0.0, le=30.0, allow_inf_nan=False)]
    probe_depth_m: Annotated[float, Field(ge=0.0, le=1000.0, allow_inf_nan=False)]
    bottom_depth_m: Annotated[float, Field(ge=0.0, le=1000.0, allow_inf_nan=False)] | None = None
    profile: list[ProfilePoint] | None = Field(default=None, min_length=1, max_length=200)
    battery_v: BatteryV | None = None
    rssi_dbm: RssiDbm | None = None
    gnss: GnssFix | None = None


ReelAction: TypeAlias = Literal["in", "out", "stop", "speed"]
MotorState: TypeAlias = Literal["stopped", "reeling_in", "paying_out", "fault"]


class ReelStatus(WireModel):
    """Reel state (10 Hz on the simulator). `line_in_speed_m_s` > 0 while line comes in, < 0 while it goes out."""

    v: Version
    device_id: DeviceId
    kind: Literal["rod"] = "rod"
    boot_id: Uint32
    seq: Uint32
    t_us: TimeUs
    wall_t_us: TimeUs | None = None
    line_out_m: Annotated[float, Field(ge=0.0, le=10_000.0, allow_inf_nan=False)]
    line_in_speed_m_s: Annotated[float, Field(ge=-100.0, le=100.0, allow_inf_nan=False)]
    motor: MotorState
    mode: ReelAction
    cmd_speed_m_s: Annotated[float, Field(ge=-100.0, le=100.0, allow_inf_nan=False)]
    drag_n: NonNeg
    tension_n: NonNeg | None = None
    last_cmd_id: Uint32 | None = None


TruthPhase: TypeAlias = Literal["start", "end", "instant"]


class TruthEvent(WireModel):
    """A labelled event in device time, e.g. `bite` start/end, `line_break` instant."""

    label: Name
    phase: TruthPhase
    t_us: TimeUs
    value: Finite | None = None


class _TruthBase(WireModel):
    """Fields shared by every truth packet; `seq`, `t0_us`, `rate_hz` equal those of the matching data packet."""

    v: Version
    device_id: DeviceId
    boot_id: Uint32
    seq: Uint32
    t0_us: TimeUs
    rate_hz: RateHz
    wall_t0_us: TimeUs | None = None
    events: list[TruthEvent] = Field(default_factory=list, max_length=100)


FishState: TypeAlias = Literal["none", "nibbling", "hooked", "fighting", "tired", "landed", "escaped"]


class RodTruth(_TruthBase):
    """Rod ground truth: true tip attitude per IMU sample, line tension per sample, fish state."""

    kind: Literal["rod"] = "rod"
    quat_wxyz: list[QuatWxyz] = _samples()
    tension_n: list[NonNeg] = _samples()
    breaking_strength_n: NonNeg
    line_out_m: NonNeg
    fish_state: FishState
    fish_mass_kg: NonNeg | None = None
    fish_stamina: Annotated[float, Field(ge=0.0, le=1.0, allow_inf_nan=False)] | None = None
    rest_pitch_rad: _Angle

    @model_validator(mode="after")
    def _check(self) -> RodTruth:
        _check_lengths(len(self.quat_wxyz), tension_n=self.tension_n)
        _check_unit_quats(self.quat_wxyz)
        return self


class HookTruth(_TruthBase):
    """Hook ground truth per IMU sample: attitude, swing angle Θ, swing direction Φ (ENU bearing), torsion φ."""

    kind: Literal["hook"] = "hook"
    quat_wxyz: list[QuatWxyz] = _samples()
    swing_angle_rad: list[_Angle] = _samples()
    swing_direction_rad: list[_Angle] = _samples()
    torsion_rad: list[_Angle] = _samples()
    rope_length_m: NonNeg | None = None
    load_kg: NonNeg | None = None

    @model_validator(mode="after")
    def _check(self) -> HookTruth:
        n = len(self.quat_wxyz)
        _check_lengths(
            n, swing_angle_rad=self.swing_angle_rad, swing_direction_rad=self.swing_direction_rad,
            torsion_rad=self.torsion_rad,
        )
        _check_unit_quats(self.quat_wxyz)
        return self


class BallTruth(WireModel):
    """Environment-ball ground truth: noise-free values matching EnvPacket `seq`."""

    v: Version
    device_id: DeviceId
    kind: Literal["ball"] = "ball"
    boot_id: Uint32
    seq: Uint32
    t_us: TimeUs
    wall_t_us: TimeUs | None = None
    spot: Name
    air_temp_c: TempC
    water_temp_c: TempC
    oxygen_mg_l: NonNeg
    light_lux: NonNeg
    humidity_pct: NonNeg
    sim_hour_of_day: Annotated[float, Field(ge=0.0, lt=24.0, allow_inf_nan=False)]
    events: list[TruthEvent] = Field(default_factory=list, max_length=100)


# ---------------------------------------------------------------------------------------------------------------
# Commands (gateway/app -> device); publish with CongestionControl.BLOCK
# ---------------------------------------------------------------------------------------------------------------


class ReelCommand(WireModel):
    """Drive the reel. `in`/`out`: |speed_m_s| (0 or absent = the reel's default speed); `stop`: hold (drag still
    slips); `speed`: signed line-in speed, > 0 reels in, < 0 pays out. `drag_n` optionally sets the drag."""

    v: Version
    cmd_id: Uint32
    action: ReelAction
    speed_m_s: Annotated[float, Field(ge=-100.0, le=100.0, allow_inf_nan=False)] | None = None
    drag_n: NonNeg | None = None
    sent_wall_us: TimeUs
    sender: Name | None = None


class BallCommand(WireModel):
    """Re-throw the ball: to `spot` by name, or to another spot chosen by the ball when `spot` is None."""

    v: Version
    cmd_id: Uint32
    action: Literal["rethrow"]
    spot: Name | None = None
    sent_wall_us: TimeUs
    sender: Name | None = None


# ---------------------------------------------------------------------------------------------------------------
# Gateway outputs
# ---------------------------------------------------------------------------------------------------------------


class Attitude(WireModel):
    """Fused attitude at the last sample of packet `seq` (device time `t_us`)."""

    v: Version = 1
    device_id: DeviceId
    kind: ImuKind
    seq: Uint32
    t_us: TimeUs
    wall_t_us: TimeUs | None = None
    quat_wxyz: QuatWxyz
    roll_rad: _Angle
    pitch_rad: _Angle
    yaw_rad: _Angle
    yaw_unwrapped_rad: Finite
    filter: Name | None = None


class AttitudeBlock(WireModel):
    """Fused attitude of every sample of one IMU packet (`boot_id`, `seq`, `t0_us`, `rate_hz` as in that packet;
    sample i at `t0_us + i * 1e6 / rate_hz`). Published only when the gateway runs with `--attitude-blocks`,
    with CongestionControl.BLOCK, for replay scoring and recording at full rate."""

    v: Version = 1
    device_id: DeviceId
    kind: ImuKind
    boot_id: Uint32
    seq: Uint32
    t0_us: TimeUs
    rate_hz: RateHz
    wall_t0_us: TimeUs | None = None
    quat_wxyz: list[QuatWxyz] = _samples()
    filter: Name | None = None

    def t_us(self) -> list[int]:
        """Device time (µs) of each sample, rounded as the gateway's `Attitude.t_us`."""
        return [self.t0_us + int(round(i * 1e6 / self.rate_hz)) for i in range(len(self.quat_wxyz))]


class Swing(WireModel):
    """Hook swing from the fused attitude at the last sample of IMU packet `seq` (paper 001 eq. 4-7); the angles are
    defined in section 3.5 "Hook angles": swing angle Θ, displacement bearing, the paper's swing-plane direction Φ,
    torsion φ, all from the gateway's heading frame. At most one per IMU packet, at most `swing_rate_hz` (20 Hz by
    default) per hook; published with BLOCK (see the key table)."""

    v: Version = 1
    device_id: DeviceId
    seq: Uint32
    t_us: TimeUs
    wall_t_us: TimeUs | None = None
    swing_angle_rad: _Angle
    swing_direction_rad: _Angle
    torsion_rad: Finite
    swing_phi_rad: _Angle | None = None
    rest_heading_rad: _Angle | None = None
    rope_length_m: Annotated[float, Field(gt=0.0, le=1000.0, allow_inf_nan=False)] | None = None


class Height(WireModel):
    """Vertical velocity and height of an IMU device from its fused attitude (seed 002 eq. 6-8): gravity removed from
    the specific force rotated to ENU, integrated twice; drift held by rest detection (velocity to zero, height
    held) and by the device's depth sensor where it has one; free-running without either for 10 s it becomes heave
    about the last rest height (`aided` says which held it)."""

    v: Version = 1
    device_id: DeviceId
    kind: ImuKind
    seq: Uint32
    t_us: TimeUs
    wall_t_us: TimeUs | None = None
    vz_m_s: Finite
    height_m: Finite
    at_rest: bool
    aided: Literal["rest", "depth", "highpass", "none"]


AlarmState: TypeAlias = Literal["raised", "cleared", "acknowledged"]
Severity: TypeAlias = Literal["critical", "major", "minor", "warning", "indeterminate"]
SEVERITIES: Final[tuple[str, ...]] = ("critical", "major", "minor", "warning", "indeterminate")  # most severe first
AlarmId = Annotated[str, Field(pattern=DEVICE_ID_PATTERN)]


class AlarmEvent(WireModel):
    """An alarm raised (or updated: `raised` again, e.g. with a new severity), acknowledged (still active) or
    cleared.

    `alarm_id` is the gateway's alarm id, the same string as REST `/api/alarms` `id` (acknowledge it with
    `POST /api/alarms/{alarm_id}/ack`). Times: `t_us` is the device clock of the sample that raised, updated or
    cleared the alarm; `source_wall_us` that sample's time on the device's realtime clock (from the packet's
    `wall_t0_us`; absent when the device sends none); `wall_t_us` the gateway's clock when it published the event.
    """

    v: Version = 1
    alarm_id: AlarmId
    device_id: DeviceId
    kind: DeviceKind
    alarm: Name
    state: AlarmState
    severity: Severity
    t_us: TimeUs
    wall_t_us: TimeUs
    source_wall_us: TimeUs | None = None
    value: Finite | None = None
    threshold: Finite | None = None
    message: Annotated[str, Field(max_length=500)] = ""


class SpotScore(WireModel):
    """Suitability of one spot (0 = bad, 1 = ideal) from the latest environment readings there."""

    spot: Name
    rank: Annotated[int, Field(ge=1)]
    score: Annotated[float, Field(ge=0.0, le=1.0, allow_inf_nan=False)]
    device_id: DeviceId | None = None
    last_seen_wall_us: TimeUs | None = None
    reasons: list[Annotated[str, Field(max_length=200)]] = Field(default_factory=list, max_length=20)
    lat_deg: Annotated[float, Field(ge=-90.0, le=90.0, allow_inf_nan=False)] | None = None
    lon_deg: Annotated[float, Field(ge=-180.0, le=180.0, allow_inf_nan=False)] | None = None


class SpotRanking(WireModel):
    """Spots best first."""

    v: Version = 1
    wall_t_us: TimeUs
    spots: list[SpotScore] = Field(max_length=1000)


class DeviceIngestCounters(WireModel):
    """Per-device counters since the gateway started (see SequenceTracker for the classification)."""

    device_id: DeviceId
    kind: DeviceKind
    ok: Annotated[int, Field(ge=0)] = 0
    lost: Annotated[int, Field(ge=0)] = 0
    duplicates: Annotated[int, Field(ge=0)] = 0
    reordered: Annotated[int, Field(ge=0)] = 0
    reboots: Annotated[int, Field(ge=0)] = 0
    rejected: dict[str, Annotated[int, Field(ge=0)]] = Field(default_factory=dict)
    filter_restarts: dict[str, Annotated[int, Field(ge=0)]] = Field(default_factory=dict)


class IngestStats(WireModel):
    """Ingest counters: `rejected` totals by reason (including packets whose device is unknown), per device;
    `filter_restarts` totals of fusion restarts by reason (a filter raised, or gave a non-finite quaternion)."""

    v: Version = 1
    wall_t_us: TimeUs
    received: Annotated[int, Field(ge=0)]
    queue_drops: Annotated[int, Field(ge=0)] = 0
    rejected: dict[str, Annotated[int, Field(ge=0)]] = Field(default_factory=dict)
    filter_restarts: dict[str, Annotated[int, Field(ge=0)]] = Field(default_factory=dict)
    devices: list[DeviceIngestCounters] = Field(default_factory=list)


class RejectedPacket(WireModel):
    """One rejected packet: where it came from and why (`reason` in REASONS)."""

    v: Version = 1
    wall_t_us: TimeUs
    key: Annotated[str, Field(max_length=300)]
    reason: Reason
    detail: Annotated[str, Field(max_length=500)] = ""
    size_bytes: Annotated[int, Field(ge=0)]


class DeviceConfig(WireModel):
    """Reply of the `gw/config/{kind}/{id}` queryable: the numeric thresholds in effect (RodThresholds / HookThresholds
    fields of `gateway.config`, units in the names: `bite_deviation_deg`)."""

    v: Version = 1
    device_id: DeviceId
    kind: DeviceKind
    thresholds: dict[Name, Finite]


# ---------------------------------------------------------------------------------------------------------------
# decode
# ---------------------------------------------------------------------------------------------------------------

Packet: TypeAlias = ImuPacket | EnvPacket | ReelStatus | RodTruth | HookTruth | BallTruth | ReelCommand | BallCommand

_MODELS: Final[dict[tuple[str, str], type[WireModel]]] = {
    ("rod", "imu"): ImuPacket,
    ("hook", "imu"): ImuPacket,
    ("ball", "env"): EnvPacket,
    ("rod", "reel"): ReelStatus,
    ("rod", "truth"): RodTruth,
    ("hook", "truth"): HookTruth,
    ("ball", "truth"): BallTruth,
    ("rod", "reel/cmd"): ReelCommand,
    ("ball", "cmd"): BallCommand,
}

ENCODINGS: Final[dict[type[WireModel], str]] = {
    ImuPacket: ENCODING_IMU,
    EnvPacket: ENCODING_ENV,
    ReelStatus: ENCODING_REEL,
    RodTruth: ENCODING_TRUTH,
    HookTruth: ENCODING_TRUTH,
    BallTruth: ENCODING_TRUTH,
    ReelCommand: ENCODING_REEL_CMD,
    BallCommand: ENCODING_BALL_CMD,
}

_RANGE_TYPES: Final = frozenset({"greater_than", "greater_than_equal", "less_than", "less_than_equal", "out_of_range"})


def _reason_from(exc: ValidationError) -> DecodeError:
    """Map pydantic errors to one reason, by priority: bad_json > version > non_finite > out_of_range > schema."""
    errors = exc.errors(include_url=False, include_context=False, include_input=False)
    types = {e["type"] for e in errors}
    first = errors[0]
    detail = f"{'.'.join(str(p) for p in first['loc'])}: {first['msg']}"[:300]
    if "json_invalid" in types or "json_type" in types:
        return DecodeError("bad_json", detail)
    for e in errors:
        if e["loc"][:1] == ("v",) and e["type"] != "missing":
            return DecodeError("version", f"v: {e['msg']}"[:300])
    if "finite_number" in types:
        return DecodeError("non_finite", detail)
    for e in errors:
        if e["type"] in _RANGE_TYPES:
            return DecodeError("out_of_range", f"{'.'.join(str(p) for p in e['loc'])}: {e['msg']}"[:300])
    return DecodeError("schema", detail)


def decode(key: str, payload: bytes | bytearray | memoryview) -> Packet:
    """Validate one sample received on `key`; returns the model or raises DecodeError (never anything else).

    Checks, in order: size (`too_large`), key (`unknown_key`), JSON + schema + ranges (one parse), then that the
    key's kind and device id equal the payload's (`key_mismatch`).
    """
    try:
        if len(payload) > MAX_PAYLOAD_BYTES:
            raise DecodeError("too_large", f"{len(payload)} bytes > {MAX_PAYLOAD_BYTES}")
        parsed = parse_key(key)
        model = _MODELS[(parsed.kind, parsed.topic)]
        try:
            packet = model.model_validate_json(payload if isinstance(payload, bytes | bytearray) else bytes(payload))
        except ValidationError as exc:
            raise _reason_from(exc) from exc
        device_id = getattr(packet, "device_id", None)
        if device_id is not None and device_id != parsed.device_id:
            raise DecodeError("key_mismatch", f"payload device_id {device_id!r} on key {key!r}")
        kind = getattr(packet, "kind", None)
        if kind is not None and kind != parsed.kind:
            raise DecodeError("key_mismatch", f"payload kind {kind!r} on key {key!r}")
        return packet  # type: ignore[return-value]
    except DecodeError:
        raise
    except Exception as exc:  # a bug or an exotic input must still count as a rejected packet, never crash ingest
        raise DecodeError("schema", f"{type(exc).__name__}: {exc}"[:300]) from exc


# ---------------------------------------------------------------------------------------------------------------
# Sequence tracking
# ---------------------------------------------------------------------------------------------------------------

SeqStatus: TypeAlias = Literal["first", "ok", "lost", "duplicate", "reordered", "reboot", "conflict", "rival"]


@dataclass(frozen=True, slots=True)
class SeqResult:
    """Classification of one arriving packet; `lost` = packets newly found missing before this one (status lost)."""

    status: SeqStatus
    lost: int = 0

    @property
    def accept(self) -> bool:
        """True when the packet carries new data of the followed stream (not a duplicate, not the rival's)."""
        return self.status not in ("duplicate", "rival")

    @property
    def conflict(self) -> bool:
        """True when the packet shows a second publisher on the key (`conflict` or `rival`)."""
        return self.status in ("conflict", "rival")


CONFLICT_EVIDENCE: Final = 2
"""New packets of the boot left behind, after a reboot, that prove it still publishes (one can be a late packet)."""


@dataclass
class SequenceTracker:
    """Classifies each packet's (boot_id, seq) of ONE device stream: ok, lost(n), duplicate, reordered, reboot, and
    conflict / rival when two publishers share the key.

    Arithmetic is modulo 2**32 so the wrap 0xFFFFFFFF -> 0 is ordinary. A seq ahead of the newest by d
    (0 < d < 2**31) is new; d - 1 packets were lost. A seq behind the newest within `window` is `reordered`
    if unseen (one previously lost packet arrived late: the counters subtract it from `lost`), else `duplicate`;
    further behind is counted as duplicate (too old to tell). A new boot_id restarts the stream (`reboot`);
    late packets of the boot before are stale and counted as duplicates.

    Two publishers: a real reboot silences the boot before it. When that boot instead goes on with new seqs
    (`CONFLICT_EVIDENCE` of them) another publisher is using the key (a spoofer, or two devices with one id). The
    tracker then goes back to the boot it followed first (`conflict`: this packet is accepted) and from then on
    classifies the newcomer's boot as `rival` (dropped, counted in `conflicts`): a forged boot_id can no longer
    make the real stream look stale. The same holds within one boot: after a jump ahead by `window` or more, when
    the sequence left behind goes on (`CONFLICT_EVIDENCE` packets), the tracker follows it again and packets near
    the jumped-to sequence are `rival`. A reboot after a boot that delivered fewer than `CONFLICT_EVIDENCE` packets
    (boots flapping, e.g. a spoofer with a new boot_id per packet) is accepted but reported as `conflict`.
    Which publisher is genuine cannot be known without authentication (zenoh access control, docs/security.md);
    the gateway raises a `device_conflict` alarm.
    Counters accumulate in `ok`, `lost`, `duplicates`, `reordered`, `reboots`, `conflicts`.
    """

    window: int = 1024
    boot_id: int | None = None
    previous_boot_id: int | None = None
    previous_newest: int = 0
    previous_fresh: int = 0
    rival_boot_id: int | None = None
    jumped_from: int | None = None  # newest seq before the last jump ahead by >= window (same boot)
    jump_lost: int = 0
    jump_fresh: int = 0
    rival_seq: tuple[int, int] | None = None  # (boot, newest seq) of a second publisher using the same boot_id
    _boot_ok0: int = 0  # `ok` when the current boot started
    newest: int = 0
    _seen: set[int] = field(default_factory=set)
    ok: int = 0
    lost: int = 0
    duplicates: int = 0
    reordered: int = 0
    reboots: int = 0
    conflicts: int = 0

    def update(self, boot_id: int, seq: int) -> SeqResult:
        """Classify one packet and update the counters."""
        if boot_id == self.rival_boot_id and boot_id != self.boot_id:
            self.conflicts += 1
            return SeqResult("rival")
        if boot_id == self.previous_boot_id and boot_id != self.boot_id:
            ahead = (seq - self.previous_newest) % UINT32
            if 0 < ahead < UINT32 // 2:  # the boot left behind goes on: is it a second publisher?
                self.previous_newest = seq
                self.previous_fresh += 1
                if self.previous_fresh >= CONFLICT_EVIDENCE:
                    return self._resume_previous(seq)
            self.duplicates += 1  # a straggler from before the reboot: stale, not a second reboot
            return SeqResult("duplicate")
        if self.rival_seq is not None and boot_id == self.rival_seq[0]:
            d = (seq - self.rival_seq[1]) % UINT32
            if d < self.window or UINT32 - d < self.window:  # near the rival's sequence, not ours
                if 0 < d < self.window:
                    self.rival_seq = (boot_id, seq)
                self.conflicts += 1
                return SeqResult("rival")
        if self.boot_id is None or boot_id != self.boot_id:
            self.jumped_from = None
            self.previous_boot_id, self.previous_newest, self.previous_fresh = self.boot_id, self.newest, 0
            status: SeqStatus = "first" if self.boot_id is None else "reboot"
            if status == "reboot":
                self.reboots += 1
                if self.ok - self._boot_ok0 < CONFLICT_EVIDENCE:  # boots flapping: more than one publisher
                    status = "conflict"
                    self.conflicts += 1
            self.boot_id, self.newest, self._seen, self._boot_ok0 = boot_id, seq, {seq}, self.ok
            self.ok += 1
            return SeqResult(status)
        ahead = (seq - self.newest) % UINT32
        if ahead == 0:
            self.duplicates += 1
            return SeqResult("duplicate")
        if ahead < UINT32 // 2:
            if ahead >= self.window:  # a big jump: remember where from, in case that sequence goes on
                self.jumped_from, self.jump_lost, self.jump_fresh = self.newest, ahead - 1, 0
            self.newest = seq
            self._remember(seq)
            self.ok += 1
            if ahead > 1:
                self.lost += ahead - 1
                return SeqResult("lost", ahead - 1)
            return SeqResult("ok")
        behind = (self.newest - seq) % UINT32
        if behind < self.window and seq not in self._seen:
            self._remember(seq)
            self.reordered += 1
            self.lost = max(0, self.lost - 1)
            self.ok += 1
            return SeqResult("reordered")
        if self.jumped_from is not None and 0 < (seq - self.jumped_from) % UINT32 < self.window:
            self.jumped_from = seq  # the sequence left behind by the jump goes on: a second publisher?
            self.jump_fresh += 1
            if self.jump_fresh >= CONFLICT_EVIDENCE:
                return self._resume_sequence(boot_id, seq)
        self.duplicates += 1
        return SeqResult("duplicate")

    def _resume_sequence(self, boot_id: int, seq: int) -> SeqResult:
        """Two publishers with one boot_id (one jumped the seq ahead): follow the sequence seen first again."""
        self.rival_seq = (boot_id, self.newest)
        self.lost = max(0, self.lost - self.jump_lost)  # the jump's gap was not loss
        self.newest, self._seen, self.jumped_from = seq, {seq}, None
        self.conflicts += 1
        self.ok += 1
        return SeqResult("conflict")

    def _resume_previous(self, seq: int) -> SeqResult:
        """Two publishers: follow the boot seen first again; the newcomer's boot becomes the rival."""
        self.rival_boot_id = self.boot_id
        self.boot_id, self.previous_boot_id, self.previous_fresh = self.previous_boot_id, None, 0
        self.newest, self._seen, self._boot_ok0 = seq, {seq}, self.ok
        self.reboots = max(0, self.reboots - 1)  # it was not a reboot
        self.conflicts += 1
        self.ok += 1
        return SeqResult("conflict")

    def _remember(self, seq: int) -> None:
        self._seen.add(seq)
        if len(self._seen) > 2 * self.window:
            self._seen = {s for s in self._seen if (self.newest - s) % UINT32 < self.window}


# ---------------------------------------------------------------------------------------------------------------
# Examples (exact payloads for docs/protocol.md and tests)
# ---------------------------------------------------------------------------------------------------------------


def examples() -> dict[str, tuple[str, WireModel]]:
    """name -> (key, model): one valid, deterministic example of every payload."""
    wall = 1_767_225_600_000_000  # 2026-01-01T00:00:00Z in unix µs
    q = (0.9537, -0.0, 0.1624, 0.2532)
    qn = math.sqrt(sum(c * c for c in q))
    quat = (round(q[0] / qn, 6), 0.0, round(q[2] / qn, 6), round(q[3] / qn, 6))
    imu = ImuPacket(
        v=1, device_id="rod-1", kind="rod", boot_id=2_882_400_001, seq=1042, t0_us=10_420_000, rate_hz=100.0,
        gyr_rad_s=[(0.0012, -0.0031, 0.0004), (0.0015, -0.0029, 0.0002)],
        acc_m_s2=[(5.312, 0.021, 8.247), (5.309, 0.018, 8.251)],
        mag_uT=[(-14.3, 18.1, -39.2), (-14.2, 18.0, -39.3)],
        temp_c=24.5, battery_v=4.08, rssi_dbm=-61.0, wall_t0_us=wall + 10_420_000,
        gnss=GnssFix(lat_deg=30.2741, lon_deg=120.1551, alt_m=7.5, speed_m_s=0.0, fix_quality=1),
    )
    hook_imu = ImuPacket(
        v=1, device_id="hook-1", kind="hook", boot_id=99, seq=7, t0_us=70_000, rate_hz=100.0,
        gyr_rad_s=[(0.0, 0.0, 0.0)], acc_m_s2=[(0.0, 0.0, 9.81)],
    )
    env = EnvPacket(
        v=1, device_id="ball-1", boot_id=5, seq=12, t_us=12_000_000, wall_t_us=wall + 12_000_000, spot="deep_hole",
        air_temp_c=14.2, humidity_pct=81.5, light_lux=1520.0, water_temp_c=17.8, oxygen_mg_l=7.95,
        probe_depth_m=6.0, bottom_depth_m=12.0,
        profile=[ProfilePoint(depth_m=0.0, water_temp_c=19.9, oxygen_mg_l=8.9),
                 ProfilePoint(depth_m=6.0, water_temp_c=10.1, oxygen_mg_l=1.2)],
        battery_v=3.9, rssi_dbm=-70.0, gnss=GnssFix(lat_deg=30.2746, lon_deg=120.1559, fix_quality=1),
    )
    reel = ReelStatus(
        v=1, device_id="rod-1", boot_id=2_882_400_001, seq=208, t_us=10_420_000, wall_t_us=wall + 10_420_000,
        line_out_m=27.4, line_in_speed_m_s=0.48, motor="reeling_in", mode="in", cmd_speed_m_s=0.5, drag_n=25.0,
        tension_n=6.2, last_cmd_id=17,
    )
    rod_truth = RodTruth(
        v=1, device_id="rod-1", boot_id=2_882_400_001, seq=1042, t0_us=10_420_000, rate_hz=100.0,
        wall_t0_us=wall + 10_420_000,
        events=[TruthEvent(label="bite", phase="start", t_us=10_415_000, value=0.349066)],
        quat_wxyz=[quat, quat], tension_n=[1.2, 1.6], breaking_strength_n=40.0, line_out_m=30.0,
        fish_state="nibbling", rest_pitch_rad=0.541,
    )
    hook_truth = HookTruth(
        v=1, device_id="hook-1", boot_id=99, seq=7, t0_us=70_000, rate_hz=100.0,
        quat_wxyz=[(1.0, 0.0, 0.0, 0.0)], swing_angle_rad=[0.0], swing_direction_rad=[0.0], torsion_rad=[0.0],
        rope_length_m=8.0, load_kg=1200.0,
    )
    ball_truth = BallTruth(
        v=1, device_id="ball-1", boot_id=5, seq=12, t_us=12_000_000, wall_t_us=wall + 12_000_000,
        spot="deep_hole", air_temp_c=14.25, water_temp_c=17.81, oxygen_mg_l=7.91, light_lux=1500.0,
        humidity_pct=81.0, sim_hour_of_day=6.2,
        events=[TruthEvent(label="rethrow", phase="instant", t_us=11_000_000)],
    )
    reel_cmd = ReelCommand(v=1, cmd_id=17, action="in", speed_m_s=0.5, sent_wall_us=wall + 10_300_000,
                           sender="gateway")
    ball_cmd = BallCommand(v=1, cmd_id=3, action="rethrow", spot="inlet", sent_wall_us=wall + 11_900_000)
    att = Attitude(
        device_id="rod-1", kind="rod", seq=1042, t_us=10_430_000, wall_t_us=wall + 10_436_000, quat_wxyz=quat,
        roll_rad=0.0012, pitch_rad=0.3316, yaw_rad=0.5236, yaw_unwrapped_rad=6.8068, filter="complementary",
    )
    att_block = AttitudeBlock(
        device_id="rod-1", kind="rod", boot_id=2_882_400_001, seq=1042, t0_us=10_420_000, rate_hz=100.0,
        wall_t0_us=wall + 10_420_000, quat_wxyz=[quat, quat], filter="default",
    )
    height = Height(device_id="hook-1", kind="hook", seq=7, t_us=80_000, wall_t_us=wall + 86_000, vz_m_s=-0.12,
                    height_m=1.84, at_rest=False, aided="rest")
    swing = Swing(device_id="hook-1", seq=7, t_us=80_000, wall_t_us=wall + 86_000, swing_angle_rad=0.087,
                  swing_direction_rad=1.2, torsion_rad=0.15, swing_phi_rad=0.6764, rest_heading_rad=0.5236,
                  rope_length_m=9.87)  # the worked example of section 3.5
    alarm = AlarmEvent(
        alarm_id="3f2b9c0d5e8a4b7c9d1e2f3a4b5c6d7e", device_id="rod-1", kind="rod", alarm="bite", state="raised",
        severity="major", t_us=10_425_000, wall_t_us=wall + 10_436_000, source_wall_us=wall + 10_425_000, value=-12.0,
        threshold=-10.0, message="bite: pitch 12.0° below rest ≥ θ1 10.0°",
    )
    spots = SpotRanking(wall_t_us=wall + 12_100_000, spots=[
        SpotScore(spot="inlet", rank=1, score=0.82, device_id="ball-2", last_seen_wall_us=wall + 12_000_000,
                  reasons=["oxygen 9.1 mg/L", "water 16 °C"], lat_deg=30.2751, lon_deg=120.1548),
        SpotScore(spot="deep_hole", rank=2, score=0.41, device_id="ball-1", last_seen_wall_us=wall + 12_000_000,
                  reasons=["low oxygen at probe depth"]),
    ])
    ingest = IngestStats(
        wall_t_us=wall + 12_000_000, received=125_000, queue_drops=0, rejected={"schema": 2, "unknown_key": 1},
        devices=[DeviceIngestCounters(device_id="rod-1", kind="rod", ok=24_990, lost=8, duplicates=1,
                                      reordered=2, reboots=0, rejected={"schema": 2})],
    )
    rejected = RejectedPacket(wall_t_us=wall + 12_000_000, key="rig/rod/rod-1/imu", reason="schema",
                              detail="acc_m_s2: acc_m_s2 has 9 samples, expected 10", size_bytes=612)
    config = DeviceConfig(device_id="rod-1", kind="rod", thresholds={"bite_deviation_deg": 10.0, "sensitivity": 3.0,
                                                                   "line_switch_deg": 20.0})
    return {
        "imu_rod": (imu_key("rod", "rod-1"), imu),
        "imu_hook_minimal": (imu_key("hook", "hook-1"), hook_imu),
        "env": (env_key("ball-1"), env),
        "reel_status": (reel_key("rod-1"), reel),
        "rod_truth": (truth_key("rod", "rod-1"), rod_truth),
        "hook_truth": (truth_key("hook", "hook-1"), hook_truth),
        "ball_truth": (truth_key("ball", "ball-1"), ball_truth),
        "reel_cmd": (reel_cmd_key("rod-1"), reel_cmd),
        "ball_cmd": (ball_cmd_key("ball-1"), ball_cmd),
        "attitude": (attitude_key("rod", "rod-1"), att),
        "attitude_block": (attitude_block_key("rod", "rod-1"), att_block),
        "height": (height_key("hook", "hook-1"), height),
        "swing": (swing_key("hook-1"), swing),
        "alarm": (alarm_key("rod", "rod-1"), alarm),
        "spots": (SPOTS_KEY, spots),
        "diag_ingest": (DIAG_INGEST_KEY, ingest),
        "diag_rejected": (DIAG_REJECTED_KEY, rejected),
        "config": (config_key("rod", "rod-1"), config),
    }


FIELD_NOTES: Final[dict[str, str]] = {
    "v": "protocol version, always 1 in this version",
    "device_id": "must equal the `{id}` chunk of the key; " + DEVICE_ID_PATTERN,
    "kind": "must equal the `{kind}` chunk of the key",
    "boot_id": "random at each device start; a new value restarts sequence tracking",
    "seq": "+1 per packet on this key, wraps 4294967295 -> 0",
    "t0_us": "device monotonic clock (µs) of sample 0; sample i at t0_us + i·1e6/rate_hz",
    "t_us": "device monotonic clock, µs",
    "rate_hz": "sample rate of the arrays",
    "gyr_rad_s": "angular rate, body frame, rad/s: n rows of [x, y, z]",
    "acc_m_s2": "specific force, body frame, m/s² (reads +9.81 on z when level): n rows of [x, y, z]",
    "mag_uT": "magnetic field, body frame, µT, n rows; absent = 6-axis IMU",
    "quat_wxyz": "unit quaternion body -> ENU, scalar first (|q| = 1 ± 1e-3)",
    "wall_t0_us": "device realtime clock (unix µs) of sample 0, if synchronised",
    "wall_t_us": "realtime clock, unix µs",
    "sent_wall_us": "sender's realtime clock when sent, unix µs",
    "events": "ground-truth labels: {label, phase start|end|instant, t_us (device clock), value?}",
    "profile": "water column measured while the probe sank (first packet after a throw)",
    "line_in_speed_m_s": "> 0 line coming in, < 0 going out",
    "cmd_speed_m_s": "motor line-in speed currently commanded",
    "speed_m_s": "in/out: magnitude (absent = reel default); speed: signed, > 0 reels in",
    "last_cmd_id": "cmd_id of the last ReelCommand applied (acknowledgement)",
    "source_wall_us": "device realtime clock (unix µs) of the sample that triggered the alarm; absent without one",
    "alarm_id": "the gateway's alarm id (REST `/api/alarms` `id`, ack with `POST /api/alarms/{alarm_id}/ack`)",
    "severity": "most severe first: critical, major, minor, warning, indeterminate (alarm engine levels)",
    "yaw_unwrapped_rad": "yaw without the ±π jumps",
    "filter_restarts": "fusion restarted from a fresh warm-up, by reason: the filter's exception class (e.g. "
                       "`LinAlgError`) or `non_finite` (it returned NaN/inf)",
    "swing_direction_rad": "bearing of the hook's horizontal displacement, counter-clockwise from East",
    "gnss": "GNSS fix at sample 0 (ImuPacket) or at the reading (EnvPacket: where the ball lies); absent without a "
            "receiver",
    "lat_deg": "WGS-84 latitude, degrees north",
    "lon_deg": "WGS-84 longitude, degrees east",
    "alt_m": "altitude above mean sea level, m",
    "fix_quality": "NMEA GGA fix quality: 0 invalid, 1 GNSS, 2 differential, 4 RTK fixed, 5 RTK float, 6 estimated",
    "depth_m": "pressure depth below the water surface at sample 0, m; absent without a depth sensor",
    "vz_m_s": "vertical velocity, ENU up, m/s",
    "height_m": "height above the device's first rest position (ENU up), m; minus the depth when depth-aided",
    "at_rest": "the rest detector holds the device still (velocity zeroed)",
    "aided": "what held the drift on this sample: rest detection, the depth sensor, the high-pass of a device free-"
             "running for 10 s (heave about the last rest height), or nothing yet (free integration)",
}

# Notes that differ from FIELD_NOTES for one model: (model name, field) -> note.
MODEL_FIELD_NOTES: Final[dict[tuple[str, str], str]] = {
    ("AttitudeBlock", "wall_t0_us"): "sample 0 on the realtime clock (unix µs): the packet's `wall_t0_us`, else "
                                     "mapped from the gateway's arrival time (as `Attitude.wall_t_us`)",
    ("AttitudeBlock", "quat_wxyz"): "n unit quaternions body -> ENU, scalar first, one per sample of the packet",
    ("AlarmEvent", "t_us"): "device monotonic clock (µs) of the sample that raised, updated or cleared the alarm",
    ("AlarmEvent", "wall_t_us"): "gateway realtime clock (unix µs) when the event was published",
    ("GnssFix", "speed_m_s"): "ground speed, m/s",
    ("SpotScore", "lat_deg"): "where the spot's ball last reported its GNSS fix (WGS-84), absent without one",
    ("SpotScore", "lon_deg"): "as `lat_deg`",
    ("Height", "t_us"): "device monotonic clock (µs) of the sample",
    ("Swing", "swing_angle_rad"): "Θ ∈ [0, π/2): angle between the rope and the vertical (section 3.5)",
    ("Swing", "swing_direction_rad"): "displacement bearing ∈ (-π, π]: direction of the hook's horizontal "
                                      "displacement from below the boom tip, CCW from East in the heading frame; "
                                      "0 when Θ = 0 (section 3.5)",
    ("Swing", "torsion_rad"): "φ ∈ (-π, π]: twist about the rope from the rest heading, right-handed about the rope "
                              "(CCW seen from above); 0 = body x at the rest heading (section 3.5)",
    ("Swing", "swing_phi_rad"): "paper 001 eq. 7 Φ ∈ [-π/2, π/2] relative to the rest heading ψ: sin Φ = sin θy / "
                                "sin Θ; the bearing is ψ + Φ or ψ + π - Φ (section 3.5); absent from old gateways",
    ("Swing", "rest_heading_rad"): "ψ: the rest heading torsion and Φ are taken from, CCW from East in the heading "
                                   "frame (configured `rest_heading_deg`, else the first fused heading)",
    ("Swing", "rope_length_m"): "the hook filter's estimate of the pendulum length (boom tip to the hook and load's "
                                "centre), m; absent with other filters",
    ("HookTruth", "swing_direction_rad"): "bearing of the hook's horizontal displacement, CCW from East (ENU)",
}


def _type_of(prop: dict[str, Any], defs: dict[str, Any]) -> str:
    if "$ref" in prop:
        return str(prop["$ref"]).split("/")[-1]
    if "anyOf" in prop:
        return " or ".join(_type_of(p, defs) for p in prop["anyOf"] if p.get("type") != "null")
    if "const" in prop:
        return json.dumps(prop["const"])
    if "enum" in prop:
        return " \\| ".join(json.dumps(e) for e in prop["enum"])
    t = str(prop.get("type", "any"))
    if t == "array":
        if "prefixItems" in prop:
            inner = _type_of(prop["prefixItems"][0], defs)
            return f"[{inner} ×{len(prop['prefixItems'])}]"
        n = f"{prop.get('minItems', 0)}..{prop.get('maxItems', '∞')}"
        return f"array({n}) of {_type_of(prop.get('items', {}), defs)}"
    if t == "object":
        return f"object of {_type_of(prop.get('additionalProperties', {}), defs)}"
    rng = []
    if "minimum" in prop or "exclusiveMinimum" in prop:
        rng.append(f"≥ {prop['minimum']}" if "minimum" in prop else f"> {prop['exclusiveMinimum']}")
    if "maximum" in prop or "exclusiveMaximum" in prop:
        rng.append(f"≤ {prop['maximum']}" if "maximum" in prop else f"< {prop['exclusiveMaximum']}")
    if "maxLength" in prop:
        rng.append(f"len {prop.get('minLength', 0)}..{prop['maxLength']}")
    return t + (f" ({', '.join(rng)})" if rng else "")


def fields_markdown(model: type[WireModel]) -> str:
    """A markdown table of the model's fields: name, JSON type with ranges, required, notes."""
    schema = model.model_json_schema()
    defs = schema.get("$defs", {})
    required = set(schema.get("required", []))
    rows = ["| field | JSON type (range) | required | notes |", "|---|---|---|---|"]
    for name, prop in schema["properties"].items():
        req = "yes" if name in required else f"no (default {json.dumps(prop.get('default'))})"
        note = MODEL_FIELD_NOTES.get((model.__name__, name), FIELD_NOTES.get(name, ""))
        rows.append(f"| `{name}` | {_type_of(prop, defs)} | {req} | {note} |")
    return "\n".join(rows)


_FIELDS_BEGIN = "<!-- fields:begin (generated) -->"
_FIELDS_END = "<!-- fields:end -->"
DOC_MODELS: Final[tuple[type[WireModel], ...]] = (
    ImuPacket, GnssFix, EnvPacket, ProfilePoint, ReelStatus, RodTruth, HookTruth, BallTruth, TruthEvent, ReelCommand,
    BallCommand, Attitude, AttitudeBlock, Height, Swing, AlarmEvent, SpotRanking, SpotScore, IngestStats,
    DeviceIngestCounters, RejectedPacket, DeviceConfig,
)


def all_fields_markdown() -> str:
    """Field tables of every wire model."""
    return "\n\n".join(f"#### {m.__name__}\n\n{inspect.cleandoc(m.__doc__ or '')}\n\n{fields_markdown(m)}"
                         for m in DOC_MODELS)


_EXAMPLES_BEGIN = "<!-- examples:begin (generated by `python -m gateway.schemas --write-doc docs/protocol.md`) -->"
_EXAMPLES_END = "<!-- examples:end -->"


def example_json(model: WireModel) -> str:
    """The model's wire JSON laid out one top-level field per line (what docs/protocol.md shows)."""
    d = json.loads(model.to_json())
    lines = [f"  {json.dumps(k)}: {json.dumps(v, ensure_ascii=False)}" for k, v in d.items()]
    return "{\n" + ",\n".join(lines) + "\n}"


def examples_markdown() -> str:
    """Markdown blocks 'Key: `...`' + JSON for every example (keys in model order)."""
    parts = []
    for name, (key, model) in examples().items():
        body = example_json(model)
        enc = ENCODINGS.get(type(model), ENCODING_GW)
        parts.append(f"#### {name}\n\nKey: `{key}` — encoding `{enc}`\n\n```json\n{body}\n```\n")
    return "\n".join(parts)


def write_doc(path: str) -> None:
    """Replace the generated examples section of the protocol document in place."""
    from pathlib import Path

    p = Path(path)
    text = p.read_text()
    for begin, end, body in ((_EXAMPLES_BEGIN, _EXAMPLES_END, examples_markdown()),
                             (_FIELDS_BEGIN, _FIELDS_END, all_fields_markdown())):
        i, j = text.index(begin), text.index(end)
        text = text[: i + len(begin)] + "\n\n" + body + "\n" + text[j:]
    p.write_text(text)


def _main(argv: list[str] | None = None) -> int:
    import argparse

    parser = argparse.ArgumentParser(prog="python -m gateway.schemas", description="Wire protocol examples.")
    parser.add_argument("--write-doc", metavar="PATH", help="regenerate the examples section of this markdown file")
    args = parser.parse_args(argv)
    if args.write_doc:
        write_doc(args.write_doc)
    else:
        print(examples_markdown())
    return 0


if __name__ == "__main__":
    raise SystemExit(_main())
