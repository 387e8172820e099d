"""Shared parts of every simulated device: IMU error model, radio link model, zenoh CLI options and the runtime.

Public API (the hook simulator builds on it; keep it stable):

- `G_M_S2`, `EARTH_FIELD_ENU_UT`: physical constants (ENU; field ≈ mid-latitude northern hemisphere).
- `ImuErrorModel` (frozen settings; presets `calibrated()`, `uncalibrated()`, `ideal()`, `preset(name)`) +
  `SensorModel(error_model, n_devices, rng)`: `.measure(gyr, acc, mag, dt_s)`
  turns TRUE body rate (rad/s), specific force (m/s²) and field (µT), shapes (N, 3) or (D, N, 3), into readings.
- `specific_force_body(q_wxyz, acc_earth_m_s2)`, `field_body(q_wxyz, field_enu_uT)`: true sensor inputs from a
  trajectory.
- `LinkModel` (frozen) + `LinkSim`: packet loss (optionally bursty, Gilbert-Elliott) and publish jitter.
- `add_zenoh_args(parser)`, `zenoh_config(args)`: `--mode/--connect/--listen/--multicast/--zenoh-config`.
- `add_fleet_args(parser, ...)`, `FleetSettings.from_args(args)`: `--count --seed --rate --samples-per-packet
  --truth/--no-truth --loss --burst --jitter-ms --duration --id-prefix`; `add_imu_args(parser)`: `--imu PRESET`.
- `Fleet` (protocol your simulator implements) and `run_fleet(session, fleet, settings)`: liveliness tokens,
  publishers, paced loop, command hand-off, loss; `run_main(fleet_factory, argv, ...)` wires it all for a `main()`.
- `imu_payload(...)`: JSON bytes of one `rig.imu.v1` packet (fast path, same bytes pydantic would accept);
  `imu_message(key, encoding, ...)`: that or the binary protocol v2 packet (`--encoding binary`) as a Message.
- `DeviceClock`: per-instance monotonic µs clock with a random boot offset and its wall-clock anchor.
- `encode_json(obj)`, `rows(array, decimals)`, `new_boot_id(rng)`: fast payload helpers.

A simulator module is `build_parser()` (with `add_zenoh_args` + `add_fleet_args`), a Fleet class and
`main(argv) = run_main(make_fleet, parser.parse_args(argv))`; `python -m devices` launches it with those options.

Zenoh defaults (no flags needed): devices run in **peer** mode, multicast scouting **off**, and **connect** to
`tcp/127.0.0.1:7447`, where the gateway listens. They start, publish and keep retrying the connection in the
background when no gateway is there (or it restarts), so data simply flows once it appears.
"""

from __future__ import annotations

import argparse
import json
import logging
import math
import queue
import random
import signal
import sys
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Protocol

import numpy as np
import zenoh
from numpy.typing import NDArray
from tqdm import tqdm

from devices import _quat
from gateway import schemas

FloatArray = NDArray[np.float64]
log = logging.getLogger("devices")

G_M_S2 = 9.80665
"""Standard gravity, m/s²."""
EARTH_FIELD_ENU_UT: tuple[float, float, float] = (0.0, 20.0, -44.0)
"""Earth field in ENU, µT: 48 µT total, inclination about 65° down (Europe / northern US mid-latitudes)."""
DEFAULT_GATEWAY_ENDPOINT = "tcp/127.0.0.1:7447"
"""Where the gateway listens and devices connect by default."""

_DEG = math.pi / 180.0


