"""What every device kind shares: the `DeviceKind` protocol, the fused device record, a batch of one kind's fused
blocks as concatenated arrays, and the pipeline's output types.

A kind handler (gateway/kinds/rod.py, hook.py, ball.py) holds only what is special to its kind: its device state
(rules, angles), its post-processing of a batch and its outputs. Fusion (warm-up, filters, restarts) is the
`gateway.fusion.bank.FusionBank`'s; the common attitude post-processing (Euler, yaw unwrap, Attitude messages) is
done once per batch over all devices of a kind here (`KindBatch`, `attitudes`), not per device.
"""

from __future__ import annotations

import math
import operator
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass, field, replace
from itertools import chain
from typing import TYPE_CHECKING, Any, ClassVar, NamedTuple, Protocol, runtime_checkable

import numpy as np

from gateway import schemas
from gateway.alarm.engine import AlarmChange, Condition
from gateway.fusion.base import AttitudeFilter, FloatArray
from gateway.fusion.quaternion import to_euler

if TYPE_CHECKING:
    from pydantic import BaseModel

    from gateway.config import ThresholdModel
    from gateway.pipeline import PipelineSettings

G_M_S2 = 9.80665

class AlarmOut(NamedTuple):
    """One engine change for the hub: `t_us` is the device time of the sample behind it, `source_wall_us` that
    sample on the device's realtime clock (None when the device sends no `wall_t0_us`)."""

    kind: str  # wire device kind
    change: AlarmChange
    t_us: int
    source_wall_us: int | None


class FilterFailure(NamedTuple):
    """A device's filter raised or returned a non-finite quaternion; its fusion restarts from a fresh warm-up."""

    kind: str
    device_id: str
    reason: str  # the exception's class name (e.g. `LinAlgError`), or `non_finite`
    detail: str


class ReelEvent(NamedTuple):
    """A reel safety action for the event log: `reel_data_lost` (auto mode, no fresh attitude within the
    controller's timeout, stop sent) or `reel_offline` (the rod's liveliness token vanished, stop sent)."""

    device_id: str
    kind: str
    t_s: float  # gateway wall time
    details: dict[str, Any]


Timed = tuple[str, int, int | None, Condition]  # (kind, device t_us, device wall µs or None, wall-time condition)


class Published(NamedTuple):
    """One message of a kind's own topic: published on `topic.key(kind, device_id)` with the row's QoS."""

    topic: schemas.Topic
    kind: str
    device_id: str
    model: schemas.WireModel


@dataclass
class Output:
    """What one batch produced; the hub publishes and persists it."""

    attitudes: list[schemas.Attitude] = field(default_factory=list)
    attitude_blocks: list[schemas.AttitudeBlock] = field(default_factory=list)
    swings: list[schemas.Swing] = field(default_factory=list)
    heights: list[schemas.Height] = field(default_factory=list)
    alarms: list[AlarmOut] = field(default_factory=list)
    spots: schemas.SpotRanking | None = None
    reel_commands: list[tuple[str, dict[str, Any]]] = field(default_factory=list)  # (device id, ReelCommand fields)
    reel_events: list[ReelEvent] = field(default_factory=list)  # reel safety stops (watchdog, offline) to log
    filter_failures: list[FilterFailure] = field(default_factory=list)
    # (kind, device id, seconds bridged): gaps in device time between packets whose seq follows on, i.e. samples the
    # device itself did not send, or a t0_us more than gaps.JITTER_TOL_S late; counted as `time_gap_bridged`
    time_gaps: list[tuple[str, str, float]] = field(default_factory=list)
    # Outputs of kinds without a field above (a kind added later): each message with its Topic row; the hub
    # publishes them with that row's key and QoS, like the built-in outputs.
    extra: list[Published] = field(default_factory=list)


HeightRow = tuple[int, int, int, float, float, bool, str]
"""(seq, t_us, wall_t_us, height_m, vz_m_s, at_rest, aided): a Height's values."""


