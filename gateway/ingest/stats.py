"""Ingest accounting: received / queue drops / rejects by reason, per-device stream counters, rate-limited logs.

Streams are tracked per (device, topic) with `ingest.sequence.SequenceTracker` (loss, reorder, duplicate, reboot);
the per-device figures reported are those of the device's main stream (`imu` or `env`).
"""

from __future__ import annotations

import logging
from collections import Counter
from collections.abc import Sequence
from dataclasses import dataclass, field

from gateway import schemas
from gateway.ingest.samplerate import SampleRateMeter
from gateway.ingest.sequence import SEQ_OK, SequenceTracker
from gateway.ingest.timecheck import DeviceClock

log = logging.getLogger("gateway.ingest")

MAIN_TOPICS = ("imu", "env")


@dataclass
class DeviceStream:
    """Counters of one device: its trackers by topic, rejects by reason, last arrival (monotonic s)."""

    device_id: str
    kind: str
    trackers: dict[str, SequenceTracker] = field(default_factory=dict)
    rejected: Counter[str] = field(default_factory=Counter)
    filter_restarts: Counter[str] = field(default_factory=Counter)
    last_arrival_s: float | None = None
    packets: int = 0
    clock: DeviceClock = field(default_factory=lambda: DeviceClock())
    rate: SampleRateMeter = field(default_factory=lambda: SampleRateMeter())  # the IMU's rate as its t0_us say
    conflict_last_s: float | None = None  # arrival (monotonic s) of the newest packet that showed a second publisher

    def main(self) -> SequenceTracker:
        for topic in MAIN_TOPICS:
            if topic in self.trackers:
                return self.trackers[topic]
        return next(iter(self.trackers.values()), SequenceTracker())

    def loss_fraction(self) -> float:
        """Lost / (received + lost) on the main stream."""
        t = self.main()
        total = t.ok + t.lost
        return t.lost / total if total else 0.0


class RateLimitedLog:
    """At most one log line per `period_s` per key; the lines in between are counted and reported next time."""

    def __init__(self, period_s: float = 5.0) -> None:
        self.period_s = period_s
        self._last: dict[str, float] = {}
        self._suppressed: Counter[str] = Counter()

    def warning(self, key: str, msg: str, now_s: float) -> bool:
        """Log `msg` unless `key` was logged less than `period_s` ago; True if logged."""
        last = self._last.get(key)
        if last is not None and now_s - last < self.period_s:
            self._suppressed[key] += 1
            return False
        n = self._suppressed.pop(key, 0)
        self._last[key] = now_s
        log.warning("%s%s", msg, f" (+{n} similar suppressed)" if n else "")
        return True


class IngestCounters:
    """All ingest counters of the gateway; `snapshot()` gives the `gw/diag/ingest` model."""

    def __init__(self) -> None:
        self.received = 0
        self.queue_drops = 0
        self.rejected: Counter[str] = Counter()
        self.filter_restarts: Counter[str] = Counter()
        self.devices: dict[str, DeviceStream] = {}
        self.conflicts_seen: set[str] = set()  # devices with a new conflict packet; the service takes and clears it
        self.log = RateLimitedLog()
        self.shard: str | None = None  # set by a shard: its snapshots say whose they are

    def stream(self, kind: str, device_id: str) -> DeviceStream:
        dev = self.devices.get(device_id)
        if dev is None:
            dev = self.devices[device_id] = DeviceStream(device_id, kind)
        return dev

    def accept(self, kind: str, device_id: str, topic: str, boot_id: int, seq: int, now_s: float) -> bool:
        """Sequence-check one decoded packet; False for a duplicate or a rival publisher's packet (drop it).
        A second publisher on the key is counted as `device_conflict` and remembered in `conflicts_seen`."""
        dev = self.devices.get(device_id) or self.stream(kind, device_id)
        tracker = dev.trackers.get(topic)
        if tracker is None:
            tracker = dev.trackers[topic] = SequenceTracker()
        res = tracker.update(boot_id, seq)
        dev.last_arrival_s = now_s
        dev.packets += 1
        if res is SEQ_OK:  # the next packet of the stream: nearly every packet
            return True
        if res.conflict:
            dev.conflict_last_s = now_s
            self.conflicts_seen.add(device_id)
            self.drop(kind, device_id, "device_conflict",
                      f"a second publisher on rig/{kind}/{device_id}/{topic} (boot {boot_id}, seq {seq})", now_s)
        return res.accept

    def drop(self, kind: str, device_id: str, reason: str, detail: str, now_s: float) -> None:
        """Count a decoded packet dropped (or a field of it ignored) for `reason`; log it, at most once per 5 s and
        reason (not per device: a hostile peer can make up any number of ids)."""
        self.rejected[reason] += 1
        self.stream(kind, device_id).rejected[reason] += 1
        self.log.warning(reason, f"device {device_id}: {reason}: {detail}", now_s)  # per reason: ids are many

    def reject(self, key: str, err: schemas.DecodeError, now_s: float) -> None:
        """Count a rejected packet by reason (and per device when the key names a known device)."""
        self.rejected[err.reason] += 1
        parts = key.split("/")
        if len(parts) >= 3 and parts[0] == "rig" and parts[2] in self.devices:
            self.devices[parts[2]].rejected[err.reason] += 1
        self.log.warning(err.reason, f"rejected packet on {key[:120]!r}: {err}", now_s)

    def filter_failed(self, kind: str, device_id: str, reason: str, detail: str, now_s: float) -> None:
        """Count a device's filter failure (its fusion restarts) by reason; log it, rate-limited per device."""
        self.filter_restarts[reason] += 1
        self.stream(kind, device_id).filter_restarts[reason] += 1
        self.log.warning(f"filter:{device_id}", f"device {device_id}: filter failed ({reason}: {detail}); "
                         "restarting its fusion from a new warm-up window", now_s)  # fmt: skip

    def snapshot(self, wall_us: int) -> schemas.IngestStats:
        devices = []
        for d in self.devices.values():
            t = d.main()
            devices.append(schemas.DeviceIngestCounters(
                device_id=d.device_id, kind=d.kind, ok=t.ok, lost=t.lost,  # type: ignore[arg-type]
                duplicates=t.duplicates, reordered=t.reordered, reboots=t.reboots, rejected=dict(d.rejected),
                filter_restarts=dict(d.filter_restarts),
            ))  # fmt: skip
        return schemas.IngestStats(
            wall_t_us=wall_us, shard=self.shard, received=self.received, queue_drops=self.queue_drops,
            rejected=dict(self.rejected), filter_restarts=dict(self.filter_restarts), devices=devices,
        )  # fmt: skip


def merge_ingest_stats(parts: Sequence[schemas.IngestStats]) -> schemas.IngestStats | None:
    """One IngestStats from several shards': counters summed, device rows concatenated (a device that moved
    between shards keeps the row with the most packets)."""
    if not parts:
        return None
    rejected: Counter[str] = Counter()
    restarts: Counter[str] = Counter()
    devices: dict[str, schemas.DeviceIngestCounters] = {}
    for s in parts:
        rejected.update(s.rejected)
        restarts.update(s.filter_restarts)
        for d in s.devices:
            if d.device_id not in devices or d.ok > devices[d.device_id].ok:
                devices[d.device_id] = d
    return schemas.IngestStats(wall_t_us=max(s.wall_t_us for s in parts), received=sum(s.received for s in parts),
                               queue_drops=sum(s.queue_drops for s in parts), rejected=dict(rejected),
                               filter_restarts=dict(restarts), devices=list(devices.values()))  # fmt: skip