# ---------------------------------------------------------------------------------------------------------------
# IMU error model
# ---------------------------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class ImuErrorModel:
    """Sensor errors, defaults from the MPU-6050 (PS-MPU-6000A rev 3.4) and HMC5883L datasheets.

    Three presets (docs/calibration.md): `calibrated()` is a board calibrated once with `python -m gateway.calibrate`
    (what the simulators publish by default); `uncalibrated()` the raw board (hard iron tens of µT: ~25° of heading
    error, accel offset tens of mg: ~2° of tilt); `ideal()` none. The bare defaults sit in between (20 mg accel
    offset, 5 µT hard iron: a factory-trimmed accel, an uncalibrated compass) and are kept for the fusion tests and
    benches tuned on them.

    White noise per sample has std `density * sqrt(rate_hz)` (one-sided density over the Nyquist band ×2,
    the usual IMU-simulator convention); at 100 Hz the gyro gives 0.05 °/s rms, the datasheet's "total RMS
    noise 0.05 °/s at 100 Hz". Biases, scale factors and misalignment are drawn once per instance; biases then
    random-walk. Readings are clipped to full scale and quantised to the ADC LSB.
    """

    gyro_noise_density_rad_s_rthz: float = 0.005 * _DEG  # MPU-6050 Table 6.1: 0.005 °/s/√Hz
    gyro_bias_std_rad_s: float = 1.0 * _DEG  # residual start-up bias (raw ZRO tolerance is ±20 °/s)
    gyro_bias_rw_rad_s_rts: float = 2e-5  # bias random walk, rad/s per √s (≈ 10 °/h instability class)
    gyro_scale_std: float = 0.01  # sensitivity tolerance ±3 % (3σ)
    gyro_fs_rad_s: float = 500.0 * _DEG  # FS_SEL=1: ±500 °/s, 65.5 LSB/(°/s)
    acc_noise_density_m_s2_rthz: float = 400e-6 * G_M_S2  # Table 6.2: 400 µg/√Hz
    acc_bias_std_m_s2: float = 0.02 * G_M_S2  # zero-g offset ±50 mg X/Y, ±80 mg Z raw; 20 mg residual
    acc_bias_rw_m_s2_rts: float = 1e-4
    acc_scale_std: float = 0.01  # ±3 % initial calibration tolerance (3σ)
    acc_fs_m_s2: float = 8.0 * G_M_S2  # AFS_SEL=2: ±8 g, 4096 LSB/g
    misalignment_std_rad: float = 0.005  # cross-axis sensitivity ±2 %
    imu_bits: int = 16
    mag_noise_std_uT: float = 0.2  # HMC5883L noise floor 2 mG (std of 100 samples)
    mag_hard_iron_std_uT: float = 5.0  # offset from the reel, motor and battery
    mag_soft_iron_std: float = 0.03  # symmetric soft-iron matrix I + S, S entries of this std
    mag_lsb_uT: float = 100.0 / 1090.0  # gain 1090 LSB/Gauss (±1.3 Ga range)
    mag_bits: int = 12  # ADC output -2048..2047

    @staticmethod
    def calibrated() -> ImuErrorModel:
        """A board calibrated once (`gateway.calibrate`: six-pose accel offset/scale fit, magnetometer ellipsoid fit).

        What is left is the fit's own residual (measured in tests/test_calibrate.py on the `uncalibrated()` board:
        hard iron ≤ 0.1 µT, soft iron ≤ 0.3 %, accel offset ≤ 1.7 mg, scale ≤ 0.1 %) plus what drifts after it:
        zero-g offset 0.3 mg/°C (MPU-6050: ±35 mg over 125 °C) over ±10 °C, hard iron from battery and motor
        currents and nearby steel. Cross-axis terms and the gyro are not calibrated offline (the filter estimates
        the gyro bias).
        """
        return ImuErrorModel(acc_bias_std_m_s2=0.003 * G_M_S2, acc_scale_std=0.002, mag_hard_iron_std_uT=0.5,
                             mag_soft_iron_std=0.005)

    @staticmethod
    def uncalibrated() -> ImuErrorModel:
        """The raw board: accel zero-g offset ±50 mg X/Y, ±80 mg Z (≈ 30 mg std), scale ±3 %, hard iron of tens of
        µT (reel motor, battery, steel screws), soft iron a few %."""
        return ImuErrorModel(acc_bias_std_m_s2=0.03 * G_M_S2, acc_scale_std=0.01, mag_hard_iron_std_uT=15.0,
                             mag_soft_iron_std=0.03)

    @staticmethod
    def preset(name: str) -> ImuErrorModel:
        """`calibrated`, `uncalibrated`, `legacy` (the bare defaults) or `ideal` (the simulators' --imu option)."""
        presets = {"calibrated": ImuErrorModel.calibrated, "uncalibrated": ImuErrorModel.uncalibrated,
                   "legacy": ImuErrorModel, "ideal": ImuErrorModel.ideal}
        if name not in presets:
            raise ValueError(f"unknown IMU error preset {name!r}; known: {', '.join(presets)}")
        return presets[name]()

    @staticmethod
    def ideal() -> ImuErrorModel:
        """No errors at all except float rounding (useful in tests)."""
        return ImuErrorModel(
            gyro_noise_density_rad_s_rthz=0.0, gyro_bias_std_rad_s=0.0, gyro_bias_rw_rad_s_rts=0.0,
            gyro_scale_std=0.0, acc_noise_density_m_s2_rthz=0.0, acc_bias_std_m_s2=0.0, acc_bias_rw_m_s2_rts=0.0,
            acc_scale_std=0.0, misalignment_std_rad=0.0, imu_bits=0, mag_noise_std_uT=0.0,
            mag_hard_iron_std_uT=0.0, mag_soft_iron_std=0.0, mag_bits=0, gyro_fs_rad_s=1e9, acc_fs_m_s2=1e9,
        )