@dataclass
class FusedDevice:
    """Fusion state of one IMU device (any kind) plus its kind's own state in `state` (e.g. `RodState`)."""

    kind: str
    device_id: str
    filter_name: str
    dt_s: float
    use_mag: bool
    filt: AttitudeFilter | None  # None: a row of the bank's default-filter batch
    state: Any = None  # the kind handler's per-device state
    yaw_last: float = math.nan
    yaw_turns: int = 0
    quat: FloatArray = field(default_factory=lambda: np.array([1.0, 0.0, 0.0, 0.0]))
    euler: FloatArray = field(default_factory=lambda: np.zeros(3))
    yaw_unwrapped: float = 0.0
    t_us: int = 0
    seq: int = 0
    wall_offset_us: int = 0  # wall clock minus device clock
    wall_from_device: bool = False  # wall_offset_us from the device's own wall_t0_us (else from arrival time)
    last_attitude_t_s: float = -math.inf
    heave: Any = None  # gateway.fusion.heave.HeaveEstimator, made on the first fused block
    heave_row: int = -1  # its row of the pipeline's `HeaveStates` (-1: not attached)
    last_height: schemas.Height | None = None  # the last height message made (`height`)
    height_row: HeightRow | None = None  # the last height's values when no message was made for it (`heights_batch`)
    last_height_t_s: float = -math.inf
    last_t_s: float = math.nan  # device time of the newest sample its filter got, s (`gateway.fusion.gaps`)
    last_block: Any = None  # the (gyr, acc, mag, t_s) block that sample ended: the left side of a bridged gap
    follows: tuple[bool, ...] = ()  # per packet of the current block: its seq follows the one before (none lost)

    # Read views of the kind state, for REST and tests (None when the kind has no such thing).
    @property
    def rod(self) -> Any:
        return getattr(self.state, "rules", None) if self.kind == "rod" else None

    @property
    def hook(self) -> Any:
        return getattr(self.state, "rules", None) if self.kind == "hook" else None

    @property
    def swing(self) -> schemas.Swing | None:
        return getattr(self.state, "swing", None)

    @property
    def rest_heading_set_rad(self) -> float | None:
        return getattr(self.state, "rest_heading_set_rad", None)

    @property
    def height(self) -> schemas.Height | None:
        """The last Height (REST views), made from `height_row` on the first read when nobody took it live."""
        row = self.height_row
        if row is not None:
            self.height_row = None
            self.last_height = schemas.Height(
                device_id=self.device_id, kind=self.kind, seq=row[0], t_us=row[1],  # type: ignore[arg-type]
                wall_t_us=row[2], height_m=row[3], vz_m_s=row[4], at_rest=row[5], aided=row[6],  # type: ignore[arg-type]
            )  # fmt: skip
        return self.last_height

    @height.setter
    def height(self, message: schemas.Height | None) -> None:
        self.last_height, self.height_row = message, None


Ends = list[tuple[int, int, int]]  # per packet of a device's block: (last sample index, seq, t_us of that sample)


@dataclass
class Fused:
    """One device's fused block in a batch: its packets' samples, the filter's quaternions and packet ends."""

    dev: FusedDevice
    q: FloatArray  # (n, 4)
    gyr: FloatArray  # (n, 3) rad/s
    acc: FloatArray  # (n, 3) m/s², calibrated
    t_s: FloatArray  # (n,) device time
    ends: Ends
    packets: list[schemas.ImuPacket]


