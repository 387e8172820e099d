"""Per-device processing, pure (no I/O, no clock reads): decoded packets in, results out; the hub fans them out.

One `Pipeline.process(packets, now_wall_s)` call takes a whole drained batch:

1. IMU packets are grouped per device (several packets of a device are concatenated in order).
2. Fusion: every device on the default filter is stepped together by `DefaultFilterBatch` (one numba call per
   distinct block length); other filters (the hook EKF, or any registered name chosen per device) run their own
   `update_block`/`run`. Euler angles come from one vectorised `to_euler` per group.
3. Device logic on the fused block: rod -> bite / drop-back / line-guard rules (`gateway.alarm.rules`) and, when
   auto reel is on, the fish-walking controller; hook -> swing angle Θ, displacement bearing, torsion φ
   (`gateway.fusion.hook`) and the hook rules; ball -> latest readings per spot and the spot ranking.
4. Rule conditions go through one `AlarmEngine` (lifecycle: raised / updated / cleared), with times converted
   from device time to wall time using the packet's `wall_t0_us` (else the arrival time).

Outputs are decimated: attitude at most every `attitude_interval_s` per device (the last sample of a packet),
swing once per packet, spot ranking at most every `spots_interval_s`.
"""

from __future__ import annotations

import logging
import math
import time
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, field, replace
from typing import Any, NamedTuple

import numpy as np
from pydantic import ValidationError

from gateway import schemas
from gateway.alarm.bite import tip_acc_up
from gateway.alarm.engine import Alarm, AlarmChange, AlarmEngine, Condition
from gateway.alarm.hook import HookAlarms
from gateway.alarm.rules import SPECS, RodAlarms
from gateway.calibrate import DeviceCalibration
from gateway.config import (
    DeviceSettings,
    HookThresholds,
    RodThresholds,
    SpotPreferences,
    ThresholdModel,
    default_thresholds,
    merge_thresholds,
)
from gateway.errors import BadSettings
from gateway.fusion import hook as hook_geo
from gateway.fusion.base import AttitudeFilter, FloatArray
from gateway.fusion.heave import AIDED_NAMES, HeaveEstimator
from gateway.fusion.quaternion import to_euler
from gateway.spots import SpotReading, rank_spots

log = logging.getLogger("gateway.pipeline")

G_M_S2 = 9.80665
DEFAULT_FILTER = "default"
HOOK_FILTER = "hook"


@dataclass(frozen=True)
class PipelineSettings:
    """Output rates and fallbacks; times in seconds."""

    default_filter: str = DEFAULT_FILTER
    hook_filter: str = HOOK_FILTER  # hooks not configured otherwise use the rope-aware EKF
    attitude_interval_s: float = 0.02  # at most 50 Hz of attitude per device (0: the end of every packet)
    swing_interval_s: float = 0.05  # hook: at most 20 Hz of Swing per hook (docs/protocol.md "Hook angles")
    attitude_blocks: bool = False  # also every sample's attitude, one AttitudeBlock per IMU packet
    spots_interval_s: float = 1.0
    reel_max_age_s: float = 1.0  # reel tension older than this is not fed to the line guard
    warmup_s: float = 0.5  # samples averaged before a filter starts (design.md: initial rest window)
    rest_gyr_std_rad_s: float = 0.01  # warm-up counts as rest below this gyro std (then its mean seeds the bias)
    warmup_bias_seed: bool = True  # False: never seed the gyro bias from a resting warm-up (as offline evaluate)
    rest_acc_tol_m_s2: float = 0.5  # ... and with |acc| within this of g
    # Auto reel watchdog: every rod in auto mode has its controller stepped at least this often (gateway clock), so
    # the controller's data timeout stops the reel when the rod's packets stop (`Pipeline.tick_reel`).
    reel_watchdog_s: float = 0.1
    # An alarm resumed from the store after a restart is cleared when its device's fresh rules have run this long
    # (gateway wall time) without a condition of its type (its clear may have been lost with the old process).
    resume_confirm_s: float = 10.0
    height_interval_s: float = 0.1  # at most 10 Hz of Height (heave) per IMU device; <= 0: none computed


@dataclass
class ImuDevice:
    """State of one rod or hook."""

    kind: str
    device_id: str
    filter_name: str
    dt_s: float
    use_mag: bool
    filt: AttitudeFilter | None  # None: a row of the default-filter batch
    rod: RodAlarms | None = None
    hook: HookAlarms | None = None
    rest_heading_rad: float | None = None  # hook: heading at the first fused sample (torsion reference)
    rest_heading_set_rad: float | None = None  # hook: configured rest heading (HookThresholds), wins when set
    last_swing_t_s: float = -math.inf  # hook: device time of the last Swing published
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
    swing: schemas.Swing | None = None
    baseline_rad: float = math.nan
    auto_reel: Any = None  # FishWalkingController when auto mode is on
    reel_step_t_s: float = -math.inf  # device time the controller was last stepped at (its steps move forward)
    heave: Any = None  # gateway.fusion.heave.HeaveEstimator, made on the first fused block
    height: schemas.Height | None = None  # the last one published
    last_height_t_s: float = -math.inf


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


@dataclass
class ReelWatch:
    """Auto-reel bookkeeping of one rod; it outlives the device's fusion state (a filter restart drops that)."""

    since_s: float  # gateway time the newest rod data reached the controller (or of the first watchdog look)
    device_t_s: float | None = None  # device time of that data's last sample
    fields: dict[str, Any] | None = None  # last command sent
    lost: bool = False  # a data-lost stop went out and no fresh data has been used since