def quantise(x: FloatArray, lsb: float, bits: int) -> FloatArray:
    """Clip to the signed `bits`-bit range and round to multiples of `lsb` (bits = 0: no quantisation)."""
    if bits <= 0:
        return x
    lo, hi = -(2 ** (bits - 1)), 2 ** (bits - 1) - 1
    counts: FloatArray = np.clip(np.rint(x / lsb), lo, hi)
    return counts * lsb


def _misalignment(rng: np.random.Generator, n: int, scale_std: float, mis_std: float) -> FloatArray:
    """(n, 3, 3) matrices (I + diag(scale)) + off-diagonal cross-axis terms."""
    m = np.tile(np.eye(3), (n, 1, 1))
    m[:, [0, 1, 2], [0, 1, 2]] += rng.normal(0.0, scale_std, (n, 3)) if scale_std > 0 else 0.0
    if mis_std > 0:
        off = rng.normal(0.0, mis_std, (n, 3, 3))
        off[:, [0, 1, 2], [0, 1, 2]] = 0.0
        m += off
    return m


class SensorModel:
    """Turns true body-frame signals of `n_devices` instances into measured ones (vectorised over instances).

    State: per-instance `gyro_bias_rad_s`, `acc_bias_m_s2` (D, 3) that random-walk, fixed `gyro_matrix`,
    `acc_matrix` (scale + misalignment, D×3×3), `mag_hard_iron_uT` (D, 3), `mag_soft_iron` (D, 3, 3).
    Measurement: y = quantise(clip(M · x_true + bias + noise)); mag: y = quantise(S · b_true + h + noise).
    """

    def __init__(self, error_model: ImuErrorModel, n_devices: int = 1, rng: np.random.Generator | None = None):
        self.err = error_model
        self.n_devices = n_devices
        self.rng = rng if rng is not None else np.random.default_rng()
        e, r, d = error_model, self.rng, n_devices
        self.gyro_bias_rad_s: FloatArray = r.normal(0.0, e.gyro_bias_std_rad_s, (d, 3))
        self.acc_bias_m_s2: FloatArray = r.normal(0.0, e.acc_bias_std_m_s2, (d, 3))
        self.gyro_matrix = _misalignment(r, d, e.gyro_scale_std, e.misalignment_std_rad)
        self.acc_matrix = _misalignment(r, d, e.acc_scale_std, e.misalignment_std_rad)
        self.mag_hard_iron_uT: FloatArray = r.normal(0.0, e.mag_hard_iron_std_uT, (d, 3))
        s = r.normal(0.0, e.mag_soft_iron_std, (d, 3, 3))
        self.mag_soft_iron: FloatArray = np.eye(3) + 0.5 * (s + np.swapaxes(s, 1, 2))

    def measure(
        self, gyr_rad_s: FloatArray, acc_m_s2: FloatArray, mag_uT: FloatArray | None, dt_s: float
    ) -> tuple[FloatArray, FloatArray, FloatArray | None]:
        """Measured (gyr, acc, mag) from true values of shape (N, 3) (only if n_devices == 1) or (D, N, 3)."""
        squeeze = gyr_rad_s.ndim == 2
        g = gyr_rad_s[None] if squeeze else gyr_rad_s
        a = acc_m_s2[None] if squeeze else acc_m_s2
        m = None if mag_uT is None else (mag_uT[None] if squeeze else mag_uT)
        assert g.shape[0] == self.n_devices and g.shape[-1] == 3, g.shape
        e, r, n = self.err, self.rng, g.shape[1]
        rate = 1.0 / dt_s
        gb = self._walk("gyro_bias_rad_s", e.gyro_bias_rw_rad_s_rts, n, dt_s)
        ab = self._walk("acc_bias_m_s2", e.acc_bias_rw_m_s2_rts, n, dt_s)
        gyr = np.einsum("dij,dnj->dni", self.gyro_matrix, g) + gb
        acc = np.einsum("dij,dnj->dni", self.acc_matrix, a) + ab
        if e.gyro_noise_density_rad_s_rthz > 0:
            gyr += r.normal(0.0, e.gyro_noise_density_rad_s_rthz * math.sqrt(rate), gyr.shape)
        if e.acc_noise_density_m_s2_rthz > 0:
            acc += r.normal(0.0, e.acc_noise_density_m_s2_rthz * math.sqrt(rate), acc.shape)
        gyr = quantise(gyr, e.gyro_fs_rad_s / 2 ** (e.imu_bits - 1), e.imu_bits) if e.imu_bits else gyr
        acc = quantise(acc, e.acc_fs_m_s2 / 2 ** (e.imu_bits - 1), e.imu_bits) if e.imu_bits else acc
        gyr = np.clip(gyr, -e.gyro_fs_rad_s, e.gyro_fs_rad_s)
        acc = np.clip(acc, -e.acc_fs_m_s2, e.acc_fs_m_s2)
        mag = None
        if m is not None:
            mag = np.einsum("dij,dnj->dni", self.mag_soft_iron, m) + self.mag_hard_iron_uT[:, None, :]
            if e.mag_noise_std_uT > 0:
                mag += r.normal(0.0, e.mag_noise_std_uT, mag.shape)
            mag = quantise(mag, e.mag_lsb_uT, e.mag_bits)
        if squeeze:
            return gyr[0], acc[0], None if mag is None else mag[0]
        return gyr, acc, mag

    def _walk(self, name: str, rw: float, n: int, dt_s: float) -> FloatArray:
        """Per-sample bias (D, N, 3) continuing a random walk from the stored bias; stores the last value."""
        b0: FloatArray = getattr(self, name)
        if rw <= 0:
            return b0[:, None, :]
        steps = self.rng.normal(0.0, rw * math.sqrt(dt_s), (self.n_devices, n, 3))
        path = b0[:, None, :] + np.cumsum(steps, axis=1)
        setattr(self, name, path[:, -1, :].copy())
        return path