class KindBatch:
    """The fused blocks of every device of one kind in a batch, concatenated: row `start[i]:stop[i]` is device
    i's. Euler angles and unwrapped yaw are computed here once for all of them (the per-device cost they had was
    most of the gateway's CPU at 100 rods)."""

    def __init__(self, items: Sequence[Fused]) -> None:
        self.items = list(items)
        sizes = np.array([f.q.shape[0] for f in self.items], dtype=np.int64)
        self.stop = np.cumsum(sizes)
        self.start = self.stop - sizes
        self.q = np.concatenate([f.q for f in self.items])
        self.acc = np.concatenate([f.acc for f in self.items])
        self.gyr = np.concatenate([f.gyr for f in self.items])
        self.t_s = np.concatenate([f.t_s for f in self.items])
        self.euler = to_euler(self.q)
        prev = np.array([f.dev.yaw_last for f in self.items])
        turns = np.array([f.dev.yaw_turns for f in self.items], dtype=np.int64)
        self.yaw_u, new_turns = unwrap_segments(self.euler[:, 2], self.start, prev, turns)
        last = self.stop - 1
        quat, euler = self.q[last], self.euler[last]  # fresh arrays: each device keeps a row of them
        yaw_last, yaw_u, turns_l = euler[:, 2].tolist(), self.yaw_u[last].tolist(), new_turns.tolist()
        for i, f in enumerate(self.items):
            d = f.dev
            d.yaw_turns, d.yaw_last, d.yaw_unwrapped = turns_l[i], yaw_last[i], yaw_u[i]
            d.quat, d.euler = quat[i], euler[i]

    def rows(self, i: int) -> slice:
        """Rows of device i."""
        return slice(int(self.start[i]), int(self.stop[i]))


def unwrap_segments(
    yaw_rad: FloatArray, start: np.ndarray, prev_wrapped_rad: FloatArray, turns: np.ndarray
) -> tuple[FloatArray, np.ndarray]:
    """Continuous yaw of concatenated blocks, each continuing from its device's previous wrapped sample
    (`prev_wrapped_rad`, nan: none yet) and turn count; returns (unwrapped yaw, new turn counts).

    The same steps as `np.unwrap` on `[prev, *block]` (a jump beyond π is taken as the short way round), but the
    2π corrections are summed as integers per segment, so devices do not leak into each other."""
    n = yaw_rad.shape[0]
    seg = np.zeros(n, dtype=np.int64)
    seg[start[1:]] = 1
    seg = np.cumsum(seg)
    before = np.empty(n)
    before[1:] = yaw_rad[:-1]
    prev = np.where(np.isnan(prev_wrapped_rad), yaw_rad[start], prev_wrapped_rad)
    before[start] = prev
    dd = yaw_rad - before
    ddmod = np.mod(dd + np.pi, 2.0 * np.pi) - np.pi
    ddmod[(ddmod == -np.pi) & (dd > 0)] = np.pi
    r = np.rint((ddmod - dd) / (2.0 * np.pi))
    r[~(np.abs(dd) >= np.pi)] = 0.0  # a step under π is no turn; nor is a NaN step (its cast was garbage turns)
    k = r.astype(np.int64)
    ck = np.cumsum(k)
    base = ck[start] - k[start]  # the sum up to (not including) each segment's first row
    total = ck - base[seg] + turns[seg]
    u: FloatArray = yaw_rad + 2.0 * np.pi * total
    return u, total[np.append(start[1:], n) - 1]


