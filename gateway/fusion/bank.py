"""The fusion bank: every IMU device's attitude filter, from warm-up to restart-on-failure.

* Warm-up: a new device's packets are collected until `warmup_s` of samples arrived; its filter then starts from
  the window's mean acc (+ mag), and when the window was at rest its mean gyro seeds the bias estimate.
* Filter factory: the default filter is a row of one `DefaultFilterBatch` (all such devices stepped by one numba
  call per distinct block length); any other name (the hook EKF, a registry filter) is an object per device.
* Batching: `fuse` takes one drained batch (packets grouped per device), gathers every device's samples into shared
  arrays in one conversion (`gather_batch`), applies calibrations and steps all filters; the default-filter rows,
  the gap check and the finiteness check take those arrays with one numpy call per batch, not one per device.
* Lost packets: for the kinds in `bridge_kinds`, a device's samples that never arrived (a gap in device time up to
  `gaps.MAX_BRIDGE_S`) are interpolated for its filter only, so its state crosses the gap in time; every output
  stays on its own samples.
* Restart on failure: a filter that raises or returns a non-finite quaternion fails alone: `out.filter_failures`
  gets a record and the device starts a fresh warm-up with its next packets.

Kind-specific parts come in as callables from the pipeline (the thresholds and filter options of a device, its
kind state), so the bank knows no kind.
"""

from __future__ import annotations

import logging
import math
from collections.abc import Callable, Iterable, Sequence
from itertools import chain, pairwise
from typing import Any, NamedTuple

import numpy as np

from gateway import schemas
from gateway.calibrate import DeviceCalibration
from gateway.fusion import _default_kernels as K
from gateway.fusion.base import AttitudeFilter, FloatArray
from gateway.fusion.batch import DefaultFilterBatch
from gateway.fusion.gaps import (
    BRIDGE_AVERAGE_S,
    COAST_MIN_S,
    MAX_BRIDGE_S,
    bridge_block,
    coast_mask,
    gap_tol_s,
    has_gap,
    has_gaps,
)
from gateway.kinds.base import Ends, FilterFailure, Fused, FusedDevice, Output

log = logging.getLogger("gateway.fusion.bank")

G_M_S2 = 9.80665
DEFAULT_FILTER = "default"
HOOK_FILTER = "hook"
# The hook EKF without the magnetometer: for a compass it cannot trust (uncalibrated, or a steel load or hook block
# beside it), which misleads the 9D filter's twist and with it the swing (docs/fusion.md, "A compass the hook filter
# cannot trust"). Heading, bearing and torsion are then relative to the start.
HOOK_FILTER_6D = "hook-6d"
COMPASS_FREE = frozenset({HOOK_FILTER_6D})  # filters that never get the magnetometer, whatever the device sends

Block = tuple[FloatArray, FloatArray, FloatArray | None, FloatArray]  # gyr, acc, mag (None: 6D), t_s


def make_filter(name: str, use_mag: bool, rope_length_m: float | None = None,
                imu_offset_m: tuple[float, float, float] | None = None,
                imu_tilt_deg: tuple[float, float] | None = None,
                acc_bias_xy_m_s2: tuple[float, float] | None = None) -> AttitudeFilter:
    """A filter by name: the hook EKF (on a rope of `rope_length_m`, else its default; its IMU at `imu_offset_m`
    from the rope axis, else its default, and tilted on the hook by `imu_tilt_deg`, else square; its accelerometer's
    x/y offset `acc_bias_xy_m_s2` as measured, else not), else the registry (KeyError when unknown)."""
    from gateway.fusion import registry

    if name in (HOOK_FILTER, HOOK_FILTER_6D):
        from gateway.fusion.hook_filter import HookFilter, HookFilterSettings

        # A configured length is a prior (15 %): a measured rope must not let a trolley jerk read as another
        # length. None (nobody configured one): the filter's wide prior from 10 m, found from the pendulum frequency;
        # telling it 10 m instead diverged on short ropes (fresh crane 1692, 2.3 m: Θ RMSE 68.7° against 1.24°).
        settings = HookFilterSettings() if rope_length_m is None else HookFilterSettings(
            rope_length_m=rope_length_m, rope_length_known=True)
        settings = settings.with_imu_offset(imu_offset_m).with_imu_tilt(imu_tilt_deg).with_acc_bias(acc_bias_xy_m_s2)
        filt = HookFilter(settings, use_mag=use_mag and name not in COMPASS_FREE)
        if imu_tilt_deg is None:
            return filt
        from gateway.fusion.hook_mount import TiltedHookFilter

        return TiltedHookFilter(filt, [math.radians(a) for a in imu_tilt_deg])  # type: ignore[return-value]
    if name in registry.FILTERS:
        return registry.make_filter(name, use_mag=use_mag)
    raise KeyError(name)