def specific_force_body(q_wxyz: FloatArray, acc_earth_m_s2: FloatArray) -> FloatArray:
    """Specific force in the body frame, m/s²: Rᵀ (a + [0, 0, g]) (ENU, gravity is -z)."""
    f = np.asarray(acc_earth_m_s2, dtype=np.float64) + np.array([0.0, 0.0, G_M_S2])
    return _quat.rotate_inverse(q_wxyz, f)


def field_body(q_wxyz: FloatArray, field_enu_uT: Sequence[float] = EARTH_FIELD_ENU_UT) -> FloatArray:
    """Earth magnetic field in the body frame, µT."""
    v = np.broadcast_to(np.asarray(field_enu_uT, dtype=np.float64), np.shape(q_wxyz)[:-1] + (3,))
    return _quat.rotate_inverse(q_wxyz, v)


# ---------------------------------------------------------------------------------------------------------------
# Radio link
# ---------------------------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class LinkModel:
    """Packet loss and publish jitter. `burst_len` > 1 makes losses bursty (Gilbert-Elliott two-state chain with
    mean burst length `burst_len` packets and long-run loss probability `loss_prob`)."""

    loss_prob: float = 0.0
    burst_len: float = 1.0
    jitter_std_s: float = 0.0


class LinkSim:
    """Decides per packet and instance whether it is lost; state = which instances are in a loss burst."""

    def __init__(self, link: LinkModel, n_devices: int, rng: np.random.Generator):
        self.link, self.rng = link, rng
        self.in_burst = np.zeros(n_devices, dtype=bool)
        p, b = link.loss_prob, max(1.0, link.burst_len)
        self.p_exit = 1.0 / b  # leave a burst
        self.p_enter = p * self.p_exit / max(1e-12, 1.0 - p)  # stationary loss = p_enter / (p_enter + p_exit)

    def lost(self) -> NDArray[np.bool_]:
        """Advance one packet period; True where that instance's packet is lost."""
        if self.link.loss_prob <= 0:
            return np.zeros_like(self.in_burst)
        u = self.rng.random(self.in_burst.shape)
        self.in_burst = np.where(self.in_burst, u >= self.p_exit, u < self.p_enter)
        return self.in_burst.copy()


# ---------------------------------------------------------------------------------------------------------------
# Clocks and payloads
# ---------------------------------------------------------------------------------------------------------------


@dataclass
class DeviceClock:
    """Device monotonic clock in µs: starts at a random boot offset; `wall_us(t_us)` maps it to unix µs."""

    boot_offset_us: int
    wall_at_zero_us: int

    @staticmethod
    def start(rng: random.Random | np.random.Generator, wall_now_us: int | None = None) -> DeviceClock:
        """A clock that reads `boot_offset_us` (0.5-20 s after boot) now."""
        offset = int(rng.uniform(0.5e6, 20e6))
        wall = time.time_ns() // 1000 if wall_now_us is None else wall_now_us
        return DeviceClock(offset, wall - offset)

    def wall_us(self, t_us: int) -> int:
        """Unix time (µs) of device time `t_us`."""
        return self.wall_at_zero_us + t_us