def attitudes(kb: KindBatch, interval_s: float) -> list[schemas.Attitude]:
    """Attitude messages at packet ends, at most every `interval_s` of device time per device; the floats of all
    devices are converted in one `tolist` each."""
    picks: list[tuple[FusedDevice, int, int, int]] = []
    t_all, gap_s = kb.t_s, interval_s - 1e-9
    for f, base in zip(kb.items, kb.start.tolist(), strict=True):
        dev = f.dev
        for j, seq, t_us in f.ends:
            t = float(t_all[base + j])
            if t - dev.last_attitude_t_s < gap_s:
                continue
            dev.last_attitude_t_s = t
            picks.append((dev, base + j, seq, t_us))
    if not picks:
        return []
    rows = np.fromiter((r for _, r, _, _ in picks), dtype=np.int64, count=len(picks))
    q_rows, eul_rows, yaw_rows = kb.q[rows], kb.euler[rows], kb.yaw_u[rows]
    quats, eul, yaw_u = q_rows.tolist(), eul_rows.tolist(), yaw_rows.tolist()
    if _attitudes_valid(picks, q_rows, eul_rows, yaw_rows):  # one check of the batch instead of pydantic's per message
        build, model, fields = schemas.prevalidated, schemas.Attitude, _ATTITUDE_SET
        return [
            build(model, {
                "v": 1, "device_id": dev.device_id, "kind": dev.kind, "seq": seq, "t_us": t_us,
                "wall_t_us": t_us + dev.wall_offset_us, "quat_wxyz": tuple(q), "roll_rad": e[0], "pitch_rad": e[1],
                "yaw_rad": e[2], "yaw_unwrapped_rad": yu, "filter": dev.filter_name,
            }, fields)
            for (dev, _, seq, t_us), q, e, yu in zip(picks, quats, eul, yaw_u, strict=True)
        ]  # fmt: skip
    return [
        schemas.Attitude(
            device_id=dev.device_id, kind=dev.kind, seq=seq, t_us=t_us,  # type: ignore[arg-type]
            wall_t_us=t_us + dev.wall_offset_us, quat_wxyz=tuple(q), roll_rad=e[0],
            pitch_rad=e[1], yaw_rad=e[2], yaw_unwrapped_rad=yu, filter=dev.filter_name,
        )
        for (dev, _, seq, t_us), q, e, yu in zip(picks, quats, eul, yaw_u, strict=True)
    ]  # fmt: skip


_ATTITUDE_SET = frozenset(schemas.Attitude.model_fields) - {"v"}  # the fields `attitudes` sets
_HEIGHT_SET = frozenset(schemas.Height.model_fields) - {"v"}
TWO_PI = 2.0 * math.pi  # the limit of schemas._Angle
TIME_END_US = 2**63  # schemas.TimeUs: 0 <= t < 2**63


def ints_valid(values: Sequence[int], end: int) -> bool:
    """Every value a Python int (strict: no bool, no numpy scalar) in [0, end): `schemas.Uint32` / `TimeUs`."""
    return not values or (set(map(type, values)) == {int} and min(values) >= 0 and max(values) < end)


def headers_valid(devs: Sequence[FusedDevice], seqs: Sequence[int], t_us: Sequence[int]) -> bool:
    """Each output message's `seq` (Uint32), `t_us` and `wall_t_us` = `t_us` + its device's offset (TimeUs) are
    what the models accept; `devs[k]`, `seqs[k]`, `t_us[k]` belong to message k."""
    walls = [t + d.wall_offset_us for d, t in zip(devs, t_us, strict=True)]
    return ints_valid(seqs, schemas.UINT32) and ints_valid(t_us, TIME_END_US) and ints_valid(walls, TIME_END_US)


def device_fields_valid(devs: Iterable[FusedDevice], filter_name: bool = True) -> bool:
    """The device id, kind (and filter name) of each device are what an output model accepts."""
    return all(type(d.device_id) is str and schemas.valid_device_id(d.device_id) and d.kind in schemas.IMU_KINDS
               and type(d.kind) is str and (not filter_name or d.filter_name is None or type(d.filter_name) is str
                                            and 1 <= len(d.filter_name) <= 64) for d in devs)  # fmt: skip


def _attitudes_valid(picks: Sequence[tuple[FusedDevice, int, int, int]], q: FloatArray, euler: FloatArray,
                     yaw_u: FloatArray) -> bool:  # fmt: skip
    """Whether every Attitude of `picks` passes the model's checks (else `attitudes` builds them through pydantic,
    which raises as it always did)."""
    if not ((np.abs(q) <= 1.0).all() and (np.abs(euler) <= TWO_PI).all() and np.isfinite(yaw_u).all()):
        return False
    devs = [d for d, _, _, _ in picks]
    return (headers_valid(devs, [s for _, _, s, _ in picks], [t for _, _, _, t in picks])
            and device_fields_valid({id(d): d for d in devs}.values()))