def known_filters() -> set[str]:
    """Every filter name a device may choose."""
    from gateway.fusion.registry import FILTERS

    return {DEFAULT_FILTER, HOOK_FILTER, HOOK_FILTER_6D, *FILTERS}


def gather(pkts: list[schemas.ImuPacket]) -> Block:
    """One device's packets as arrays (mag None unless every packet has it); sample times in device seconds."""
    gyr = np.array([s for p in pkts for s in p.gyr_rad_s], dtype=np.float64)
    acc = np.array([s for p in pkts for s in p.acc_m_s2], dtype=np.float64)
    has_mag = all(p.has_mag for p in pkts)
    mag = np.array([s for p in pkts for s in p.mag_uT or ()], dtype=np.float64) if has_mag else None
    t_s = np.concatenate([p.t0_us * 1e-6 + np.arange(p.n) / p.rate_hz for p in pkts])
    return gyr, acc, mag, t_s


def _rows3(blocks: Iterable[Sequence[tuple[float, float, float]]], rows: int) -> FloatArray:
    """(rows, 3) float64 of the packets' sample triples, concatenated: one pass over the floats (`np.fromiter`),
    half the time of `np.array` on a list of tuples; raises ValueError when the count is not `rows`."""
    flat = np.fromiter(chain.from_iterable(chain.from_iterable(blocks)), dtype=np.float64, count=3 * rows)
    return flat.reshape(rows, 3)


class Gathered(NamedTuple):
    """Many devices' samples in shared arrays (device i: rows `start[i]:stop[i]`) and their packets' ends: what
    the bank steps a whole batch from with one numpy operation per sensor, where a loop per device cost ~µs each."""

    gyr: FloatArray  # (N, 3) rad/s, C-contiguous
    acc: FloatArray  # (N, 3) m/s², C-contiguous
    mag: FloatArray | None  # (N, 3) µT (None: no device has it); rows of a device without it in every packet unused
    has_mag: list[bool]  # per device: every packet brought a magnetometer
    t_s: FloatArray  # (N,) device time, s
    start: list[int]  # per device: its first row
    stop: list[int]  # per device: one past its last row
    ends: list[Ends]  # per device: (last sample's index in its block, seq, device t_us of that sample) per packet

    def block(self, i: int) -> Block:
        """Device i's (gyr, acc, mag or None, t_s): views of the shared arrays."""
        a, b = self.start[i], self.stop[i]
        mag = self.mag[a:b] if self.has_mag[i] and self.mag is not None else None
        return self.gyr[a:b], self.acc[a:b], mag, self.t_s[a:b]


