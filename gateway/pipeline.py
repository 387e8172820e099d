"""The gateway's per-device processing behind one facade, pure (no I/O, no clock reads): decoded packets in,
results out; the hub fans them out.

One `Pipeline.process(packets, now_wall_s)` call takes a whole drained batch:

1. Packets are dispatched by type: IMU packets are grouped per device, any other packet goes to the handler of
   its kind (`gateway.kinds`: reel status -> rod, environment readings -> ball).
2. Fusion (`gateway.fusion.bank.FusionBank`): warm-up, filters (the default filter of every device in one batched
   numba call), calibration and restart-on-failure.
3. Per kind, over the concatenated blocks of all its devices: Euler angles, unwrapped yaw and Attitude messages
   (`gateway.kinds.base.KindBatch`), then the kind's own logic (`DeviceKind.post`: rod rules and auto reel, hook
   angles and rules), height/heave per device.
4. Rule conditions go through one `AlarmEngine` (lifecycle: raised / updated / cleared), with times converted
   from device time to wall time using the packet's `wall_t0_us` (else the arrival time).

Configuration (kind defaults + per-device overrides) is merged in one place, `gateway.config.effective_settings`;
auto reel and its watchdog are `gateway.control.auto_reel.AutoReel`'s. Outputs are decimated: attitude at most
every `attitude_interval_s` per device (the last sample of a packet), swing once per packet at most every
`swing_interval_s`, spot ranking at most every `spots_interval_s`.
"""

from __future__ import annotations

import time
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np
from pydantic import ValidationError

from gateway import schemas
from gateway.alarm import bite_fast
from gateway.alarm.engine import Alarm, AlarmEngine, Condition
from gateway.alarm.rules import SPECS
from gateway.config import DeviceSettings, RodThresholds, ThresholdModel, effective_settings, merge_thresholds
from gateway.control.auto_reel import AutoReel, controller_class
from gateway.errors import BadSettings
from gateway.fusion.bank import DEFAULT_FILTER, HOOK_FILTER, FusionBank, known_filters
from gateway.fusion.base import FloatArray
from gateway.fusion.heave import HeaveEstimator, heave_run_segments
from gateway.kinds import KINDS, KindRow, KindServices
from gateway.kinds.ball import BallKind
from gateway.kinds.base import (
    AlarmOut,
    DeviceKind,
    FilterFailure,
    Fused,
    FusedDevice,
    HeaveStates,
    KindBatch,
    KindContext,
    Output,
    ReelEvent,
    Timed,
    attitude_blocks,
    attitudes,
    heave_rows,
    height_messages,
    heights,
    heights_batch,
)
from gateway.kinds.rod import RodKind

__all__ = ["AlarmOut", "FilterFailure", "Output", "Pipeline", "PipelineSettings", "ReelEvent", "DEFAULT_FILTER",
           "HOOK_FILTER", "FusedDevice"]  # fmt: skip



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


def _unwrap(prev_wrapped: float, turns: int, yaw: FloatArray) -> tuple[FloatArray, int]:
    """Continuous yaw of one block, continuing from the previous wrapped sample and turn count (one device's
    `gateway.kinds.base.unwrap_segments`)."""
    from gateway.kinds.base import unwrap_segments

    yaw = np.asarray(yaw, dtype=np.float64)
    u, t = unwrap_segments(yaw, np.array([0]), np.array([prev_wrapped]), np.array([turns]))
    return u, int(t[0])