def timed(dev: FusedDevice, conds: Iterable[Condition]) -> list[Timed]:
    """Rule conditions with wall times (the engine and store work in wall time); device times go along."""
    if not conds:
        return []
    offset_s = dev.wall_offset_us * 1e-6
    out: list[Timed] = []
    for cond in conds:
        t_us = int(round(cond.t_s * 1e6))
        src = t_us + dev.wall_offset_us if dev.wall_from_device else None
        out.append((dev.kind, t_us, src, replace(cond, t_s=cond.t_s + offset_s)))
    return out


@dataclass
class KindContext:
    """What the pipeline lends a handler: its settings, the current thresholds of a device, and a way to report
    that one device's post-processing failed (it restarts alone)."""

    settings: PipelineSettings
    thresholds: Callable[[str, str | None], ThresholdModel]  # (kind, device id or None) -> merged thresholds
    fail: Callable[[FusedDevice, Exception, Output], None]


@runtime_checkable
class DeviceKind(Protocol):
    """One device kind. `fused` kinds send IMU packets through the fusion bank and get `new_state` /
    `post` / `apply`; every kind may consume other packet types (`packet_types`, `on_packet`) and add outputs at
    the end of a batch (`end_batch`)."""

    name: ClassVar[str]  # the wire kind (`rig/{name}/{id}/...`)
    fused: ClassVar[bool]
    # The common IMU outputs (Attitude, Height, AttitudeBlock) for this kind: their wire models list the kinds they
    # accept (the protocol's Topic table), so a kind gets them once it is listed there.
    imu_outputs: ClassVar[bool]
    # Samples lost on the link interpolated for this kind's filter (`gateway.fusion.gaps`), or its packets fed back
    # to back: a choice per kind, measured (docs/fusion.md, "Lost packets").
    bridge_lost_samples: ClassVar[bool]
    # ... and the interpolated gyro rates tapered towards zero inside a gap with this time constant, s (0: the line)
    bridge_gyro_taper_s: ClassVar[float]
    packet_types: ClassVar[tuple[type[Any], ...]]

    def thresholds_model(self) -> type[BaseModel]:
        """The pydantic model of this kind's configuration (defaults + per-device overrides)."""
        ...

    def default_filter(self, settings: PipelineSettings) -> str:
        """The attitude filter a device of this kind gets when its settings name none."""
        ...

    def filter_options(self, th: Any) -> dict[str, Any]:
        """Extra arguments of the filter factory from the device's thresholds (e.g. the hook's rope length)."""
        ...

    def new_state(self, ctx: KindContext, dev: FusedDevice, th: Any) -> Any:
        """The per-device state of a device that just finished its warm-up."""
        ...

    def apply(self, ctx: KindContext, dev: FusedDevice, th: Any) -> bool:
        """New thresholds for a live device; False: its fusion must restart (e.g. a filter model parameter)."""
        ...

    def on_packet(self, ctx: KindContext, packet: Any, now_s: float) -> None:
        """A non-IMU packet of this kind (e.g. reel status, environment readings)."""
        ...

    def filter_inputs(self, device_id: str, wall_end_s: float, n: int, dt_s: float) -> dict[str, Any]:
        """Known inputs of the device's own filter for a block of `n` samples `dt_s` apart whose last is at wall time
        `wall_end_s`: keyword arguments of its `run` (e.g. the hook's crane feed, `tip_enu`); {} for none."""
        ...

    def post(self, ctx: KindContext, kb: KindBatch, now_s: float, out: Output) -> list[Timed]:
        """Kind logic on a batch's fused blocks (Euler etc. already in `kb`): outputs and rule conditions."""
        ...

    def end_batch(self, ctx: KindContext, now_s: float, out: Output) -> None:
        """After every packet of the batch (e.g. the ball's spot ranking)."""
        ...