def gather_batch(groups: list[list[schemas.ImuPacket]]) -> Gathered:
    """`gather` of many devices (the same values) with one array conversion per sensor for all of them. Packets
    decoded from the binary encoding bring their float32 rows (`schemas.sample_rows`, their sample tuples are not
    even built): a batch with any is gathered from rows (rows 6 and 9 wide each in one concatenation, the JSON
    packets' tuples made rows one by one), else from the tuples."""
    pk = [p for g in groups for p in g]
    counts = [len(g) for g in groups]  # each at least one packet
    kept = [schemas.sample_rows(p) for p in pk]
    n_list = [p.n if r is None else r.shape[0] for p, r in zip(pk, kept, strict=True)]
    mag_pkt = [p.has_mag for p in pk]
    n = np.array(n_list, dtype=np.int64)
    first_pkt = np.cumsum(counts, dtype=np.int64) - np.array(counts, dtype=np.int64)  # each device's first packet
    stops = np.cumsum(n)
    total = int(stops[-1]) if pk else 0
    dev_stop = stops[first_pkt + counts - 1] if pk else np.zeros(0, dtype=np.int64)
    start, stop = (dev_stop - np.add.reduceat(n, first_pkt)).tolist() if pk else [], dev_stop.tolist()
    has_mag = np.logical_and.reduceat(mag_pkt, first_pkt).tolist() if pk else []
    mag_rows = np.repeat(np.repeat(has_mag, counts), n) if pk else np.zeros(0, dtype=np.bool_)  # per row: taken

    mag: FloatArray | None = None
    if any(r is not None for r in kept):
        rows = [r if r is not None else np.hstack([a for a in p.arrays() if a is not None])  # JSON: [gyr acc (mag)]
                for r, p in zip(kept, pk, strict=True)]  # fmt: skip
        wide = [r.shape[1] == 9 for r in rows]
        if all(wide) or not any(wide):
            whole = np.concatenate(rows, dtype=np.float64)
        else:  # rods 6 wide, hooks 9: each width in one concatenation, put in place by a row mask
            whole = np.zeros((total, 9))
            row_wide = np.repeat(wide, n)
            whole[row_wide] = np.concatenate([r for r, w in zip(rows, wide, strict=True) if w], dtype=np.float64)
            whole[~row_wide, :6] = np.concatenate([r for r, w in zip(rows, wide, strict=True) if not w],
                                                  dtype=np.float64)  # fmt: skip
        gyr, acc = np.ascontiguousarray(whole[:, 0:3]), np.ascontiguousarray(whole[:, 3:6])
        if any(has_mag):
            mag = np.ascontiguousarray(whole[:, 6:9])
    else:
        gyr, acc = _rows3((p.gyr_rad_s for p in pk), total), _rows3((p.acc_m_s2 for p in pk), total)
        if any(has_mag):
            taken = [p for p, m in zip(pk, np.repeat(has_mag, counts).tolist(), strict=True) if m]
            mag = np.zeros((total, 3))
            mag[mag_rows] = _rows3((p.mag_uT or () for p in taken), int(np.count_nonzero(mag_rows)))

    rate = np.array([p.rate_hz for p in pk], dtype=np.float64)
    t0_us = np.array([p.t0_us for p in pk], dtype=np.int64)
    first = np.repeat(stops - n, n)  # each row's packet's first row
    t_s = np.repeat(t0_us * 1e-6, n) + (np.arange(total) - first) / np.repeat(rate, n)
    # packet ends (`round` and `np.rint` both round half to even: the same t_us as the per-packet formula)
    t_end = (t0_us + np.rint((n - 1) * 1e6 / rate).astype(np.int64)).tolist()
    idx = (stops - 1 - np.repeat(np.array(start, dtype=np.int64), counts)).tolist()
    rows_e = list(zip(idx, [p.seq for p in pk], t_end, strict=True))
    ends = [rows_e[a : a + c] for a, c in zip(first_pkt.tolist(), counts, strict=True)]
    return Gathered(gyr, acc, mag, has_mag, t_s, start, stop, ends)


def gather_all(groups: list[list[schemas.ImuPacket]]) -> list[Block]:
    """`gather` of many devices with one array conversion per sensor for all of them (the same values), as
    blocks (`gather_batch` keeps them in shared arrays)."""
    g = gather_batch(groups)
    return [g.block(i) for i in range(len(groups))]


class Shared(NamedTuple):
    """A batch's running devices in shared arrays (`gather_batch`; None when gathering failed) and each one's
    index in them; a device absent from `at` has a block of its own."""

    gathered: Gathered | None
    at: dict[str, int]

    @property
    def ends(self) -> list[Ends]:
        assert self.gathered is not None
        return self.gathered.ends


def packet_ends(groups: list[list[schemas.ImuPacket]]) -> list[Ends]:
    """Per device: (index of the packet's last sample in its block, seq, device t_us of that sample) per packet;
    computed for all devices' packets at once (`round` and `np.rint` both round half to even: the same t_us)."""
    pk = [p for g in groups for p in g]
    n = np.array([p.n for p in pk], dtype=np.int64)
    rate = np.array([p.rate_hz for p in pk], dtype=np.float64)
    t_end = np.array([p.t0_us for p in pk], dtype=np.int64) + np.rint((n - 1) * 1e6 / rate).astype(np.int64)
    counts = [len(g) for g in groups]
    first = np.repeat(np.cumsum(counts) - counts, counts)  # the device's first packet, per packet
    cum = np.cumsum(n)
    idx = cum - (cum[first] - n[first]) - 1  # the last sample's index within the device's block
    rows = list(zip(idx.tolist(), [p.seq for p in pk], t_end.tolist(), strict=True))
    out, at = [], 0
    for c in counts:
        out.append(rows[at : at + c])
        at += c
    return out


