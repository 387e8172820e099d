"""The fusion bank: every IMU device's attitude filter, from warm-up to restart-on-failure.

* Warm-up: a new device's packets are collected until `warmup_s` of samples arrived; its filter then starts from
  the window's mean acc (+ mag), and when the window was at rest its mean gyro seeds the bias estimate.
* Filter factory: the default filter is a row of one `DefaultFilterBatch` (all such devices stepped by one numba
  call per distinct block length); any other name (the hook EKF, a registry filter) is an object per device.
* Batching: `fuse` takes one drained batch (packets grouped per device), gathers every device's samples in one
  array conversion, applies calibrations and steps all filters.
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
from typing import Any

import numpy as np

from gateway import schemas
from gateway.calibrate import DeviceCalibration
from gateway.fusion import _default_kernels as K
from gateway.fusion.base import AttitudeFilter, FloatArray
from gateway.fusion.batch import DefaultFilterBatch
from gateway.fusion.gaps import (
    BRIDGE_AVERAGE_S,
    COAST_MIN_S,
    GAP_FACTOR,
    JITTER_TOL_S,
    MAX_BRIDGE_S,
    bridge_block,
    coast_mask,
    has_gap,
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


def make_filter(name: str, use_mag: bool, rope_length_m: float | None = None) -> AttitudeFilter:
    """A filter by name: the hook EKF (on a rope of `rope_length_m`, else its default), else the registry
    (KeyError when unknown)."""
    from gateway.fusion import registry

    if name in (HOOK_FILTER, HOOK_FILTER_6D):
        from gateway.fusion.hook_filter import HookFilter, HookFilterSettings

        # The hook setting's length (configured, or the 10 m default) is a prior the pendulum frequency corrects: a
        # wrong one is found within seconds of swinging, while a wide prior would let a trolley jerk read as a rope.
        settings = HookFilterSettings() if rope_length_m is None else HookFilterSettings(
            rope_length_m=rope_length_m, rope_length_known=True)
        return HookFilter(settings, use_mag=use_mag and name not in COMPASS_FREE)
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


def gather_all(groups: list[list[schemas.ImuPacket]]) -> list[Block]:
    """`gather` of many devices with one array conversion per sensor for all of them (the same values). Packets
    decoded from the binary encoding bring their float32 rows (`schemas.sample_rows`, their sample tuples are not
    even built): a batch with any is gathered from rows, the JSON packets' tuples made rows one by one."""
    pk = [p for g in groups for p in g]
    sizes = [sum(p.n for p in g) for g in groups]
    stop = np.cumsum(sizes).tolist()
    cuts = list(zip([0, *stop[:-1]], stop, strict=True))  # rows of each device (slices: np.split is slow)
    total = stop[-1] if stop else 0
    kept = [schemas.sample_rows(p) for p in pk]
    from_rows = any(r is not None for r in kept)
    rows = [r if r is not None else np.hstack([a for a in p.arrays() if a is not None])  # JSON: [gyr acc (mag)]
            for r, p in zip(kept, pk, strict=True)] if from_rows else []  # fmt: skip

    sel = [i for i, g in enumerate(groups) if all(p.has_mag for p in g)]
    # the common case, every packet 6 wide or every one 9 wide: one concatenation, then its columns
    whole = np.concatenate(rows, dtype=np.float64) if from_rows and len({r.shape[1] for r in rows}) == 1 else None
    if whole is not None and whole.shape[1] == 9 and len(sel) < len(groups):
        whole = None  # a device with a packet of 6 among 9-wide ones: its magnetometer is not taken

    def column(a: int, b: int, which: Iterable[int] | None = None) -> FloatArray:
        """Columns a:b of the kept rows of packets `which` (all), as one contiguous float64 array."""
        if whole is not None:
            return np.ascontiguousarray(whole[:, a:b])
        picked = rows if which is None else [rows[j] for j in which]
        return np.concatenate([r[:, a:b] for r in picked], dtype=np.float64)

    gyr_all = column(0, 3) if from_rows else _rows3((p.gyr_rad_s for p in pk), total)
    acc_all = column(3, 6) if from_rows else _rows3((p.acc_m_s2 for p in pk), total)
    n = np.array([p.n for p in pk], dtype=np.int64)
    first = np.repeat(np.cumsum(n) - n, n)
    t0 = np.repeat(np.array([p.t0_us for p in pk], dtype=np.int64) * 1e-6, n)
    rate = np.repeat(np.array([p.rate_hz for p in pk], dtype=np.float64), n)
    t_all = t0 + (np.arange(first.shape[0]) - first) / rate
    mags: list[FloatArray | None] = [None] * len(groups)
    if sel:
        if from_rows:
            first_pkt = np.cumsum([0, *map(len, groups)]).tolist()  # each device's first packet in `pk`
            m_all = column(6, 9, (j for i in sel for j in range(first_pkt[i], first_pkt[i + 1])))
        else:
            m_all = _rows3((p.mag_uT or () for i in sel for p in groups[i]), sum(sizes[i] for i in sel))
        at = 0
        for i in sel:
            mags[i], at = m_all[at : at + sizes[i]], at + sizes[i]
    return [(gyr_all[a:b], acc_all[a:b], mags[i], t_all[a:b]) for i, (a, b) in enumerate(cuts)]


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
        self.devices: dict[str, FusedDevice] = {}
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
        blocks = self._blocks([(d, p) for d, p in ready if d.device_id not in started], out)
        blocks.update(started)
        items: dict[str, tuple[FusedDevice, list[schemas.ImuPacket], Block]] = {}
        for dev, pkts in ready:
            if dev.device_id not in blocks:
                continue
            gyr, acc, mag, t_s = blocks[dev.device_id]
            if abs(1.0 / pkts[-1].rate_hz - dev.dt_s) > 1e-12:
                dev.dt_s = 1.0 / pkts[-1].rate_hz
                if dev.filt is None and self.batch is not None:
                    self.batch.set_dt(dev.device_id, dev.dt_s)
            last = pkts[-1]
            seqs = [dev.seq, *(p.seq for p in pkts)]
            dev.follows = tuple(b == a + 1 for a, b in pairwise(seqs))  # for the gap checks' tolerance
            dev.t_us, dev.seq = last.t0_us + int(round((last.n - 1) * 1e6 / last.rate_hz)), last.seq
            dev.wall_from_device = last.wall_t0_us is not None
            dev.wall_offset_us = (last.wall_t0_us - last.t0_us) if last.wall_t0_us is not None else (
                int(now_s * 1e6) - dev.t_us)  # fmt: skip
            items[dev.device_id] = (dev, pkts, (gyr, acc, mag if dev.use_mag else None, t_s))
        quats = self._step(items, out)
        ids = list(quats)
        ends = packet_ends([items[d][1] for d in ids]) if ids else []
        return [Fused(dev, quats[d], blk[0], blk[1], blk[3], e, pkts)
                for d, e in zip(ids, ends, strict=True) for dev, pkts, blk in (items[d],)]  # fmt: skip

    def _blocks(self, ready: list[tuple[FusedDevice, list[schemas.ImuPacket]]], out: Output) -> dict[str, Block]:
        """Samples of running devices, calibrated: one conversion for all; on bad data, device by device."""
        if not ready:
            return {}
        try:
            arrays = gather_all([p for _, p in ready])
        except Exception:
            arrays = []
        res: dict[str, Block] = {}
        for k, (dev, pkts) in enumerate(ready):
            try:
                gyr, acc, mag, t_s = arrays[k] if arrays else gather(pkts)
                if (cal := self.cal.get(dev.device_id)) is not None:
                    acc, mag = cal.apply(acc, mag)
                res[dev.device_id] = (gyr, acc, mag, t_s)
            except Exception as exc:
                self.fail(dev.kind, dev.device_id, exc, out)
        return res

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

    def _step(self, items: dict[str, tuple[FusedDevice, list[schemas.ImuPacket], Block]], out: Output
              ) -> dict[str, FloatArray]:  # fmt: skip
        """One fused block per device: objects one by one, default-filter rows together per block length."""
        quats: dict[str, FloatArray] = {}
        by_len: dict[int, list[str]] = {}
        inputs: dict[str, Block] = {}  # a device's filter input when it differs from its block (lost packets)
        kept: dict[str, np.ndarray] = {}  # ... and where the block's own samples are in it
        for dev_id, (dev, pkts, (gyr, acc, mag, t_s)) in items.items():
            if dev.kind in self.bridge_kinds and self.max_bridge_s > 0.0:
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
                if dev_id in kept and bridged_run is not None and self.coast_min_s < math.inf:
                    coast = coast_mask(gyr.shape[0], kept[dev_id], max(1, round(self.coast_min_s / dev.dt_s)))
                    quats[dev_id] = bridged_run(gyr, acc, mag, dev.dt_s, coast)
                else:
                    quats[dev_id] = step(gyr, acc, mag, dev.dt_s)
            except Exception as exc:
                self.fail(dev.kind, dev_id, exc, out)
        if by_len:
            try:
                quats.update(self._step_batch(items, by_len, inputs))
            except Exception as exc:  # the shared kernel failed: every device in it restarts
                for ids in by_len.values():
                    for dev_id in ids:
                        self.fail(items[dev_id][0].kind, dev_id, exc, out)
        for dev_id, keep in kept.items():
            if dev_id in quats:
                quats[dev_id] = quats[dev_id][keep]
        for dev_id in [d for d, q in quats.items() if not np.isfinite(q).all()]:
            del quats[dev_id]
            self.fail(items[dev_id][0].kind, dev_id, None, out)
        return quats

    def _bridge(self, dev: FusedDevice, pkts: list[schemas.ImuPacket], block: Block
                ) -> tuple[FloatArray, FloatArray, FloatArray | None, np.ndarray] | None:  # fmt: skip
        """The device's block (of packets `pkts`) with the samples lost before and within it interpolated
        (`gaps.bridge_block`), or None when none were; remembers the block as the left side of the next gap. Between
        packets whose seq follows on, only a spacing `JITTER_TOL_S` past a period is a gap (a jittery t0_us)."""
        gyr, acc, mag, t_s = block
        prev_t_s, prev = dev.last_t_s, dev.last_block
        dev.last_t_s, dev.last_block = float(t_s[-1]), block
        strict = (GAP_FACTOR - 1.0) * dev.dt_s
        none_lost = all(dev.follows)
        if not has_gap(t_s, prev_t_s, dev.dt_s, max(strict, JITTER_TOL_S) if none_lost else strict):
            return None
        tol = np.full(t_s.shape[0], strict)  # within a packet the times are exact; between packets, see JITTER_TOL_S
        starts = np.cumsum([0, *(p.n for p in pkts[:-1])])
        tol[starts[np.array(dev.follows, dtype=np.bool_)]] = max(strict, JITTER_TOL_S)
        return bridge_block(gyr, acc, mag, t_s, dev.dt_s, prev, self.max_bridge_s,
                            max(1, round(self.bridge_average_s / dev.dt_s)), self.gyro_taper_s.get(dev.kind, 0.0), tol)

    def _step_batch(self, items: dict[str, tuple[FusedDevice, list[schemas.ImuPacket], Block]],
                    by_len: dict[int, list[str]], inputs: dict[str, Block]) -> dict[str, FloatArray]:  # fmt: skip
        quats: dict[str, FloatArray] = {}
        batch = self.batch
        assert batch is not None
        for n, ids in by_len.items():
            n_dev = len(batch)
            gyr_a, acc_a, mag_a = np.zeros((n_dev, n, 3)), np.zeros((n_dev, n, 3)), np.zeros((n_dev, n, 3))
            active = np.zeros(n_dev, dtype=np.bool_)
            rows = [batch.row(d) for d in ids]
            for d, r in zip(ids, rows, strict=True):
                gyr, acc, mag, _ = inputs.get(d) or items[d][2]
                gyr_a[r], acc_a[r] = gyr, acc
                if mag is not None:
                    mag_a[r] = mag
                active[r] = True
            q_all = batch.step(gyr_a, acc_a, mag_a, active)
            for d, r in zip(ids, rows, strict=True):
                quats[d] = q_all[r]
        return quats