class KindBase:
    """No-op defaults for `DeviceKind`: a handler overrides what its kind does."""

    name: ClassVar[str] = ""
    fused: ClassVar[bool] = True
    imu_outputs: ClassVar[bool] = True
    bridge_lost_samples: ClassVar[bool] = False
    bridge_gyro_taper_s: ClassVar[float] = 0.0
    packet_types: ClassVar[tuple[type[Any], ...]] = ()

    def thresholds_model(self) -> type[BaseModel]:
        raise NotImplementedError

    def default_filter(self, settings: PipelineSettings) -> str:
        return settings.default_filter

    def filter_options(self, th: Any) -> dict[str, Any]:
        return {}

    def new_state(self, ctx: KindContext, dev: FusedDevice, th: Any) -> Any:
        return None

    def apply(self, ctx: KindContext, dev: FusedDevice, th: Any) -> bool:
        return True

    def on_packet(self, ctx: KindContext, packet: Any, now_s: float) -> None:
        return None

    def filter_inputs(self, device_id: str, wall_end_s: float, n: int, dt_s: float) -> dict[str, Any]:
        return {}

    def post(self, ctx: KindContext, kb: KindBatch, now_s: float, out: Output) -> list[Timed]:
        return []

    def end_batch(self, ctx: KindContext, now_s: float, out: Output) -> None:
        return None


def _heave_of(f: Fused, rest_acc_tol_m_s2: float) -> Any:
    """The device's HeaveEstimator, made on its first fused block (g from that block's start when level)."""
    from gateway.fusion.heave import HeaveEstimator

    dev, acc = f.dev, f.acc
    if dev.heave is None:
        g0 = float(np.linalg.norm(acc[: min(acc.shape[0], 50)].mean(axis=0)))
        level = abs(g0 - G_M_S2) < rest_acc_tol_m_s2
        dev.heave = HeaveEstimator(gravity_m_s2=g0 if level else G_M_S2)
    return dev.heave


def _depth_into(f: Fused, depth: FloatArray, base: int) -> None:
    """Each packet's depth at its first sample, rows from `base` (NaN elsewhere, as initialised)."""
    for (i, _, _), p in zip(f.ends, f.packets, strict=True):
        if p.depth_m is not None:
            depth[base + i - p.n + 1] = p.depth_m


def heights(f: Fused, bias_rad_s: FloatArray | None, interval_s: float, rest_acc_tol_m_s2: float
            ) -> list[schemas.Height]:  # fmt: skip
    """Height / heave of one fused block (gateway.fusion.heave) at packet ends, at most every `interval_s`."""
    heave, depth = _heave_of(f, rest_acc_tol_m_s2), None
    if any(p.depth_m is not None for p in f.packets):
        depth = np.full(f.t_s.shape[0], np.nan)
        _depth_into(f, depth, 0)
    # the rest detector sees the rate without the filter's bias estimate
    rows = heave.update(f.q, f.gyr if bias_rad_s is None else f.gyr - bias_rad_s, f.acc, f.dev.dt_s, depth)
    return height_messages(f, rows, interval_s)