_Timed = tuple[str, int, int | None, Condition]  # (kind, device t_us, device wall µs or None, wall-time condition)


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


def _thermocline_m(profile: list[schemas.ProfilePoint] | None) -> float | None:
    """Depth of the steepest temperature drop in a profile (None without at least 3 levels)."""
    if not profile or len(profile) < 3:
        return None
    pts = sorted(profile, key=lambda p: p.depth_m)
    grads = [
        (a.water_temp_c - b.water_temp_c) / max(b.depth_m - a.depth_m, 1e-6) for a, b in zip(pts, pts[1:], strict=False)
    ]
    i = int(np.argmax(grads))
    return 0.5 * (pts[i].depth_m + pts[i + 1].depth_m)


def _position(fix: schemas.GnssFix | None) -> dict[str, float]:
    """A spot's `lat_deg`/`lon_deg` from its ball's GNSS fix (none without a fix or with fix quality 0)."""
    return {} if fix is None or fix.fix_quality == 0 else {"lat_deg": fix.lat_deg, "lon_deg": fix.lon_deg}


def _unwrap(prev_wrapped: float, turns: int, yaw: FloatArray) -> tuple[FloatArray, int]:
    """Continuous yaw for a block, continuing from the previous wrapped sample and turn count."""
    if math.isnan(prev_wrapped):
        prev_wrapped = float(yaw[0])
    u = np.unwrap(np.concatenate(([prev_wrapped], yaw)))[1:] + 2.0 * math.pi * turns
    new_turns = int(round((float(u[-1]) - float(yaw[-1])) / (2.0 * math.pi)))
    return u, new_turns