class Pipeline:
    """All per-device state of the gateway behind the methods the runner and REST call. Not thread-safe: one owner
    calls it. `kinds` (device id -> wire kind), `devices` (running fused devices), `defaults`, `device_settings`,
    `auto_reel`, `env`, `reel` and `engine` are its read views."""

    def __init__(
        self,
        settings: PipelineSettings | None = None,
        defaults: Mapping[str, ThresholdModel] | None = None,
        device_settings: Mapping[str, tuple[str, DeviceSettings]] | None = None,
        active_alarms: Iterable[Alarm] = (),
        kinds: Sequence[KindRow] = KINDS,
    ) -> None:
        self.settings = s = settings or PipelineSettings()
        self.device_settings: dict[str, tuple[str, DeviceSettings]] = dict(device_settings or {})
        self.reel_control = AutoReel(s.reel_watchdog_s, self._rod_thresholds,
                                     {d for d, (_, ds) in self.device_settings.items() if ds.auto_reel})  # fmt: skip
        services = KindServices(self.reel_control)
        self.handlers: dict[str, DeviceKind] = {row.name: row.make(services) for row in kinds}
        self._by_packet = {t: h for h in self.handlers.values() for t in h.packet_types}
        self.defaults: dict[str, ThresholdModel] = {k: h.thresholds_model()() for k, h in self.handlers.items()}  # type: ignore[misc]
        self.defaults.update(defaults or {})
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
        self.kinds: dict[str, str] = {d: k for d, (k, _) in self.device_settings.items()}  # every device seen or set
        self.bank = FusionBank(
            warmup_s=s.warmup_s, rest_gyr_std_rad_s=s.rest_gyr_std_rad_s, rest_acc_tol_m_s2=s.rest_acc_tol_m_s2,
            warmup_bias_seed=s.warmup_bias_seed, effective=self.effective,
            filter_options=lambda kind, th: self.handlers[kind].filter_options(th),
            new_state=lambda dev, th: self.handlers[dev.kind].new_state(self._ctx, dev, th),
            on_drop=self.reel_control.forget,
            bridge_kinds={name for name, h in self.handlers.items() if h.bridge_lost_samples},
            gyro_taper_s={name: h.bridge_gyro_taper_s for name, h in self.handlers.items()},
            filter_inputs=lambda dev, wall_end_s, n, dt_s: self.handlers[dev.kind].filter_inputs(
                dev.device_id, wall_end_s, n, dt_s),
        )  # fmt: skip
        for d, (_, ds) in self.device_settings.items():
            if ds.calibration is not None:
                self.bank.set_calibration(d, ds.calibration)
        self._dropped = 0  # `bank.dropped` when the batch's devices were fused
        self.heave_states = HeaveStates()  # every IMU device's heave state, a row each (`heave_rows`)
        self._ctx = KindContext(s, lambda kind, dev_id: self.effective(kind, dev_id)[1], self._post_failed)
        self.taker: Callable[[schemas.Topic], Callable[[str, str], bool] | None] | None = None
        """Per batch, whether anyone takes a device's messages of a topic now (the composition root sets
        `Hub.taker`): the heights nobody takes are not made (their values stay on the device for REST). None, or
        None from it: every one is made."""

    def _height_taker(self) -> Callable[[FusedDevice], bool] | None:
        takes = None if self.taker is None else self.taker(schemas.T_HEIGHT)
        return None if takes is None else lambda dev: takes(dev.kind, dev.device_id)

    # -- read views -----------------------------------------------------------------------------------------

    @property
    def devices(self) -> dict[str, FusedDevice]:
        return self.bank.devices

    @property
    def auto_reel(self) -> dict[str, bool]:
        """Rod id -> True for the rods in auto (fish-walking) mode."""
        return self.reel_control.on

    @property
    def env(self) -> dict[str, schemas.EnvPacket]:
        """Ball id -> latest environment reading."""
        return self._ball.env

    @property
    def reel(self) -> dict[str, tuple[schemas.ReelStatus, float]]:
        """Rod id -> (latest reel status, arrival wall s)."""
        return self._rod.reel

    @property
    def _batch(self) -> Any:
        return self.bank.batch

    @property
    def _rod(self) -> RodKind:
        h = self.handlers["rod"]
        assert isinstance(h, RodKind)
        return h

    @property
    def _ball(self) -> BallKind:
        h = self.handlers["ball"]
        assert isinstance(h, BallKind)
        return h

    # -- configuration --------------------------------------------------------------------------------------

    def effective(self, kind: str, device_id: str | None = None) -> tuple[str, ThresholdModel]:
        """(filter name, thresholds) of a device: kind defaults with its override merged on top."""
        entry = self.device_settings.get(device_id) if device_id is not None else None
        return effective_settings(kind, None if entry is None else entry[1],
                                  self.handlers[kind].default_filter(self.settings), self.defaults[kind])  # fmt: skip

    def _rod_thresholds(self, device_id: str) -> RodThresholds:
        th = self.effective("rod", device_id)[1]
        assert isinstance(th, RodThresholds)
        return th

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
        errors = []
        known = known_filters()
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
            self.bank.set_calibration(device_id, ds.calibration)
        self.device_settings[device_id] = (kind, ds)
        self.kinds[device_id] = kind
        if ds.auto_reel != self.auto_reel.get(device_id, False):
            self.reel_control.switch(device_id, ds.auto_reel, device_id in self.devices)
        dev = self.devices.get(device_id)
        if dev is not None:
            if recalibrated or self.effective(kind, device_id)[0] != dev.filter_name:
                self.bank.drop(device_id)
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
            self.reel_control.switch(device_id, on, device_id in self.devices)
        return not on or controller_class() is not None

    def _apply(self, dev: FusedDevice) -> None:
        _, th = self.effective(dev.kind, dev.device_id)
        if not self.handlers[dev.kind].apply(self._ctx, dev, th):
            self.bank.drop(dev.device_id)

    def restart(self, device_id: str) -> None:
        """Forget a device's fusion and rules state (its next packets start a new warm-up), e.g. when its clock
        jumped to a new timeline. Alarms stay with the engine; settings stay."""
        self.bank.restart(device_id)

    def warm_up(self) -> None:
        """Compile the numba kernels (default batch filter, hook filter, heave) on dummy data, leaving no state behind.

        Called once at start-up: a first compile can take tens of seconds on a busy machine, and done on the first
        packet it would stall ingest (and delay every alarm) for that long."""
        self.bank.warm_up({self.settings.hook_filter, self.settings.default_filter})
        bite_fast.warm_up()  # the rods' bite detector
        if self.settings.height_interval_s > 0:
            n, acc = 5, np.array([0.0, 0.0, 9.80665])
            q, gyr, accs = np.tile([1.0, 0, 0, 0], (n, 1)), np.zeros((n, 3)), np.tile(acc, (n, 1))
            h = HeaveEstimator()
            h.update(q, gyr, accs, 0.01)
            heave_run_segments(h.state[None].copy(), q, gyr, accs, np.zeros(0), np.array([0]), np.array([n]),
                               np.array([0.01]), h.params[None].copy())  # fmt: skip

    # -- processing -----------------------------------------------------------------------------------------

    def process(self, packets: Iterable[schemas.Packet], now_wall_s: float | None = None) -> Output:
        """Run one drained batch of decoded, sequence-checked packets (in arrival order)."""
        now = time.time() if now_wall_s is None else now_wall_s
        out = Output()
        imu: dict[str, list[schemas.ImuPacket]] = {}
        for p in packets:
            if isinstance(p, schemas.ImuPacket):
                imu.setdefault(p.device_id, []).append(p)
                self.kinds[p.device_id] = p.kind
                continue
            handler, device_id = self._by_packet.get(type(p)), getattr(p, "device_id", None)
            if handler is not None and isinstance(device_id, str):
                if handler.fused:  # e.g. a rod's reel status: its IMU packets tell the kind
                    self.kinds.setdefault(device_id, handler.name)
                else:
                    self.kinds[device_id] = handler.name
                handler.on_packet(self._ctx, p, now)
        conditions: list[Timed] = []
        if imu:
            self._fuse(imu, now, out, conditions)
        if self._resumed:
            self._settle_resumed(conditions, now)
        for kind, t_us, src_us, c in conditions:
            out.alarms += [AlarmOut(kind, change, t_us, src_us) for change in self.engine.evaluate([c])]
        for h in self.handlers.values():
            h.end_batch(self._ctx, now, out)
        return out

    def _fuse(self, imu: dict[str, list[schemas.ImuPacket]], now: float, out: Output, conds: list[Timed]) -> None:
        fused = self.bank.fuse(imu, now, out)
        self._dropped = self.bank.dropped  # `_imu_outputs`: a device dropped since (failed in post) is left out
        by_kind: dict[str, list[Fused]] = {}
        for f in fused:
            by_kind.setdefault(f.dev.kind, []).append(f)
        s = self.settings
        for kind, items in by_kind.items():
            handler = self.handlers.get(kind)
            if handler is None:  # no row for this kind: its devices fuse, no kind logic
                continue
            try:
                kb = KindBatch(items)
                if handler.imu_outputs:
                    out.attitudes += attitudes(kb, s.attitude_interval_s)
                conds += handler.post(self._ctx, kb, now, out)
            except Exception as exc:  # a bug in the vectorised part: every device of the kind restarts
                for f in items:
                    self._post_failed(f.dev, exc, out)
                continue
            if handler.imu_outputs:
                self._imu_outputs(kb, out)

    def _imu_outputs(self, kb: KindBatch, out: Output) -> None:
        """Heights (one heave kernel call for all devices of the kind) and attitude blocks of the devices whose
        post succeeded; a failure costs only its device (a kernel failure: every device tries alone)."""
        s = self.settings
        live = (list(range(len(kb.items))) if self.bank.dropped == self._dropped else  # none failed in post
                [i for i, f in enumerate(kb.items) if self.devices.get(f.dev.device_id) is f.dev])  # fmt: skip
        rows: FloatArray | None = None
        if s.height_interval_s > 0 and live:
            try:
                rows = heave_rows(kb, live, self.bank.biases([kb.items[i].dev for i in live]), s.rest_acc_tol_m_s2,
                                  self.heave_states)  # fmt: skip
            except Exception:
                rows = None
        batch = None
        if rows is not None and live:
            try:
                batch = heights_batch(kb, live, rows, s.height_interval_s, self._height_taker())
            except Exception:  # then device by device: a failure costs only its device
                batch = None
        if batch is not None:  # every value passed the batch check: only the attitude blocks are per device
            out.heights += batch
        if not (s.attitude_blocks or s.height_interval_s > 0 and batch is None):
            return  # nothing per device left
        for i in live:
            f = kb.items[i]
            try:
                if s.height_interval_s > 0 and batch is None:
                    out.heights += (height_messages(f, rows[kb.rows(i)], s.height_interval_s) if rows is not None
                                    else heights(f, self.bank.bias(f.dev), s.height_interval_s,
                                                 s.rest_acc_tol_m_s2))  # fmt: skip
                if s.attitude_blocks:
                    out.attitude_blocks += attitude_blocks(f)
            except Exception as exc:  # e.g. an output time out of range: only this device restarts
                self._post_failed(f.dev, exc, out)

    def _post_failed(self, dev: FusedDevice, exc: Exception, out: Output) -> None:
        if self.devices.get(dev.device_id) is dev:
            self.bank.fail(dev.kind, dev.device_id, exc, out)

    def _settle_resumed(self, conditions: list[Timed], now: float) -> None:
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

    # -- auto reel ------------------------------------------------------------------------------------------

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
        return self.reel_control.tick(now_wall_s)

    def reel_offline(self, device_id: str, now_wall_s: float) -> Output:
        """The rod's liveliness token vanished: if it is in auto mode, stop its reel and log `reel_offline`. Auto
        stays on; fresh data after a reconnect restarts the controller as after a data timeout."""
        return self.reel_control.offline(device_id, now_wall_s)

    # -- views ----------------------------------------------------------------------------------------------

    def rank_spots(self, now: float) -> schemas.SpotRanking:
        """Spots best first, from the latest reading at each spot (the newest ball wins a shared spot)."""
        prefs = self.defaults["ball"]
        return self._ball.rank(now, prefs)  # type: ignore[arg-type]

    def bias_rad_s(self, device_id: str) -> list[float] | None:
        """The filter's gyro bias estimate, rad/s, when the filter has one (REST views)."""
        dev = self.devices.get(device_id)
        bias = None if dev is None else self.bank.bias(dev)
        return None if bias is None else [float(x) for x in bias]