class HeaveStates:
    """Every IMU device's heave state and settings as rows of two arrays, one row per device id (kept across its
    fusion restarts: at most one per device seen). A batch's devices are then stepped with one gather and one
    scatter around the kernel (`heave_rows`), where stacking each device's state and copying it back cost a numpy
    call per device. A device's `HeaveEstimator` holds a view of its row as its `state`, so its own `update` (the
    per-device path) advances the same row. One owner: the ingest task (through the pipeline)."""

    def __init__(self) -> None:
        self.slots: dict[str, int] = {}  # device id -> its row
        self.owners: list[Any] = []  # per row: the HeaveEstimator whose `state` is a view of it
        self.states: FloatArray = np.zeros((0, 0))
        self.params: FloatArray = np.zeros((0, 0))

    def attach(self, device_id: str, heave: Any) -> int:
        """Give `heave` (a fresh HeaveEstimator of the device) its device's row: its state and settings are copied
        in and its `state` becomes a view of that row. Returns the row."""
        row = self.slots.get(device_id)
        if row is None:
            row = self.slots[device_id] = len(self.owners)
            self.owners.append(heave)
            if row >= self.states.shape[0]:
                self._grow(max(16, 2 * row), heave.state.shape[0], heave.params.shape[0])
        else:
            self.owners[row] = heave
        self.states[row] = heave.state
        self.params[row] = heave.params
        heave.state = self.states[row]
        return row

    def _grow(self, rows: int, n_state: int, n_params: int) -> None:
        states, params = np.zeros((rows, n_state)), np.zeros((rows, n_params))
        n = self.states.shape[0]
        if n:
            states[:n], params[:n] = self.states, self.params
        self.states, self.params = states, params
        for row, owner in enumerate(self.owners[:n]):  # each estimator's view onto the new arrays
            owner.state = states[row]


_depth_of = operator.attrgetter("depth_m")


def heave_rows(kb: KindBatch, live: Sequence[int], bias_rad_s: FloatArray, rest_acc_tol_m_s2: float,
               store: HeaveStates) -> FloatArray:  # fmt: skip
    """`heights`' heave rows (H, V_z, at rest, aided) of the devices `live` of a batch in one kernel call
    (`heave_run_segments`), each with its own state (its row of `store`), rate and settings; `bias_rad_s[k]` is
    live device k's gyro bias (zero where its filter has none). Rows of other devices are unset."""
    from gateway.fusion.heave import heave_run_segments

    items = [kb.items[i] for i in live]
    at_rows = [f.dev.heave_row for f in items]
    if at_rows and min(at_rows) < 0:  # a device's first fused block (or its estimator made by `heights`)
        for k, f in enumerate(items):
            if at_rows[k] < 0:
                at_rows[k] = f.dev.heave_row = store.attach(f.dev.device_id, _heave_of(f, rest_acc_tol_m_s2))
    at = np.array(at_rows, dtype=np.int64)
    sizes = kb.stop - kb.start
    bias = np.zeros((len(kb.items), 3))
    bias[np.asarray(live, dtype=np.int64)] = bias_rad_s
    gyr = kb.gyr - np.repeat(bias, sizes, axis=0)  # minus 0.0 where a filter has no bias: the same floats
    depth = np.zeros(0)
    depths = list(map(_depth_of, chain.from_iterable(f.packets for f in items)))
    if depths.count(None) != len(depths):  # some packet carries a depth
        depth = np.full(kb.q.shape[0], np.nan)
        for i, f in zip(live, items, strict=True):
            _depth_into(f, depth, int(kb.start[i]))
    states = store.states[at]
    dt_s = np.array([f.dev.dt_s for f in items], dtype=np.float64)
    sel = np.asarray(live, dtype=np.int64)
    rows: FloatArray = heave_run_segments(states, kb.q, gyr, kb.acc, depth, kb.start[sel], kb.stop[sel], dt_s,
                                          store.params[at])  # fmt: skip
    store.states[at] = states
    return rows


def height_messages(f: Fused, rows: FloatArray, interval_s: float) -> list[schemas.Height]:
    """Height messages at the block's packet ends from its heave rows (`rows[j]`: sample j of the block), at
    most every `interval_s` of device time; the device keeps the last one."""
    from gateway.fusion.heave import AIDED_NAMES

    dev, t_s, out = f.dev, f.t_s, []
    for i, seq, t_us in f.ends:
        if t_s[i] - dev.last_height_t_s < interval_s - 1e-9:
            continue
        dev.last_height_t_s = float(t_s[i])
        h, v, rest, aided = rows[i]
        out.append(schemas.Height(
            device_id=dev.device_id, kind=dev.kind, seq=seq, t_us=t_us,  # type: ignore[arg-type]
            wall_t_us=t_us + dev.wall_offset_us, vz_m_s=float(v), height_m=float(h), at_rest=bool(rest),
            aided=AIDED_NAMES[int(aided)],  # type: ignore[arg-type]
        ))  # fmt: skip
    dev.height = out[-1] if out else dev.height
    return out