try:  # msgspec (a viser dependency) encodes float lists ~5x faster than the json module; same JSON text
    import msgspec

    _encode_json: Callable[[Any], bytes] = msgspec.json.encode
except ImportError:  # pragma: no cover
    def _encode_json(obj: Any) -> bytes:
        return json.dumps(obj, separators=(",", ":")).encode()


def encode_json(obj: Any) -> bytes:
    """Compact JSON bytes of plain Python data (dicts, lists, str, int, finite float)."""
    return _encode_json(obj)


def rows(a: FloatArray | list[Any], decimals: int) -> list[Any]:
    """Nested lists of `a` rounded to `decimals` (lists pass through: round whole batches once, then index)."""
    if isinstance(a, list):
        return a
    out: list[Any] = np.round(a, decimals).tolist()
    return out


def imu_payload(
    *, device_id: str, kind: str, boot_id: int, seq: int, t0_us: int, rate_hz: float,
    gyr_rad_s: FloatArray | list[Any], acc_m_s2: FloatArray | list[Any], mag_uT: FloatArray | list[Any] | None = None,
    wall_t0_us: int | None = None,
    temp_c: float | None = None, battery_v: float | None = None, rssi_dbm: float | None = None,
) -> bytes:
    """JSON bytes of a `rig.imu.v1` packet (schemas.ImuPacket), built without pydantic for speed.

    Optional scalars are sent as given (round them first). Arrays (n, 3) are rounded to 1 µrad/s, 10 µm/s²,
    1 nT (below every LSB); nested lists are used as given.
    """
    d: dict[str, Any] = {
        "v": schemas.PROTOCOL_VERSION, "device_id": device_id, "kind": kind, "boot_id": boot_id,
        "seq": seq % schemas.UINT32, "t0_us": t0_us, "rate_hz": rate_hz,
        "gyr_rad_s": rows(gyr_rad_s, 6), "acc_m_s2": rows(acc_m_s2, 5),
    }
    if mag_uT is not None:
        d["mag_uT"] = rows(mag_uT, 3)
    for k, v in (("temp_c", temp_c), ("battery_v", battery_v), ("rssi_dbm", rssi_dbm), ("wall_t0_us", wall_t0_us)):
        if v is not None:
            d[k] = v
    return encode_json(d)


IMU_ENCODINGS: tuple[str, ...] = ("json", "binary")


def imu_message(key: str, encoding: str, **fields: Any) -> Message:
    """One IMU put in `encoding` (`json`: `imu_payload`, `binary`: `schemas.imu_binary`, float32 samples)."""
    if encoding == "binary":
        return Message(key, schemas.imu_binary(**fields), schemas.ENCODING_IMU_BINARY)
    return Message(key, imu_payload(**fields), schemas.ENCODING_IMU)


def new_boot_id(rng: random.Random | np.random.Generator) -> int:
    """Random uint32 boot id (the firmware uses its hardware RNG at start)."""
    return int(rng.integers(0, schemas.UINT32)) if isinstance(rng, np.random.Generator) else rng.getrandbits(32)


# ---------------------------------------------------------------------------------------------------------------
# CLI options and zenoh session
# ---------------------------------------------------------------------------------------------------------------


def add_zenoh_args(parser: argparse.ArgumentParser, *, default_connect: str | None = DEFAULT_GATEWAY_ENDPOINT) -> None:
    """`--mode peer|client`, `--connect EP` (repeatable), `--listen EP` (repeatable), `--multicast`,
    `--zenoh-config FILE` (TLS/mTLS, user/password: docs/security.md)."""
    g = parser.add_argument_group("zenoh")
    g.add_argument("--mode", choices=["peer", "client"], default="peer", help="zenoh session mode (default: peer)")
    g.add_argument(
        "--connect", action="append", default=None, metavar="ENDPOINT",
        help=f"endpoint to connect to, repeatable (default: {default_connect}; 'none' for no connect)",
    )
    g.add_argument("--listen", action="append", default=None, metavar="ENDPOINT", help="endpoint to listen on")
    g.add_argument("--multicast", action="store_true", help="enable multicast scouting (default: off)")
    g.add_argument("--zenoh-config", type=Path, default=None, metavar="FILE",
                   help="a zenoh JSON5 config file as the base (e.g. the device config written by "
                        "`python -m gateway.ingest.secure_config`: mTLS to the gateway); --connect/--listen given "
                        "explicitly override its endpoints")  # fmt: skip
    parser.set_defaults(_default_connect=default_connect)