class Pipeline:
    """All per-device state of the gateway. Not thread-safe: call from the ingest task only (REST calls that
    change settings are made on the same event loop)."""

    def __init__(
        self,
        settings: PipelineSettings | None = None,
        defaults: Mapping[str, ThresholdModel] | None = None,
        device_settings: Mapping[str, tuple[str, DeviceSettings]] | None = None,
        active_alarms: Iterable[Alarm] = (),
    ) -> None:
        self.settings = settings or PipelineSettings()
        self.defaults: dict[str, ThresholdModel] = {k: default_thresholds(k) for k in ("rod", "hook", "ball")}
        self.defaults.update(defaults or {})
        self.device_settings: dict[str, tuple[str, DeviceSettings]] = dict(device_settings or {})
        active = list(active_alarms)
        self.engine = AlarmEngine(active)
        # Alarms resumed from the store: the rules restart from scratch, so one whose clear was lost (a full disk, a
        # kill) would stay active for good. Each is confirmed by any condition of its type, else cleared once its
        # device's fresh rules have run for `resume_confirm_s`. Only the rules' own types (rod, hook): ingest and
        # presence alarms (device_conflict, ...) clear themselves.
        self._resumed: dict[tuple[str, str], float | None] = {
            (a.device_id, a.type): None for a in active
            if a.active and (spec := SPECS.get(a.type)) is not None and spec.kind in ("rod", "hook")
        }  # fmt: skip
        self.devices: dict[str, ImuDevice] = {}
        self.kinds: dict[str, str] = {}  # every device ever seen or configured -> wire kind
        self.kinds.update({d: k for d, (k, _) in self.device_settings.items()})
        self.env: dict[str, schemas.EnvPacket] = {}  # device id -> latest reading
        self.reel: dict[str, tuple[schemas.ReelStatus, float]] = {}  # rod id -> (latest status, arrival wall s)
        self.auto_reel: dict[str, bool] = {d: True for d, (_, ds) in self.device_settings.items() if ds.auto_reel}
        self._reel_watch: dict[str, ReelWatch] = {}
        self._batch: Any = None
        self._warmup: dict[str, list[schemas.ImuPacket]] = {}
        # Per-device IMU calibration, parsed once from DeviceSettings.calibration (absent: raw values are fused).
        self._cal: dict[str, DeviceCalibration] = {
            d: DeviceCalibration.from_json(ds.calibration)
            for d, (_, ds) in self.device_settings.items()
            if ds.calibration is not None
        }
        self._last_spots_s = -math.inf
        self._spots_dirty = False

    # -- configuration --------------------------------------------------------------------------------------

    def effective(self, kind: str, device_id: str | None = None) -> tuple[str, ThresholdModel]:
        """(filter name, thresholds) of a device: kind defaults with its override merged on top."""
        base = self.defaults[kind]
        default_filter = self.settings.hook_filter if kind == "hook" else self.settings.default_filter
        entry = self.device_settings.get(device_id) if device_id is not None else None
        if entry is None:
            return default_filter, base
        return entry[1].filter_name or default_filter, merge_thresholds(base, entry[1].thresholds)

    def set_defaults(self, kind: str, thresholds: ThresholdModel) -> None:
        """New kind defaults; applied to every live device of the kind (re-merged with its override)."""
        for dev, k in self.kinds.items():  # validate every device's merge first: all or nothing
            if k == kind and dev in self.device_settings:
                try:
                    merge_thresholds(thresholds, self.device_settings[dev][1].thresholds)
                except ValidationError as exc:
                    raise BadSettings([f"device {dev}: {e['msg']}" for e in exc.errors()]) from exc
        self.defaults[kind] = thresholds
        for live in list(self.devices.values()):
            if live.kind == kind:
                self._apply(live)

    def validate_device_settings(self, kind: str, ds: DeviceSettings) -> ThresholdModel:
        """The thresholds `ds` would give; raises BadSettings with readable messages."""
        from gateway.fusion.registry import FILTERS

        errors = []
        known = {DEFAULT_FILTER, HOOK_FILTER, *FILTERS}
        if ds.filter_name is not None and ds.filter_name not in known:
            errors.append(f"filter_name: unknown filter {ds.filter_name!r}; known: {', '.join(sorted(known))}")
        try:
            th = merge_thresholds(self.defaults[kind], ds.thresholds)
        except ValidationError as exc:
            errors += [f"thresholds.{'.'.join(str(p) for p in e['loc']) or '(model)'}: {e['msg']}"
                       for e in exc.errors()]  # fmt: skip
        if ds.auto_reel and kind != "rod":
            errors.append(f"auto_reel: only a rod has a reel, not a {kind}")
        if errors:
            raise BadSettings(errors)
        return th

    def set_device_settings(self, device_id: str, kind: str, ds: DeviceSettings) -> None:
        """Validate and apply one device's settings (auto reel included); a changed filter or calibration restarts its
        fusion on the next packet (the filter's reference field came from the data as it was corrected before)."""
        self.validate_device_settings(kind, ds)
        old = self.device_settings.get(device_id)
        recalibrated = (old[1].calibration if old else None) != ds.calibration
        if recalibrated:
            if ds.calibration is None:
                self._cal.pop(device_id, None)
            else:
                self._cal[device_id] = DeviceCalibration.from_json(ds.calibration)
        self.device_settings[device_id] = (kind, ds)
        self.kinds[device_id] = kind
        if ds.auto_reel != self.auto_reel.get(device_id, False):
            self._switch_auto_reel(device_id, ds.auto_reel)
        dev = self.devices.get(device_id)
        if dev is not None:
            if recalibrated or self.effective(kind, device_id)[0] != dev.filter_name:
                self._drop(device_id)
            else:
                self._apply(dev)

    def set_auto_reel(self, device_id: str, on: bool) -> bool:
        """Turn auto reel (fish walking) on or off for a rod, recorded in its DeviceSettings (`auto_reel`) so the
        caller can persist them; False when the controller is not available. Idempotent: the same mode again
        keeps the running controller."""
        if on != self.auto_reel.get(device_id, False):
            kind, ds = self.device_settings.get(device_id, ("rod", DeviceSettings()))
            self.device_settings[device_id] = (kind, ds.model_copy(update={"auto_reel": on}))
            self.kinds.setdefault(device_id, kind)
            self._switch_auto_reel(device_id, on)
        return not on or _controller_class() is not None

    def _switch_auto_reel(self, device_id: str, on: bool) -> None:
        self._reel_watch.pop(device_id, None)  # a fresh watchdog record per auto session
        if on:
            self.auto_reel[device_id] = True
        else:
            self.auto_reel.pop(device_id, None)
        dev = self.devices.get(device_id)
        if dev is not None:
            dev.auto_reel = self._make_controller(dev) if on else None

    def _apply(self, dev: ImuDevice) -> None:
        _, th = self.effective(dev.kind, dev.device_id)
        if dev.rod is not None and isinstance(th, RodThresholds):
            dev.rod.set_thresholds(th)
        if dev.hook is not None and isinstance(th, HookThresholds):
            rope = getattr(getattr(dev.filt, "settings", None), "rope_length_m", None)
            if rope is not None and rope != th.rope_length_m:  # the pendulum model changed: restart fusion
                self._drop(dev.device_id)
                return
            dev.hook.set_thresholds(th)
            dev.rest_heading_set_rad = None if th.rest_heading_deg is None else math.radians(th.rest_heading_deg)

    def restart(self, device_id: str) -> None:
        """Forget a device's fusion and rules state (its next packets start a new warm-up), e.g. when its clock
        jumped to a new timeline. Alarms stay with the engine; settings stay."""
        self._warmup.pop(device_id, None)
        if device_id in self.devices:
            self._drop(device_id)

    def _drop(self, device_id: str) -> None:
        dev = self.devices.pop(device_id)
        if dev.filt is None and self._batch is not None:
            self._batch.remove(device_id)

    def warm_up(self) -> None:
        """Compile the numba kernels (default batch filter, hook filter) on dummy data, leaving no state behind.

        Called once at start-up: a first compile can take tens of seconds on a busy machine, and done on the first
        packet it would stall ingest (and delay every alarm) for that long."""
        from gateway.fusion.batch import DefaultFilterBatch

        acc, mag = np.array([0.0, 0.0, G_M_S2]), np.array([0.0, 20.0, -44.0])
        batch = DefaultFilterBatch()
        batch.add("warm-up", dt_s=0.01, acc_m_s2=acc, mag_uT=mag)
        n = 5
        batch.step(np.zeros((1, n, 3)), np.tile(acc, (1, n, 1)), np.tile(mag, (1, n, 1)))
        for name in {self.settings.hook_filter, self.settings.default_filter} - {DEFAULT_FILTER}:
            try:
                f = _make_filter(name, True)
            except KeyError:
                continue
            f.initialise(acc, mag)
            step = getattr(f, "update_block", None) or f.run
            step(np.zeros((n, 3)), np.tile(acc, (n, 1)), np.tile(mag, (n, 1)), 0.01)
        if self.settings.height_interval_s > 0:
            HeaveEstimator().update(np.tile([1.0, 0, 0, 0], (n, 1)), np.zeros((n, 3)), np.tile(acc, (n, 1)), 0.01)

    # -- processing -----------------------------------------------------------------------------------------

    def process(self, packets: Iterable[schemas.Packet], now_wall_s: float | None = None) -> Output:
        """Run one drained batch of decoded, sequence-checked packets (in arrival order)."""
        now = time.time() if now_wall_s is None else now_wall_s
        out = Output()
        imu: dict[str, list[schemas.ImuPacket]] = {}
        for p in packets:
            if isinstance(p, schemas.ImuPacket):
                imu.setdefault(p.device_id, []).append(p)
            elif isinstance(p, schemas.EnvPacket):
                self.kinds[p.device_id] = "ball"
                self.env[p.device_id] = p
                self._spots_dirty = True
            elif isinstance(p, schemas.ReelStatus):
                self.kinds.setdefault(p.device_id, "rod")
                self.reel[p.device_id] = (p, now)
        conditions: list[_Timed] = []
        if imu:
            self._fuse(imu, now, out, conditions)
        if self._resumed:
            self._settle_resumed(conditions, now)
        for kind, t_us, src_us, c in conditions:
            out.alarms += [AlarmOut(kind, change, t_us, src_us) for change in self.engine.evaluate([c])]
        if self._spots_dirty and now - self._last_spots_s >= self.settings.spots_interval_s:
            out.spots = self.rank_spots(now)
            self._last_spots_s, self._spots_dirty = now, False
        return out

    def _settle_resumed(self, conditions: list[_Timed], now: float) -> None:
        """Confirm resumed alarms by their rules' conditions; clear the ones unconfirmed after `resume_confirm_s`
        of their device's fused data (wall time)."""
        for _, _, _, c in conditions:
            self._resumed.pop((c.device_id, c.type), None)
        for (device_id, alarm_type), since in list(self._resumed.items()):
            dev = self.devices.get(device_id)
            if dev is None:  # not fused yet (or restarting): its rules have not looked
                continue
            if since is None:
                self._resumed[(device_id, alarm_type)] = now
            elif now - since >= self.settings.resume_confirm_s:
                del self._resumed[(device_id, alarm_type)]
                msg = f"cleared: not confirmed within {self.settings.resume_confirm_s:g} s of data after a restart"
                conditions.append((dev.kind, dev.t_us, None, Condition(device_id, alarm_type, None, now, message=msg)))

    def _device(self, p: schemas.ImuPacket, gyr: FloatArray, acc: FloatArray, mag: FloatArray | None) -> ImuDevice:
        """Create a device after its warm-up window: the filter starts from the window's mean acc (+ mag), and
        when the window was at rest its mean gyro seeds the filter's bias estimate."""
        self.kinds[p.device_id] = p.kind
        n_warm = max(1, int(math.ceil(self.settings.warmup_s * p.rate_hz)))  # a big first batch: use its start only
        gyr, acc, mag = gyr[:n_warm], acc[:n_warm], None if mag is None else mag[:n_warm]
        name, th = self.effective(p.kind, p.device_id)
        use_mag = mag is not None
        acc0, mag0 = acc.mean(axis=0), None if mag is None else mag.mean(axis=0)
        filt: AttitudeFilter | None = None
        if name != DEFAULT_FILTER:
            try:
                filt = _make_filter(name, use_mag, th.rope_length_m if isinstance(th, HookThresholds) else None)
            except KeyError:
                log.warning("device %s: filter %r not available, using %r", p.device_id, name, DEFAULT_FILTER)
                name = DEFAULT_FILTER
        hook_start = getattr(filt, "start", None) if p.kind == "hook" else None  # HookFilter: its own warm-up
        if hook_start is not None:
            hook_start(gyr, acc, mag, 1.0 / p.rate_hz, seed_bias=self.settings.warmup_bias_seed)
        elif filt is not None:
            filt.initialise(acc0, mag0)
        else:
            if self._batch is None:
                from gateway.fusion.batch import DefaultFilterBatch

                self._batch = DefaultFilterBatch()
            self._batch.add(p.device_id, dt_s=1.0 / p.rate_hz, use_mag=use_mag, acc_m_s2=acc0, mag_uT=mag0)
        dev = ImuDevice(p.kind, p.device_id, name, 1.0 / p.rate_hz, use_mag, filt)
        if hook_start is None:  # (a HookFilter decided rest, bias seeding and "already swinging" in its start)
            g_std = gyr.std(axis=0) if gyr.shape[0] > 1 else np.full(3, math.inf)
            quiet = g_std < self.settings.rest_gyr_std_rad_s
            level = abs(float(np.linalg.norm(acc0)) - G_M_S2) < self.settings.rest_acc_tol_m_s2
            if level and quiet.all() and self.settings.warmup_bias_seed:
                self._seed_bias(dev, gyr.mean(axis=0))
        if p.kind == "rod":
            dev.rod = RodAlarms(p.device_id, th if isinstance(th, RodThresholds) else None)
            if self.auto_reel.get(p.device_id):
                dev.auto_reel = self._make_controller(dev)
        else:
            dev.hook = HookAlarms(p.device_id, th if isinstance(th, HookThresholds) else None)
            if isinstance(th, HookThresholds) and th.rest_heading_deg is not None:
                dev.rest_heading_set_rad = math.radians(th.rest_heading_deg)
        self.devices[p.device_id] = dev
        return dev

    def _seed_bias(self, dev: ImuDevice, bias_rad_s: FloatArray) -> None:
        """Start the filter's gyro-bias estimate at `bias_rad_s` (filters without a bias state are left alone)."""
        if dev.filt is None:
            from gateway.fusion import _default_kernels as K

            clip = math.radians(self._batch.settings.bias_clip_deg_s)
            row = self._batch.row(dev.device_id)
            self._batch.states[row, K.S_BIAS : K.S_BIAS + 3] = np.clip(bias_rad_s, -clip, clip)
            return
        seed = getattr(dev.filt, "seed_gyro_bias", None)  # e.g. HookFilter
        if seed is not None:
            seed(bias_rad_s)

    def _gather(
        self, dev_id: str, pkts: list[schemas.ImuPacket]
    ) -> tuple[FloatArray, FloatArray, FloatArray | None, FloatArray]:
        gyr = np.array([s for p in pkts for s in p.gyr_rad_s], dtype=np.float64)
        acc = np.array([s for p in pkts for s in p.acc_m_s2], dtype=np.float64)
        has_mag = all(p.mag_uT is not None for p in pkts)
        mag = np.array([s for p in pkts for s in p.mag_uT or ()], dtype=np.float64) if has_mag else None
        t_s = np.concatenate([p.t0_us * 1e-6 + np.arange(p.n) / p.rate_hz for p in pkts])
        return gyr, acc, mag, t_s

    def _fuse(
        self, imu: dict[str, list[schemas.ImuPacket]], now: float, out: Output, conds: list[_Timed]
    ) -> None:
        blocks: dict[str, tuple[FloatArray, FloatArray, FloatArray | None, FloatArray]] = {}
        ends: dict[str, list[tuple[int, int, int]]] = {}  # per device: (last sample index, seq, t_us) per packet
        fused: dict[str, list[schemas.ImuPacket]] = {}  # per device: the packets behind its block
        for dev_id, pkts in imu.items():
            dev = self.devices.get(dev_id)
            try:  # one device's bad data (or a bug it triggers) costs only its own output: it restarts
                if dev is None:  # warm-up: collect, start the filter once the window is full
                    warm = self._warmup.setdefault(dev_id, [])
                    warm.extend(pkts)
                    self.kinds[dev_id] = pkts[0].kind
                    if sum(p.n / p.rate_hz for p in warm) < self.settings.warmup_s - 1e-9:  # 10 x 0.05 s is 0.4999…
                        continue
                    pkts = self._warmup.pop(dev_id)
                    gyr, acc, mag, t_s = self._gather(dev_id, pkts)
                    if (cal := self._cal.get(dev_id)) is not None:  # before `_device` takes the warm-up means
                        acc, mag = cal.apply(acc, mag)
                    dev = self._device(pkts[0], gyr, acc, mag)  # a filter that cannot start: counted, warms up again
                else:
                    gyr, acc, mag, t_s = self._gather(dev_id, pkts)
                    if (cal := self._cal.get(dev_id)) is not None:
                        acc, mag = cal.apply(acc, mag)
            except Exception as exc:
                self._fail(pkts[0].kind, dev_id, exc, out)
                continue
            if abs(1.0 / pkts[-1].rate_hz - dev.dt_s) > 1e-12:
                dev.dt_s = 1.0 / pkts[-1].rate_hz
                if dev.filt is None:
                    self._batch.set_dt(dev_id, dev.dt_s)
            last = pkts[-1]
            dev.t_us, dev.seq = last.t0_us + int(round((last.n - 1) * 1e6 / last.rate_hz)), last.seq
            dev.wall_from_device = last.wall_t0_us is not None
            dev.wall_offset_us = (last.wall_t0_us - last.t0_us) if last.wall_t0_us is not None else (
                int(now * 1e6) - dev.t_us)  # fmt: skip
            blocks[dev_id] = (gyr, acc, mag if dev.use_mag else None, t_s)
            fused[dev_id] = pkts
            idx = np.cumsum([p.n for p in pkts]) - 1
            ends[dev_id] = [(int(i), p.seq, p.t0_us + int(round((p.n - 1) * 1e6 / p.rate_hz)))
                            for i, p in zip(idx, pkts, strict=True)]  # fmt: skip
        quats = self._step_filters(blocks, out)
        for dev_id, q in quats.items():
            dev = self.devices[dev_id]
            mine: list[_Timed] = []
            try:
                self._post(dev, q, blocks[dev_id], ends[dev_id], now, out, mine)
                if self.settings.height_interval_s > 0:
                    out.heights += self._heights(dev, q, blocks[dev_id], fused[dev_id], ends[dev_id])
                if self.settings.attitude_blocks:
                    out.attitude_blocks += self._attitude_blocks(dev, q, fused[dev_id])
            except Exception as exc:  # e.g. an output time out of range: only this device restarts
                self._fail(dev.kind, dev_id, exc, out)
                continue
            conds += mine

    def _heights(
        self, dev: ImuDevice, q: FloatArray, block: tuple[FloatArray, FloatArray, FloatArray | None, FloatArray],
        pkts: list[schemas.ImuPacket], ends: list[tuple[int, int, int]],
    ) -> list[schemas.Height]:  # fmt: skip
        """Height / heave of the block (gateway.fusion.heave) at packet ends, at most every `height_interval_s`."""
        gyr, acc, _, t_s = block
        if dev.heave is None:
            g0 = float(np.linalg.norm(acc[: min(acc.shape[0], 50)].mean(axis=0)))
            level = abs(g0 - G_M_S2) < self.settings.rest_acc_tol_m_s2
            dev.heave = HeaveEstimator(gravity_m_s2=g0 if level else G_M_S2)
        depth = None
        if any(p.depth_m is not None for p in pkts):
            depth = np.full(t_s.shape[0], np.nan)
            for (i, _, _), p in zip(ends, pkts, strict=True):
                if p.depth_m is not None:
                    depth[i - p.n + 1] = p.depth_m
        bias = self._bias(dev)  # the rest detector sees the rate without the filter's bias estimate
        rows = dev.heave.update(q, gyr if bias is None else gyr - bias, acc, dev.dt_s, depth)
        out = []
        for i, seq, t_us in ends:
            if t_s[i] - dev.last_height_t_s < self.settings.height_interval_s - 1e-9:
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

    def _step_filters(
        self, blocks: dict[str, tuple[FloatArray, FloatArray, FloatArray | None, FloatArray]], out: Output
    ) -> dict[str, FloatArray]:
        """One fused block per device. A filter that raises or returns a non-finite quaternion fails alone: it is
        reported in `out.filter_failures` and its device restarts from a fresh warm-up window (`_fail`)."""
        quats: dict[str, FloatArray] = {}
        by_len: dict[int, list[str]] = {}
        for dev_id, (gyr, acc, mag, _) in blocks.items():
            dev = self.devices[dev_id]
            if dev.filt is None:
                by_len.setdefault(gyr.shape[0], []).append(dev_id)
                continue
            step = getattr(dev.filt, "update_block", None) or dev.filt.run
            try:
                quats[dev_id] = step(gyr, acc, mag, dev.dt_s)
            except Exception as exc:
                self._fail(dev.kind, dev_id, exc, out)
        if by_len:
            try:
                quats.update(self._step_batch(blocks, by_len))
            except Exception as exc:  # the shared kernel failed: every device in it restarts
                for ids in by_len.values():
                    for dev_id in ids:
                        self._fail(self.devices[dev_id].kind, dev_id, exc, out)
        for dev_id in [d for d, q in quats.items() if not np.isfinite(q).all()]:
            del quats[dev_id]
            self._fail(self.devices[dev_id].kind, dev_id, None, out)
        return quats

    def _fail(self, kind: str, device_id: str, exc: Exception | None, out: Output) -> None:
        """Record a filter failure and forget the device's fusion state; its next packets start a new warm-up.
        Like a filter change, this also restarts the device's rules state (alarms stay with the engine)."""
        reason = "non_finite" if exc is None else type(exc).__name__
        detail = "non-finite quaternion" if exc is None else str(exc)[:200]
        out.filter_failures.append(FilterFailure(kind, device_id, reason, detail))
        self._warmup.pop(device_id, None)
        if device_id in self.devices:
            self._drop(device_id)
        elif self._batch is not None and device_id in self._batch.device_ids:  # failed half-way through `_device`
            self._batch.remove(device_id)

    def _step_batch(
        self, blocks: dict[str, tuple[FloatArray, FloatArray, FloatArray | None, FloatArray]],
        by_len: dict[int, list[str]],
    ) -> dict[str, FloatArray]:  # fmt: skip
        quats: dict[str, FloatArray] = {}
        batch = self._batch
        for n, ids in by_len.items():
            n_dev = len(batch)
            gyr_a, acc_a, mag_a = np.zeros((n_dev, n, 3)), np.zeros((n_dev, n, 3)), np.zeros((n_dev, n, 3))
            active = np.zeros(n_dev, dtype=np.bool_)
            rows = [batch.row(d) for d in ids]
            for d, r in zip(ids, rows, strict=True):
                gyr, acc, mag, _ = blocks[d]
                gyr_a[r], acc_a[r] = gyr, acc
                if mag is not None:
                    mag_a[r] = mag
                active[r] = True
            q_all = batch.step(gyr_a, acc_a, mag_a, active)
            for d, r in zip(ids, rows, strict=True):
                quats[d] = q_all[r]
        return quats

    def _attitude_blocks(
        self, dev: ImuDevice, q: FloatArray, pkts: list[schemas.ImuPacket]
    ) -> list[schemas.AttitudeBlock]:
        """Every sample's attitude, one AttitudeBlock per packet (`q` holds the packets' samples in order)."""
        out, start = [], 0
        for p in pkts:
            rows = q[start : start + p.n].tolist()
            start += p.n
            out.append(schemas.AttitudeBlock(
                device_id=dev.device_id, kind=dev.kind, boot_id=p.boot_id, seq=p.seq,  # type: ignore[arg-type]
                t0_us=p.t0_us, rate_hz=p.rate_hz, wall_t0_us=p.t0_us + dev.wall_offset_us,
                quat_wxyz=[tuple(r) for r in rows], filter=dev.filter_name,
            ))  # fmt: skip
        return out

    def _post(
        self,
        dev: ImuDevice,
        q: FloatArray,
        block: tuple[FloatArray, FloatArray, FloatArray | None, FloatArray],
        ends: list[tuple[int, int, int]],
        now: float,
        out: Output,
        conds: list[_Timed],
    ) -> None:
        """Euler, outputs at packet ends (decimated), device rules; conditions get wall times (the engine and store
        work in wall time), their device times go along for the wire."""
        _, acc, _, t_s = block
        eul = to_euler(q)
        yaw_u, dev.yaw_turns = _unwrap(dev.yaw_last, dev.yaw_turns, eul[:, 2])
        dev.yaw_last = float(eul[-1, 2])
        dev.quat, dev.euler, dev.yaw_unwrapped = q[-1].copy(), eul[-1].copy(), float(yaw_u[-1])
        offset_s = dev.wall_offset_us * 1e-6
        for i, seq, t_us in ends:
            if t_s[i] - dev.last_attitude_t_s < self.settings.attitude_interval_s - 1e-9:
                continue
            dev.last_attitude_t_s = float(t_s[i])
            out.attitudes.append(schemas.Attitude(
                device_id=dev.device_id, kind=dev.kind, seq=seq, t_us=t_us,  # type: ignore[arg-type]
                wall_t_us=t_us + dev.wall_offset_us, quat_wxyz=tuple(float(x) for x in q[i]),  # type: ignore[arg-type]
                roll_rad=float(eul[i, 0]), pitch_rad=float(eul[i, 1]), yaw_rad=float(eul[i, 2]),
                yaw_unwrapped_rad=float(yaw_u[i]), filter=dev.filter_name,
            ))  # fmt: skip
        new: list[Condition] = []
        if dev.rod is not None:
            acc_up = tip_acc_up(q, acc)
            tension = None
            reel = self.reel.get(dev.device_id)
            if reel is not None and reel[0].tension_n is not None and now - reel[1] <= self.settings.reel_max_age_s:
                tension = np.full(t_s.shape, reel[0].tension_n)
            # The rod rules decide sample by sample: a burst gives the same alarms in one call as packet by packet.
            rod_block, new = dev.rod.update(t_s, eul[:, 1], eul[:, 0], eul[:, 2], acc_up, tension)
            dev.baseline_rad = rod_block.baseline_rad
            if dev.auto_reel is not None:
                self._auto_reel(dev, float(t_s[-1]), float(eul[-1, 1]), reel[0] if reel else None, now, out)
        elif dev.hook is not None:
            if dev.rest_heading_rad is None:
                dev.rest_heading_rad = float(hook_geo.twist_heading(q[0]))
            swing = hook_geo.swing_angle(q)
            ref = dev.rest_heading_rad if dev.rest_heading_set_rad is None else dev.rest_heading_set_rad
            tors = hook_geo.torsion(q, ref)
            new = dev.hook.update(t_s, swing, tors)
            rope = getattr(dev.filt, "rope_length_m", None)  # the hook filter's estimate at the batch's end
            for i, seq, t_us in ends:
                if t_s[i] - dev.last_swing_t_s < self.settings.swing_interval_s - 1e-9:
                    continue
                dev.last_swing_t_s = float(t_s[i])
                dev.swing = schemas.Swing(
                    device_id=dev.device_id, seq=seq, t_us=t_us, wall_t_us=t_us + dev.wall_offset_us,
                    swing_angle_rad=float(swing[i]), swing_direction_rad=float(hook_geo.displacement_bearing(q[i])),
                    torsion_rad=float(tors[i]), swing_phi_rad=float(hook_geo.swing_direction_paper(q[i], ref)),
                    rest_heading_rad=math.remainder(ref, 2.0 * math.pi),
                    rope_length_m=None if rope is None else float(rope),
                )  # fmt: skip
                out.swings.append(dev.swing)
        for cond in new:
            t_us = int(round(cond.t_s * 1e6))
            src = t_us + dev.wall_offset_us if dev.wall_from_device else None
            conds.append((dev.kind, t_us, src, replace(cond, t_s=cond.t_s + offset_s)))

    # -- auto reel ------------------------------------------------------------------------------------------

    def _make_controller(self, dev: ImuDevice) -> Any:
        cls = _controller_class()
        if cls is None:
            return None
        from gateway.control.fish_walking import FishWalkingSettings

        _, th = self.effective("rod", dev.device_id)
        assert isinstance(th, RodThresholds)
        s = FishWalkingSettings(theta2_rad=math.radians(th.line_switch_deg), theta3_rad=math.radians(th.line_limit_deg),
                                line_breaking_n=th.line_breaking_n)  # fmt: skip
        return cls(s)

    def _auto_reel(
        self, dev: ImuDevice, t_s: float, pitch: float, reel: schemas.ReelStatus | None, now: float, out: Output
    ) -> None:
        """Step the controller on a fused block's last sample (device time `t_s`); send the command if it changed."""
        from gateway.control.fish_walking import Observation

        t_step = t_s
        if t_s <= dev.reel_step_t_s:
            if dev.reel_step_t_s - t_s > dev.auto_reel.settings.attitude_timeout_s:  # device clock restarted (reboot)
                dev.auto_reel.enable()
            else:  # a watchdog step's estimate ran ahead of this late sample: keep the controller's time moving on
                t_step = dev.reel_step_t_s + 1e-3
        obs = Observation(t_s, pitch - dev.baseline_rad, None, reel.tension_n if reel else None,
                          reel.line_out_m if reel else None)  # fmt: skip
        decision = dev.auto_reel.step(t_step, obs)
        dev.reel_step_t_s = t_step
        w = self._watch(dev.device_id, now)
        w.since_s, w.device_t_s = now, t_s
        self._reel_send(dev.device_id, w, decision.command_fields(), decision.reason, now, out)

    def tick_reel(self, now_wall_s: float) -> Output:
        """Reel watchdog tick, at gateway wall time (the clock `process` gets); the service calls it every
        `reel_watchdog_s`. Each rod in auto mode whose newest data is older than `reel_watchdog_s` has its controller
        stepped with no new observation at device time t = (device time of the newest sample it got) + (gateway
        time elapsed since that sample was processed). Only elapsed gateway time enters, so the device's clock
        offset and the wall clocks' skew do not; the sample's transport delay is not counted (the stop comes that
        much later than `attitude_timeout_s` after the sample was taken, but never before it). Once no fresh data
        came for the controller's timeout, its decision is `stop` (with the drag), sent once more and logged as
        `reel_data_lost`. A rod in auto without a running controller (no data since auto went on or since the
        gateway started, or its filter restarting) gets a plain stop once that timeout has passed."""
        out = Output()
        for dev_id in [d for d, on in self.auto_reel.items() if on]:
            w = self._watch(dev_id, now_wall_s)
            if now_wall_s - w.since_s < self.settings.reel_watchdog_s:  # fresh: the packets step the controller
                continue
            dev = self.devices.get(dev_id)
            ctrl = dev.auto_reel if dev is not None else None
            if dev is not None and ctrl is not None and w.device_t_s is not None:
                t = w.device_t_s + (now_wall_s - w.since_s)
                if t <= dev.reel_step_t_s:
                    continue
                decision = ctrl.step(t, None)
                dev.reel_step_t_s = t
                self._reel_send(dev_id, w, decision.command_fields(), decision.reason, now_wall_s, out)
            elif now_wall_s - w.since_s > _reel_timeout_s():
                self._reel_send(dev_id, w, {"action": "stop"}, "timeout", now_wall_s, out)
        return out

    def reel_offline(self, device_id: str, now_wall_s: float) -> Output:
        """The rod's liveliness token vanished: if it is in auto mode, stop its reel and log `reel_offline`. Auto
        stays on; fresh data after a reconnect restarts the controller as after a data timeout."""
        out = Output()
        if self.auto_reel.get(device_id):
            w = self._watch(device_id, now_wall_s)
            w.fields, w.lost = {"action": "stop"}, True
            out.reel_commands.append((device_id, w.fields))
            out.reel_events.append(ReelEvent(device_id, "reel_offline", now_wall_s, {"command": w.fields}))
        return out

    def _watch(self, device_id: str, now: float) -> ReelWatch:
        w = self._reel_watch.get(device_id)
        if w is None:
            w = self._reel_watch[device_id] = ReelWatch(now)
        return w

    def _reel_send(
        self, device_id: str, w: ReelWatch, fields: dict[str, Any], reason: str, now: float, out: Output
    ) -> None:
        """Queue `fields` if they changed; a data-lost stop is always sent (and logged) the first time."""
        lost = reason == "timeout" and not w.lost
        w.lost = reason == "timeout"
        if lost:
            out.reel_events.append(ReelEvent(device_id, "reel_data_lost", now,
                                             {"data_age_s": round(now - w.since_s, 3), "command": fields}))  # fmt: skip
        if lost or fields != w.fields:
            w.fields = fields
            out.reel_commands.append((device_id, fields))

    # -- views ----------------------------------------------------------------------------------------------

    def rank_spots(self, now: float) -> schemas.SpotRanking:
        """Spots best first, from the latest reading at each spot (the newest ball wins a shared spot)."""
        latest: dict[str, schemas.EnvPacket] = {}
        for p in self.env.values():
            cur = latest.get(p.spot)
            if cur is None or (p.wall_t_us or 0) >= (cur.wall_t_us or 0):
                latest[p.spot] = p
        readings = [
            SpotReading(spot, p.water_temp_c, p.oxygen_mg_l, p.light_lux, p.probe_depth_m, _thermocline_m(p.profile))
            for spot, p in latest.items()
        ]
        prefs = self.defaults["ball"]
        assert isinstance(prefs, SpotPreferences)
        lt = time.localtime(now)
        ranked = rank_spots(readings, prefs, lt.tm_hour + lt.tm_min / 60.0)
        spots = [
            schemas.SpotScore(
                spot=s.spot_id, rank=i + 1, score=min(1.0, max(0.0, s.score)),
                device_id=latest[s.spot_id].device_id, last_seen_wall_us=latest[s.spot_id].wall_t_us,
                reasons=[r[:200] for r in s.reasons][:20], **_position(latest[s.spot_id].gnss),
            )
            for i, s in enumerate(ranked)
        ]  # fmt: skip
        return schemas.SpotRanking(wall_t_us=int(now * 1e6), spots=spots)

    def bias_rad_s(self, device_id: str) -> list[float] | None:
        """The filter's gyro bias estimate, rad/s, when the filter has one (REST views)."""
        dev = self.devices.get(device_id)
        bias = None if dev is None else self._bias(dev)
        return None if bias is None else [float(x) for x in bias]

    def _bias(self, dev: ImuDevice) -> FloatArray | None:
        """The device filter's gyro bias estimate (3,), rad/s, or None; a view, no copy (per-block use)."""
        if dev.filt is None:
            from gateway.fusion import _default_kernels as K

            assert self._batch is not None
            return np.asarray(self._batch.states[self._batch.row(dev.device_id), K.S_BIAS : K.S_BIAS + 3], dtype=float)
        for attr in ("bias_rad_s", "gyro_bias_rad_s"):
            b = getattr(dev.filt, attr, None)
            if b is not None:
                return np.asarray(b, dtype=float)
        return None