def heights_batch(kb: KindBatch, live: Sequence[int], rows: FloatArray, interval_s: float,
                  takes: Callable[[FusedDevice], bool] | None = None) -> list[schemas.Height] | None:  # fmt: skip
    """`height_messages` of the devices `live` of a batch (heave rows of the whole batch), with one range check of
    all their values instead of pydantic's per message; None (nothing changed) when a value fails it: the caller
    then builds them device by device through pydantic, which raises for the device it concerns. A device that
    `takes` says nobody reads gets no message, only its values kept (`FusedDevice.height` makes one on demand)."""
    from gateway.fusion.heave import AIDED_NAMES

    t_all, gap_s = kb.t_s.tolist(), interval_s - 1e-9
    picks: list[tuple[FusedDevice, int, int, int]] = []  # (device, row in kb, seq, t_us)
    last: dict[int, float] = {}  # item -> device time of its last pick
    for i in live:
        f = kb.items[i]
        base, t_last = int(kb.start[i]), f.dev.last_height_t_s
        for j, seq, t_us in f.ends:
            t = t_all[base + j]
            if t - t_last >= gap_s:
                picks.append((f.dev, base + j, seq, t_us))
                t_last = last[i] = t
    if not picks:
        return []
    vals = rows[[r for _, r, _, _ in picks]]
    aided = vals[:, 3]
    times = [t for _, _, _, t in picks]
    walls = [t + d.wall_offset_us for (d, _, _, _), t in zip(picks, times, strict=True)]
    aided_ok = ((aided >= 0) & (aided < len(AIDED_NAMES)) & (aided == np.floor(aided))).all()
    devs = [d for d, _, _, _ in picks]
    unique = {id(d): d for d in devs}
    if not (np.isfinite(vals[:, :2]).all() and aided_ok
            and headers_valid(devs, [s for _, _, s, _ in picks], times)
            and device_fields_valid(unique.values(), filter_name=False)):
        return None
    for i, t in last.items():
        kb.items[i].dev.last_height_t_s = t
    build, model, fields = schemas.prevalidated, schemas.Height, _HEIGHT_SET
    taken = {} if takes is None else {k: takes(d) for k, d in unique.items()}  # once per device
    out: list[schemas.Height] = []
    for (dev, _, seq, t), wall, (h, v, rest, a) in zip(picks, walls, vals.tolist(), strict=True):
        if taken.get(id(dev), True):
            dev.height = m = build(model, {
                "v": 1, "device_id": dev.device_id, "kind": dev.kind, "seq": seq, "t_us": t, "wall_t_us": wall,
                "vz_m_s": v, "height_m": h, "at_rest": bool(rest), "aided": AIDED_NAMES[int(a)],
            }, fields)  # fmt: skip
            out.append(m)
        else:
            dev.height_row = (seq, t, wall, h, v, bool(rest), AIDED_NAMES[int(a)])
    return out


def attitude_blocks(f: Fused) -> list[schemas.AttitudeBlock]:
    """Every sample's attitude, one AttitudeBlock per packet (`f.q` holds the packets' samples in order)."""
    dev, out, start = f.dev, [], 0
    for p in f.packets:
        rows = f.q[start : start + p.n].tolist()
        start += p.n
        out.append(schemas.AttitudeBlock(
            device_id=dev.device_id, kind=dev.kind, boot_id=p.boot_id, seq=p.seq,  # type: ignore[arg-type]
            t0_us=p.t0_us, rate_hz=p.rate_hz, wall_t0_us=p.t0_us + dev.wall_offset_us,
            quat_wxyz=[tuple(r) for r in rows], filter=dev.filter_name,
        ))  # fmt: skip
    return out