def zenoh_config(
    mode: str = "peer", connect: Sequence[str] = (DEFAULT_GATEWAY_ENDPOINT,), listen: Sequence[str] = (),
    multicast: bool = False,
) -> zenoh.Config:
    """A zenoh Config with explicit endpoints; connecting never blocks start-up and is retried in the background."""
    conf = zenoh.Config()
    conf.insert_json5("mode", json.dumps(mode))
    conf.insert_json5("scouting/multicast/enabled", "true" if multicast else "false")
    if connect:
        conf.insert_json5("connect/endpoints", json.dumps(list(connect)))
        # never give up: open() returns after ~0.5 s without a gateway and the link is retried in the background
        # (note: connect/timeout_ms = 0 would disable the retries)
        conf.insert_json5("connect/exit_on_failure", "false")
        retry = '{"period_init_ms": 250, "period_max_ms": 2000, "period_increase_factor": 2}'
        conf.insert_json5("connect/retry", retry)
    if listen:
        conf.insert_json5("listen/endpoints", json.dumps(list(listen)))
    return conf


def zenoh_config_from_args(args: argparse.Namespace) -> zenoh.Config:
    """Config from `add_zenoh_args` options; with `--zenoh-config` the file is the base and only endpoints given
    explicitly on the command line are set over it (a secure device config keeps its TLS endpoints)."""
    path: Path | None = getattr(args, "zenoh_config", None)
    if path is not None:
        conf = zenoh.Config.from_file(str(path))
        if args.connect:
            conf.insert_json5("connect/endpoints", json.dumps([c for c in args.connect if c.lower() != "none"]))
        if args.listen:
            conf.insert_json5("listen/endpoints", json.dumps(list(args.listen)))
        return conf
    connect = args.connect if args.connect is not None else (
        [args._default_connect] if getattr(args, "_default_connect", None) else []
    )
    connect = [c for c in connect if c.lower() != "none"]
    return zenoh_config(args.mode, connect, args.listen or [], args.multicast)


# ---------------------------------------------------------------------------------------------------------------
# Fleet runtime
# ---------------------------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class FleetSettings:
    """How a fleet of identical simulated devices runs (see `add_fleet_args` for the CLI)."""

    count: int = 1
    seed: int | None = None
    rate_hz: float = 100.0
    samples_per_packet: int = 10
    truth: bool = True
    link: LinkModel = field(default_factory=LinkModel)
    duration_s: float | None = None
    id_prefix: str = "dev"
    progress: bool = True
    imu_encoding: str = "json"  # or "binary" (protocol v2, docs/protocol.md section 3.6)

    @property
    def ids(self) -> list[str]:
        """`{prefix}-1 .. {prefix}-N`."""
        return [f"{self.id_prefix}-{i + 1}" for i in range(self.count)]

    @property
    def period_s(self) -> float:
        """Time between packets of one instance."""
        return self.samples_per_packet / self.rate_hz

    @staticmethod
    def from_args(args: argparse.Namespace) -> FleetSettings:
        """From `add_fleet_args` options."""
        return FleetSettings(
            count=args.count, seed=args.seed, rate_hz=args.rate, samples_per_packet=args.samples_per_packet,
            truth=args.truth, link=LinkModel(args.loss, args.burst, args.jitter_ms / 1000.0),
            duration_s=args.duration, id_prefix=args.id_prefix, progress=not args.no_progress,
            imu_encoding=args.encoding,
        )


def _bounded(cast: Callable[[str], Any], lo: float, hi: float) -> Callable[[str], Any]:
    """argparse type: `cast(text)` within [lo, hi]."""

    def parse(text: str) -> Any:
        value = cast(text)
        if not lo <= value <= hi:
            raise argparse.ArgumentTypeError(f"{text} is outside {lo:g}..{hi:g}")
        return value

    return parse