def _make_filter(name: str, use_mag: bool, rope_length_m: float | None = None) -> AttitudeFilter:
    """A filter by name: the hook EKF (on a rope of `rope_length_m`, else its default), else the registry
    (KeyError when unknown)."""
    from gateway.fusion import registry

    if name == HOOK_FILTER:
        from gateway.fusion.hook_filter import HookFilter, HookFilterSettings

        # The hook setting's length (configured, or the 10 m default) is a prior the pendulum frequency corrects: a
        # wrong one is found within seconds of swinging, while a wide prior would let a trolley jerk read as a rope.
        settings = HookFilterSettings() if rope_length_m is None else HookFilterSettings(
            rope_length_m=rope_length_m, rope_length_known=True)
        return HookFilter(settings, use_mag=use_mag)
    if name in registry.FILTERS:
        return registry.make_filter(name, use_mag=use_mag)
    raise KeyError(name)


def _reel_timeout_s() -> float:
    """The fish-walking controller's data timeout, s (its default; 0.3 s when the module is missing)."""
    try:
        from gateway.control.fish_walking import FishWalkingSettings
    except ImportError:
        return 0.3
    return FishWalkingSettings().attitude_timeout_s


def _controller_class() -> Any:
    """The fish-walking controller class, or None when gateway.control.fish_walking is missing."""
    try:
        from gateway.control.fish_walking import FishWalkingController
    except ImportError:
        return None
    return FishWalkingController