class FusionBank:
    """Filters of every IMU device. `devices` holds the running ones; a device in warm-up is not there yet.

    `effective(kind, id)` -> (filter name, thresholds); `filter_options(kind, thresholds)` -> extra filter factory
    arguments; `new_state(dev, thresholds)` -> the kind state of a device that just started; `on_drop(id)` is
    called when a running device is forgotten (restart, failure, settings change)."""

    def __init__(
        self, *, warmup_s: float = 0.5, rest_gyr_std_rad_s: float = 0.01, rest_acc_tol_m_s2: float = 0.5,
        warmup_bias_seed: bool = True, effective: Callable[[str, str], tuple[str, Any]],
        filter_options: Callable[[str, Any], dict[str, Any]], new_state: Callable[[FusedDevice, Any], Any],
        on_drop: Callable[[str], None] = lambda _: None, bridge_kinds: Iterable[str] = (),
        gyro_taper_s: dict[str, float] | None = None,
        filter_inputs: Callable[[FusedDevice, float, int, float], dict[str, FloatArray]] | None = None,
    ) -> None:  # fmt: skip
        self.warmup_s, self.rest_gyr_std_rad_s, self.rest_acc_tol_m_s2 = warmup_s, rest_gyr_std_rad_s, rest_acc_tol_m_s2
        self.warmup_bias_seed = warmup_bias_seed
        self.bridge_kinds = set(bridge_kinds)  # kinds whose lost samples are interpolated for their filter
        self.max_bridge_s = MAX_BRIDGE_S  # longest lost-sample gap interpolated for a filter (0: none, back to back)
        self.bridge_average_s = BRIDGE_AVERAGE_S  # the samples either side of a gap averaged for its line
        self.gyro_taper_s = dict(gyro_taper_s or {})  # per kind: bridged gyro rates tapered (`gaps.taper_inserted`)
        self.coast_min_s = COAST_MIN_S  # gaps this long or longer: a filter with `run_bridged` coasts on its model
        self._effective, self._filter_options, self._new_state, self._on_drop = (effective, filter_options,
                                                                                 new_state, on_drop)  # fmt: skip
        # known inputs of a device's own filter for a block (device, wall time of its last sample s, rows, dt):
        # keyword arguments of its `run` (a hook's crane feed: `tip_enu`); none by default
        self._filter_inputs = filter_inputs
        self.devices: dict[str, FusedDevice] = {}
        self.dropped = 0  # running devices forgotten so far (`drop`): unchanged, every fused device still runs
        self.batch: DefaultFilterBatch | None = None
        self.cal: dict[str, DeviceCalibration] = {}  # per-device IMU calibration (absent: raw values are fused)
        self._warmup: dict[str, list[schemas.ImuPacket]] = {}

    # -- life cycle -----------------------------------------------------------------------------------------

    def set_calibration(self, device_id: str, calibration: dict[str, Any] | None) -> None:
        if calibration is None:
            self.cal.pop(device_id, None)
        else:
            self.cal[device_id] = DeviceCalibration.from_json(calibration)

    def restart(self, device_id: str) -> None:
        """Forget a device's warm-up and fusion state; its next packets start a new warm-up."""
        self._warmup.pop(device_id, None)
        if device_id in self.devices:
            self.drop(device_id)
        elif self.batch is not None and device_id in self.batch.device_ids:  # failed half-way through `_start`
            self.batch.remove(device_id)

    def drop(self, device_id: str) -> None:
        dev = self.devices.pop(device_id)
        self.dropped += 1
        if dev.filt is None and self.batch is not None:
            self.batch.remove(device_id)
        self._on_drop(device_id)

    def fail(self, kind: str, device_id: str, exc: Exception | None, out: Output) -> None:
        """Record a filter failure and forget the device's fusion state (its kind state goes too; alarms stay with
        the engine); its next packets start a new warm-up."""
        reason = "non_finite" if exc is None else type(exc).__name__
        detail = "non-finite quaternion" if exc is None else str(exc)[:200]
        out.filter_failures.append(FilterFailure(kind, device_id, reason, detail))
        self.restart(device_id)

    def warm_up(self, filter_names: set[str]) -> None:
        """Compile the numba kernels (default batch filter and `filter_names`) on dummy data, leaving no state."""
        acc, mag = np.array([0.0, 0.0, G_M_S2]), np.array([0.0, 20.0, -44.0])
        batch = DefaultFilterBatch()
        batch.add("warm-up", dt_s=0.01, acc_m_s2=acc, mag_uT=mag)
        n = 5
        batch.step(np.zeros((1, n, 3)), np.tile(acc, (1, n, 1)), np.tile(mag, (1, n, 1)))
        t_gap = np.array([0.0, 0.01, 0.04])  # two samples lost: the gap kernels (`gaps.bridge_block`)
        bridge_block(np.zeros((3, 3)), np.tile(acc, (3, 1)), None, t_gap, 0.01, None, gyro_taper_s=0.05)
        for name in filter_names - {DEFAULT_FILTER}:
            try:
                f = make_filter(name, True)
            except KeyError:
                continue
            f.initialise(acc, mag)
            step = getattr(f, "update_block", None) or f.run
            step(np.zeros((n, 3)), np.tile(acc, (n, 1)), np.tile(mag, (n, 1)), 0.01)
            getattr(f, "torsion_std_rad", None)  # the hook filter's torsion σ (`_heading_gradient`), compiled too

    def bias(self, dev: FusedDevice) -> FloatArray | None:
        """The device filter's gyro bias estimate (3,), rad/s, or None; a view, no copy (per-block use)."""
        if dev.filt is None:
            assert self.batch is not None
            return np.asarray(self.batch.states[self.batch.row(dev.device_id), K.S_BIAS : K.S_BIAS + 3], dtype=float)
        for attr in ("bias_rad_s", "gyro_bias_rad_s"):
            b = getattr(dev.filt, attr, None)
            if b is not None:
                return np.asarray(b, dtype=float)
        return None

    def biases(self, devs: Sequence[FusedDevice]) -> FloatArray:
        """`bias` of many devices as rows of one (n, 3) array, zeros where a filter has none: the default-filter
        rows read with one index instead of a view per device."""
        out = np.zeros((len(devs), 3))
        at: list[int] = []
        for k, dev in enumerate(devs):
            if dev.filt is None:
                at.append(k)
            elif (b := self.bias(dev)) is not None:
                out[k] = b
        if at:
            assert self.batch is not None
            rows = self.batch.rows([devs[k].device_id for k in at])
            out[at] = self.batch.states[rows, K.S_BIAS : K.S_BIAS + 3]
        return out

    # -- one batch ------------------------------------------------------------------------------------------

    def fuse(self, imu: dict[str, list[schemas.ImuPacket]], now_s: float, out: Output) -> list[Fused]:
        """Step every device with packets in this batch; the fused blocks of the running ones (new devices whose
        warm-up completed included), in stepping order."""
        ready: list[tuple[FusedDevice, list[schemas.ImuPacket]]] = []
        started: dict[str, Block] = {}
        for dev_id, pkts in imu.items():
            dev = self.devices.get(dev_id)
            if dev is not None:
                ready.append((dev, pkts))
                continue
            try:  # warm-up: collect, start the filter once the window is full
                warm = self._warmup.setdefault(dev_id, [])
                warm.extend(pkts)
                if sum(p.n / p.rate_hz for p in warm) < self.warmup_s - 1e-9:  # 10 x 0.05 s is 0.4999…
                    continue
                pkts = self._warmup.pop(dev_id)
                gyr, acc, mag, t_s = gather_all([pkts])[0]
                if (cal := self.cal.get(dev_id)) is not None:  # before `_start` takes the warm-up means
                    acc, mag = cal.apply(acc, mag)
                dev = self._start(pkts[0], gyr, acc, mag)  # a filter that cannot start: counted, warms up again
            except Exception as exc:  # one device's bad data (or a bug it triggers) costs only its own output
                self.fail(pkts[0].kind, dev_id, exc, out)
                continue
            started[dev_id] = (gyr, acc, mag, t_s)
            ready.append((dev, pkts))
        blocks, shared = self._blocks([(d, p) for d, p in ready if d.device_id not in started], out)
        blocks.update(started)
        items: dict[str, tuple[FusedDevice, list[schemas.ImuPacket], Block]] = {}
        ends: dict[str, Ends] = {}
        for dev, pkts in ready:
            dev_id = dev.device_id
            if dev_id not in blocks:
                continue
            gyr, acc, mag, t_s = blocks[dev_id]
            last = pkts[-1]
            if abs(1.0 / last.rate_hz - dev.dt_s) > 1e-12:
                dev.dt_s = 1.0 / last.rate_hz
                if dev.filt is None and self.batch is not None:
                    self.batch.set_dt(dev_id, dev.dt_s)
            e = ends[dev_id] = shared.ends[shared.at[dev_id]] if dev_id in shared.at else packet_ends([pkts])[0]
            seq0 = dev.seq
            dev.follows = ((pkts[0].seq == seq0 + 1,) if len(pkts) == 1 else  # for the gap checks' tolerance
                           tuple(b == a + 1 for a, b in pairwise([seq0, *(p.seq for p in pkts)])))  # fmt: skip
            dev.t_us, dev.seq = e[-1][2], last.seq
            dev.wall_from_device = last.wall_t0_us is not None
            dev.wall_offset_us = (last.wall_t0_us - last.t0_us) if last.wall_t0_us is not None else (
                int(now_s * 1e6) - dev.t_us)  # fmt: skip
            items[dev_id] = (dev, pkts, (gyr, acc, mag if dev.use_mag else None, t_s))
        quats = self._step(items, shared, out)
        return [Fused(dev, q, blk[0], blk[1], blk[3], ends[d], pkts)
                for d, q in quats.items() for dev, pkts, blk in (items[d],)]  # fmt: skip

    def _blocks(self, ready: list[tuple[FusedDevice, list[schemas.ImuPacket]]], out: Output
                ) -> tuple[dict[str, Block], Shared]:  # fmt: skip
        """Samples of running devices, calibrated: one conversion for all, the blocks views of its shared arrays
        (a calibration written back into them); on bad data, device by device."""
        res: dict[str, Block] = {}
        if not ready:
            return res, Shared(None, {})
        try:
            g: Gathered | None = gather_batch([p for _, p in ready])
        except Exception:
            g = None
        at: dict[str, int] = {}
        for k, (dev, pkts) in enumerate(ready):
            try:
                gyr, acc, mag, t_s = g.block(k) if g is not None else gather(pkts)
                if (cal := self.cal.get(dev.device_id)) is not None:
                    acc_cal, mag_cal = cal.apply(acc, mag)
                    if g is None:
                        acc, mag = acc_cal, mag_cal
                    else:  # (n, 3) float64 both: the shared rows hold the calibrated values
                        acc[...] = acc_cal
                        if mag is not None:
                            mag[...] = mag_cal
                res[dev.device_id] = (gyr, acc, mag, t_s)
                if g is not None:
                    at[dev.device_id] = k
            except Exception as exc:
                self.fail(dev.kind, dev.device_id, exc, out)
        return res, Shared(g, at)

    def _start(self, p: schemas.ImuPacket, gyr: FloatArray, acc: FloatArray, mag: FloatArray | None) -> FusedDevice:
        """Create a device after its warm-up window (see the module docstring)."""
        n_warm = max(1, int(math.ceil(self.warmup_s * p.rate_hz)))  # a big first batch: use its start only
        gyr, acc, mag = gyr[:n_warm], acc[:n_warm], None if mag is None else mag[:n_warm]
        name, th = self._effective(p.kind, p.device_id)
        if name in COMPASS_FREE:
            mag = None
        use_mag = mag is not None
        acc0, mag0 = acc.mean(axis=0), None if mag is None else mag.mean(axis=0)
        filt: AttitudeFilter | None = None
        if name != DEFAULT_FILTER:
            try:
                filt = make_filter(name, use_mag, **self._filter_options(p.kind, th))
            except KeyError:
                log.warning("device %s: filter %r not available, using %r", p.device_id, name, DEFAULT_FILTER)
                name = DEFAULT_FILTER
        own_start = getattr(filt, "start", None)  # e.g. HookFilter: its own warm-up (rest, bias, already swinging)
        if own_start is not None:
            own_start(gyr, acc, mag, 1.0 / p.rate_hz, seed_bias=self.warmup_bias_seed)
        elif filt is not None:
            filt.initialise(acc0, mag0)
        else:
            if self.batch is None:
                self.batch = DefaultFilterBatch()
            self.batch.add(p.device_id, dt_s=1.0 / p.rate_hz, use_mag=use_mag, acc_m_s2=acc0, mag_uT=mag0)
        dev = FusedDevice(p.kind, p.device_id, name, 1.0 / p.rate_hz, use_mag, filt)
        if own_start is None:
            g_std = gyr.std(axis=0) if gyr.shape[0] > 1 else np.full(3, math.inf)
            quiet = g_std < self.rest_gyr_std_rad_s
            level = abs(float(np.linalg.norm(acc0)) - G_M_S2) < self.rest_acc_tol_m_s2
            if level and quiet.all() and self.warmup_bias_seed:
                self._seed_bias(dev, gyr.mean(axis=0))
        dev.state = self._new_state(dev, th)
        self.devices[p.device_id] = dev
        return dev

    def _seed_bias(self, dev: FusedDevice, bias_rad_s: FloatArray) -> None:
        """Start the filter's gyro-bias estimate at `bias_rad_s` (filters without a bias state are left alone)."""
        if dev.filt is None:
            assert self.batch is not None
            clip = math.radians(self.batch.settings.bias_clip_deg_s)
            row = self.batch.row(dev.device_id)
            self.batch.states[row, K.S_BIAS : K.S_BIAS + 3] = np.clip(bias_rad_s, -clip, clip)
            return
        seed = getattr(dev.filt, "seed_gyro_bias", None)  # e.g. HookFilter
        if seed is not None:
            seed(bias_rad_s)

    def _step(self, items: dict[str, tuple[FusedDevice, list[schemas.ImuPacket], Block]], shared: Shared,
              out: Output) -> dict[str, FloatArray]:  # fmt: skip
        """One fused block per device: objects one by one, default-filter rows together per block length."""
        quats: dict[str, FloatArray] = {}
        by_len: dict[int, list[str]] = {}
        inputs: dict[str, Block] = {}  # a device's filter input when it differs from its block (lost packets)
        kept: dict[str, np.ndarray] = {}  # ... and where the block's own samples are in it
        gapped = self._gapped(items, shared) if self.max_bridge_s > 0.0 else set()
        for dev_id, (dev, pkts, (gyr, acc, mag, t_s)) in items.items():
            if dev_id in gapped:
                try:
                    bridged = self._bridge(dev, pkts, (gyr, acc, mag, t_s))
                except Exception as exc:
                    self.fail(dev.kind, dev_id, exc, out)
                    continue
                if bridged is not None:
                    gyr, acc, mag, kept[dev_id] = bridged
                    inputs[dev_id] = (gyr, acc, mag, t_s)
                    if all(dev.follows):  # no packet lost: a gap in the device's own time (see `Output.time_gaps`)
                        out.time_gaps.append((dev.kind, dev_id, (gyr.shape[0] - kept[dev_id].shape[0]) * dev.dt_s))
            if dev.filt is None:
                by_len.setdefault(gyr.shape[0], []).append(dev_id)
                continue
            step = getattr(dev.filt, "update_block", None) or dev.filt.run
            bridged_run = getattr(dev.filt, "run_bridged", None)
            try:
                takes = getattr(dev.filt, "known_inputs", ())  # a filter that takes none gets none
                known = {} if self._filter_inputs is None or not takes else {
                    k: v for k, v in self._filter_inputs(dev, float(t_s[-1]) + 1e-6 * dev.wall_offset_us,
                                                         gyr.shape[0], dev.dt_s).items() if k in takes}  # fmt: skip
                if dev_id in kept and bridged_run is not None and self.coast_min_s < math.inf:
                    coast = coast_mask(gyr.shape[0], kept[dev_id], max(1, round(self.coast_min_s / dev.dt_s)))
                    quats[dev_id] = bridged_run(gyr, acc, mag, dev.dt_s, coast, **known)
                else:
                    quats[dev_id] = step(gyr, acc, mag, dev.dt_s, **known)
            except Exception as exc:
                self.fail(dev.kind, dev_id, exc, out)
        finite: set[str] = set()  # devices whose quaternions were checked finite already
        if by_len:
            try:
                q_batch, finite = self._step_batch(items, by_len, inputs, shared)
                quats.update(q_batch)
            except Exception as exc:  # the shared kernel failed: every device in it restarts
                for ids in by_len.values():
                    for dev_id in ids:
                        self.fail(items[dev_id][0].kind, dev_id, exc, out)
        for dev_id, keep in kept.items():
            if dev_id in quats:
                quats[dev_id] = quats[dev_id][keep]
        for dev_id in [d for d, q in quats.items() if d not in finite and not np.isfinite(q).all()]:
            del quats[dev_id]
            self.fail(items[dev_id][0].kind, dev_id, None, out)
        return quats

    def _gapped(self, items: dict[str, tuple[FusedDevice, list[schemas.ImuPacket], Block]], shared: Shared
                ) -> set[str]:  # fmt: skip
        """The devices of `bridge_kinds` whose block may miss samples (`_bridge` tells): `gaps.has_gaps` of all
        the devices in the shared arrays at once (devices outside them are asked one by one); every other one's
        block is remembered as the left side of its next gap, as `_bridge` does."""
        ask: list[tuple[FusedDevice, int]] = []
        out: set[str] = set()
        for dev_id, (dev, _, _) in items.items():
            if dev.kind in self.bridge_kinds:
                if dev_id in shared.at:
                    ask.append((dev, shared.at[dev_id]))
                else:
                    out.add(dev_id)
        if not ask:
            return out
        g = shared.gathered
        assert g is not None
        at = np.array([k for _, k in ask], dtype=np.int64)
        start, stop = np.array(g.start, dtype=np.int64)[at], np.array(g.stop, dtype=np.int64)[at]
        dt_s = np.array([d.dt_s for d, _ in ask])
        tol = gap_tol_s(dt_s, [all(d.follows) for d, _ in ask])
        prev_t_s = np.array([d.last_t_s for d, _ in ask])
        gap = has_gaps(g.t_s[start], g.t_s[stop - 1], stop - start, prev_t_s, dt_s, tol).tolist()
        last_t_s = g.t_s[stop - 1].tolist()
        for (dev, _), gapped, t_last in zip(ask, gap, last_t_s, strict=True):
            if gapped:
                out.add(dev.device_id)
            else:
                dev.last_t_s, dev.last_block = t_last, items[dev.device_id][2]
        return out

    def _bridge(self, dev: FusedDevice, pkts: list[schemas.ImuPacket], block: Block
                ) -> tuple[FloatArray, FloatArray, FloatArray | None, np.ndarray] | None:  # fmt: skip
        """The device's block (of packets `pkts`) with the samples lost before and within it interpolated
        (`gaps.bridge_block`), or None when none were; remembers the block as the left side of the next gap. Between
        packets whose seq follows on, only a spacing `JITTER_TOL_S` past a period is a gap (a jittery t0_us)."""
        gyr, acc, mag, t_s = block
        prev_t_s, prev = dev.last_t_s, dev.last_block
        dev.last_t_s, dev.last_block = float(t_s[-1]), block
        if not has_gap(t_s, prev_t_s, dev.dt_s, gap_tol_s(dev.dt_s, all(dev.follows))):
            return None
        # within a packet the times are exact; between packets, see JITTER_TOL_S
        tol = np.full(t_s.shape[0], gap_tol_s(dev.dt_s, False))
        start, follow_starts = 0, []
        for pkt, follows in zip(pkts, dev.follows, strict=False):
            if follows:
                follow_starts.append(start)
            start += pkt.n
        if follow_starts:
            tol[follow_starts] = gap_tol_s(dev.dt_s, True)
        return bridge_block(gyr, acc, mag, t_s, dev.dt_s, prev, self.max_bridge_s,
                            max(1, round(self.bridge_average_s / dev.dt_s)), self.gyro_taper_s.get(dev.kind, 0.0), tol)

    def _step_batch(self, items: dict[str, tuple[FusedDevice, list[schemas.ImuPacket], Block]],
                    by_len: dict[int, list[str]], inputs: dict[str, Block], shared: Shared
                    ) -> tuple[dict[str, FloatArray], set[str]]:  # fmt: skip
        """The default-filter rows, one kernel call per block length: the devices whose input is their rows of the
        shared arrays copied in with one index per sensor, the others (bridged, just started) one by one. Returns
        the quaternions and the devices of the former whose quaternions are all finite (checked in one call)."""
        quats: dict[str, FloatArray] = {}
        finite: set[str] = set()
        batch = self.batch
        assert batch is not None
        g, at = shared
        for n, ids in by_len.items():
            n_dev = len(batch)
            rows = batch.rows(ids)
            few = 4 * len(ids) < n_dev  # a length few devices have (lost packets): step those rows alone
            slots = list(range(len(ids))) if few else rows  # where each device's inputs go
            size = len(ids) if few else n_dev
            gyr_a, acc_a, mag_a = np.zeros((size, n, 3)), np.zeros((size, n, 3)), np.zeros((size, n, 3))
            fast: list[int] = []  # input: the device's rows of the shared arrays
            own: list[int] = []  # input: a block of its own (bridged, just started, gathered alone)
            for k, d in enumerate(ids):
                (fast if g is not None and d in at and d not in inputs else own).append(k)
            for k in own:
                gyr, acc, mag, _ = inputs.get(ids[k]) or items[ids[k]][2]
                r = slots[k]
                gyr_a[r], acc_a[r] = gyr, acc
                if mag is not None:
                    mag_a[r] = mag
            if fast:
                assert g is not None
                to = np.array([slots[k] for k in fast], dtype=np.int64)
                src = np.array([g.start[at[ids[k]]] for k in fast], dtype=np.int64)[:, None] + np.arange(n)
                gyr_a[to], acc_a[to] = g.gyr[src], g.acc[src]
                on = np.array([items[ids[k]][2][2] is not None for k in fast], dtype=np.bool_)
                if on.any():
                    assert g.mag is not None
                    mag_a[to[on]] = g.mag[src[on]]
            if few:
                q_all = batch.step_rows(np.array(rows, dtype=np.int64), gyr_a, acc_a, mag_a)
            else:
                active = np.zeros(n_dev, dtype=np.bool_)
                active[rows] = True
                q_all = batch.step(gyr_a, acc_a, mag_a, active)
            quats.update(zip(ids, q_all[slots], strict=True))
            if fast:
                ok = np.isfinite(q_all[to]).all(axis=(1, 2))
                finite.update(ids[fast[j]] for j in np.flatnonzero(ok).tolist())
        return quats, finite