def add_fleet_args(
    parser: argparse.ArgumentParser, *, id_prefix: str, rate_hz: float = 100.0, samples_per_packet: int = 10
) -> None:
    """Shared device options: count, seed, rate, batching, truth, loss, jitter, duration."""
    g = parser.add_argument_group("fleet")
    g.add_argument("--count", type=_bounded(int, 1, 100_000), default=1,
                   help="instances in this process, ids PREFIX-1..PREFIX-N")
    g.add_argument("--id-prefix", default=id_prefix, help=f"device id prefix (default: {id_prefix})")
    g.add_argument("--seed", type=int, default=None, help="random seed (default: random)")
    g.add_argument("--rate", type=_bounded(float, 0.01, 1000.0), default=rate_hz,
                   help=f"sample rate, Hz, up to 1000 (default: {rate_hz:g})")
    g.add_argument(
        "--samples-per-packet", type=_bounded(int, 1, schemas.MAX_SAMPLES), default=samples_per_packet,
        help=f"samples batched per packet (default: {samples_per_packet})",
    )
    g.add_argument("--truth", action=argparse.BooleanOptionalAction, default=True, help="publish ground truth")
    g.add_argument("--loss", type=_bounded(float, 0.0, 0.99), default=0.0, help="packet loss probability (default: 0)")
    g.add_argument("--burst", type=float, default=1.0, help="mean loss burst length in packets (default: 1)")
    g.add_argument("--jitter-ms", type=float, default=0.0, help="publish time jitter std, ms (default: 0)")
    g.add_argument("--duration", type=float, default=None, help="stop after this many seconds (default: run on)")
    g.add_argument("--no-progress", action="store_true", help="no progress bar")
    g.add_argument("--encoding", choices=IMU_ENCODINGS, default="json",
                   help="IMU packets as JSON (rig.imu.v1) or the binary protocol v2 (rig.imu.v2) (default: json)")
    g.add_argument("-v", "--verbose", action="store_true", help="log debug messages")


IMU_PRESETS: tuple[str, ...] = ("calibrated", "uncalibrated", "legacy", "ideal")


def add_imu_args(parser: argparse.ArgumentParser) -> None:
    """`--imu PRESET`: which `ImuErrorModel` preset the simulated IMU has (default: calibrated)."""
    parser.add_argument(
        "--imu", choices=IMU_PRESETS, default="calibrated",
        help="IMU errors: calibrated = board calibrated once with gateway.calibrate (default); uncalibrated = raw "
             "board (hard iron tens of µT, accel offset tens of mg); legacy = the old defaults; ideal = none",
    )


@dataclass(frozen=True, slots=True)
class Message:
    """One put: key, payload bytes, encoding string; `block` uses CongestionControl.BLOCK."""

    key: str
    payload: bytes
    encoding: str
    block: bool = False


class Fleet(Protocol):
    """What `run_fleet` drives. All instances share the packet period; `tick` is called once per period.

    - `kind`: device kind (`rod`, `hook`, `ball`); `ids`: device ids.
    - `command_selectors`: key expressions to subscribe to (commands); payloads reach `on_command`.
    - `tick(k)`: produce packet k of every instance (device time advances by one period per tick) and return the
      messages. Return data messages per instance as `data[i]` so the runtime can drop lost ones; `extra` is
      always sent (truth is never lost).
    """

    kind: str
    ids: list[str]
    command_selectors: tuple[str, ...]

    def tick(self, k: int) -> tuple[list[list[Message]], list[Message]]: ...

    def on_command(self, key: str, payload: bytes) -> None: ...


@dataclass
class RunStats:
    """Counters of one run."""

    ticks: int = 0
    sent: int = 0
    lost: int = 0
    late_ticks: int = 0
    commands: int = 0


