"""Fan-out of pipeline results: zenoh outputs, the store (alarm history), and in-process listeners (websocket,
3-D view later). Alarms and reel commands are published with CongestionControl.BLOCK; attitude and swing with
DROP (a newer sample follows shortly)."""

from __future__ import annotations

import itertools
import logging
import time
from collections.abc import Callable

from gateway import schemas
from gateway.alarm.engine import Alarm, AlarmChange, Severity
from gateway.ingest.bus import Bus
from gateway.pipeline import Output
from gateway.store import Store

log = logging.getLogger("gateway.hub")

Listener = Callable[[str, schemas.WireModel], None]
"""(topic, model): topic is `attitude`, `swing`, `alarm`, `spots` or `reel_cmd`."""

# The engine has ThingsBoard's five severities, the wire three (see docs/gateway.md).
WIRE_SEVERITY: dict[Severity, schemas.Severity] = {
    Severity.CRITICAL: "critical", Severity.MAJOR: "warning", Severity.MINOR: "warning",
    Severity.WARNING: "warning", Severity.INDETERMINATE: "info",
}  # fmt: skip


def wire_alarm_id(alarm_id: str) -> int:
    """The wire's uint32 alarm id: the first 32 bits of the store's hex id (REST uses the full id)."""
    try:
        return int(alarm_id[:8], 16)
    except ValueError:
        return hash(alarm_id) % schemas.UINT32


def alarm_event(kind: str, change: AlarmChange, source_wall_us: int | None, now_us: int) -> schemas.AlarmEvent:
    """Wire event of an engine change: raised/updated -> `raised` (with the current severity), cleared -> `cleared`."""
    a: Alarm = change.alarm
    return schemas.AlarmEvent(
        alarm_id=wire_alarm_id(a.id), device_id=a.device_id, kind=kind, alarm=a.type,  # type: ignore[arg-type]
        state="cleared" if change.kind == "cleared" else "raised", severity=WIRE_SEVERITY[a.severity],
        t_us=int(a.updated_at * 1e6), wall_t_us=now_us, source_wall_us=source_wall_us,
        value=a.value, threshold=a.threshold, message=a.message[:500],
    )  # fmt: skip


class Hub:
    """Publishes and persists one `Output` at a time; `listeners` get every published model too."""

    def __init__(self, bus: Bus, store: Store, clock: Callable[[], float] = time.time) -> None:
        self.bus = bus
        self.store = store
        self.clock = clock
        self.listeners: list[Listener] = []
        self._cmd_ids = itertools.count(int(clock()) % 1_000_000 * 1000)
        self.published = 0

    def _put(self, key: str, topic: str, model: schemas.WireModel, *, block: bool = False) -> None:
        self.bus.put(key, model.to_json(), encoding=schemas.ENCODING_GW, block=block)
        self.published += 1
        for cb in self.listeners:
            try:
                cb(topic, model)
            except Exception:
                log.exception("listener failed on %s", topic)

    def emit(self, out: Output) -> None:
        """Alarms first (they matter most and are rare), then reel commands, attitude, swing, spots."""
        now_us = int(self.clock() * 1e6)
        for kind, change, src_us in out.alarms:
            stored = self.store.upsert_alarm(change.alarm)
            change = AlarmChange(change.kind, stored)
            if change.kind == "acknowledged":
                continue
            self._put(schemas.alarm_key(kind, stored.device_id), "alarm", alarm_event(kind, change, src_us, now_us),
                      block=True)  # fmt: skip
        for device_id, fields in out.reel_commands:
            self.send_reel(device_id, sender="auto", **fields)
        for a in out.attitudes:
            self._put(schemas.attitude_key(a.kind, a.device_id), "attitude", a)
        for s in out.swings:
            self._put(schemas.swing_key(s.device_id), "swing", s)
        if out.spots is not None:
            self._put(schemas.SPOTS_KEY, "spots", out.spots)

    def send_reel(
        self, device_id: str, action: str, speed_m_s: float | None = None, drag_n: float | None = None,
        sender: str = "api",
    ) -> schemas.ReelCommand:
        """Publish a ReelCommand to `rig/rod/{id}/reel/cmd` with BLOCK; returns it (with its cmd_id)."""
        cmd = schemas.ReelCommand(
            v=1, cmd_id=next(self._cmd_ids) % schemas.UINT32, action=action,  # type: ignore[arg-type]
            speed_m_s=speed_m_s, drag_n=drag_n, sent_wall_us=int(self.clock() * 1e6), sender=sender,
        )  # fmt: skip
        self.bus.put(schemas.reel_cmd_key(device_id), cmd.to_json(), encoding=schemas.ENCODING_REEL_CMD, block=True)
        for cb in self.listeners:
            cb("reel_cmd", cmd)
        return cmd