def run_fleet(session: zenoh.Session, fleet: Fleet, settings: FleetSettings, stop: Callable[[], bool] | None = None,
              ) -> RunStats:
    """Run the paced loop until `settings.duration_s` elapses or `stop()` is true; returns counters.

    Declares one liveliness token per instance (`rig/{kind}/{id}`), publishers per key on first use, and command
    subscribers whose callbacks only enqueue. Device time of tick k is k · period; the loop sleeps to absolute
    deadlines, so it does not drift, and skips sleeping when late (counted in `late_ticks`).
    """
    rng = np.random.default_rng(None if settings.seed is None else settings.seed + 7919)
    link = LinkSim(settings.link, len(fleet.ids), rng)
    inbox: queue.SimpleQueue[tuple[str, bytes]] = queue.SimpleQueue()

    def on_sample(sample: zenoh.Sample) -> None:
        inbox.put((str(sample.key_expr), sample.payload.to_bytes()))

    tokens = [session.liveliness().declare_token(schemas.device_token_key(fleet.kind, i)) for i in fleet.ids]
    subs = [session.declare_subscriber(sel, on_sample) for sel in fleet.command_selectors]
    pubs: dict[str, zenoh.Publisher] = {}

    def put(m: Message) -> None:
        pub = pubs.get(m.key)
        if pub is None:
            pub = session.declare_publisher(
                m.key, encoding=zenoh.Encoding(m.encoding),
                congestion_control=zenoh.CongestionControl.BLOCK if m.block else zenoh.CongestionControl.DROP,
            )
            pubs[m.key] = pub
        pub.put(m.payload)

    stats = RunStats()
    period = settings.period_s
    total = None if settings.duration_s is None else max(1, int(round(settings.duration_s / period)))
    bar = tqdm(total=total, unit="tick", desc=f"{fleet.kind} x{len(fleet.ids)}", disable=not settings.progress,
               file=sys.stderr, mininterval=1.0)
    start = time.monotonic()
    try:
        k = 0
        while total is None or k < total:
            if stop is not None and stop():
                break
            while True:
                try:
                    key, payload = inbox.get_nowait()
                except queue.Empty:
                    break
                stats.commands += 1
                try:
                    fleet.on_command(key, payload)
                except Exception:  # a bad command must not kill the device
                    log.exception("command on %s failed", key)
            data, extra = fleet.tick(k)
            lost = link.lost()
            if settings.link.jitter_std_s > 0:
                time.sleep(min(0.5 * period, abs(float(rng.normal(0.0, settings.link.jitter_std_s)))))
            for i, msgs in enumerate(data):
                if lost[i]:
                    stats.lost += len(msgs)
                    continue
                for m in msgs:
                    put(m)
                    stats.sent += 1
            for m in extra:
                put(m)
                stats.sent += 1
            k += 1
            stats.ticks = k
            bar.update(1)
            delay = start + k * period - time.monotonic()
            if delay > 0:
                time.sleep(delay)
            else:
                stats.late_ticks += 1
    finally:
        bar.close()
        for s in subs:
            s.undeclare()  # type: ignore[no-untyped-call]
        for t in tokens:
            t.undeclare()  # type: ignore[no-untyped-call]
        for p in pubs.values():
            p.undeclare()  # type: ignore[no-untyped-call]
    return stats


def decode_command(key: str, payload: bytes, index: dict[str, int]) -> tuple[int, schemas.Packet] | None:
    """A command for one of this fleet's instances as (instance index, packet); rejected or foreign ones are None.

    Malformed commands are logged with the protocol's reject reason; commands for ids not in `index` (a wildcard
    subscription sees every device's) are ignored silently."""
    try:
        cmd = schemas.decode(key, payload)
    except schemas.DecodeError as exc:
        log.warning("rejected command on %s: %s", key, exc)
        return None
    i = index.get(schemas.parse_key(key).device_id)
    return None if i is None else (i, cmd)


def _interrupt(signum: int, frame: object) -> None:
    raise KeyboardInterrupt(f"signal {signum}")


def stop_on_termination_signals() -> None:
    """Make SIGTERM (and SIGINT, even when a background shell started us with it ignored) stop like Ctrl-C.

    A launcher or service manager stops devices with SIGTERM; Python's default for it kills the process before
    `finally` blocks run, so the zenoh session and child processes would not be cleaned up."""
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, _interrupt)


def ignore_termination_signals() -> None:
    """Once stopping: a repeated SIGTERM/SIGINT (a launcher and a process group both signalling) must not break
    off the clean-up (closing the zenoh session, stopping children) with a traceback."""
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, signal.SIG_IGN)


def run_main(
    make_fleet: Callable[[argparse.Namespace, FleetSettings], Fleet],
    args: argparse.Namespace,
) -> int:
    """Open the session (always closed on exit), build the fleet, run it, print the counters on stderr."""
    logging.basicConfig(level=logging.DEBUG if args.verbose else logging.INFO, format="%(levelname)s %(message)s")
    settings = FleetSettings.from_args(args)
    fleet = make_fleet(args, settings)
    stop_on_termination_signals()
    with zenoh.open(zenoh_config_from_args(args)) as session:
        log.info("%s: publishing %d device(s) %s..%s at %g Hz, %d samples/packet", fleet.kind, len(fleet.ids),
                 fleet.ids[0], fleet.ids[-1], settings.rate_hz, settings.samples_per_packet)
        try:
            stats = run_fleet(session, fleet, settings)
        except KeyboardInterrupt:
            ignore_termination_signals()
            return 130
    log.info(
        "%s: %d ticks, %d messages sent, %d lost, %d late ticks, %d commands",
        fleet.kind, stats.ticks, stats.sent, stats.lost, stats.late_ticks, stats.commands,
    )
    return 0
