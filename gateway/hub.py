"""Fan-out of pipeline results: zenoh outputs, the store (alarm history), and in-process listeners (websocket,
3-D view later). Alarms, reel commands, hook swing (at most 20 Hz per hook) and (opt-in) attitude blocks are published
with CongestionControl.BLOCK; attitude with DROP (a newer sample follows shortly)."""

from __future__ import annotations

import itertools
import logging
import time
from collections.abc import Callable

from gateway import schemas
from gateway.alarm.engine import Alarm, AlarmChange
from gateway.ingest.bus import Bus
from gateway.pipeline import AlarmOut, Output
from gateway.store import Store

log = logging.getLogger("gateway.hub")

Listener = Callable[[str, schemas.WireModel], None]
"""(topic, model): topic is `attitude`, `attitude_block`, `swing`, `alarm`, `spots` or `reel_cmd`."""


def alarm_event(out: AlarmOut, now_us: int) -> schemas.AlarmEvent:
    """Wire event of an engine change: raised/updated -> `raised` (with the current severity), cleared -> `cleared`.

    `alarm_id` and `severity` are the engine's (= the store's) own; `t_us` is device time, `wall_t_us` = `now_us`.
    """
    a: Alarm = out.change.alarm
    return schemas.AlarmEvent(
        alarm_id=a.id, device_id=a.device_id, kind=out.kind, alarm=a.type,  # type: ignore[arg-type]
        state="cleared" if out.change.kind == "cleared" else "raised", severity=a.severity.value,
        t_us=out.t_us, wall_t_us=now_us, source_wall_us=out.source_wall_us,
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
        """Alarms first (they matter most and are rare), then reel commands, attitude, attitude blocks (BLOCK: a
        scoring run or a full-rate recording must not lose samples), swing, spots."""
        now_us = int(self.clock() * 1e6)
        for al in out.alarms:
            stored = self.store.upsert_alarm(al.change.alarm)  # may keep an older active row's id: publish that one
            if al.change.kind == "acknowledged":
                continue
            al = al._replace(change=AlarmChange(al.change.kind, stored))
            self._put(schemas.alarm_key(al.kind, stored.device_id), "alarm", alarm_event(al, now_us), block=True)
        for device_id, fields in out.reel_commands:
            self.send_reel(device_id, sender="auto", **fields)
        for a in out.attitudes:
            self._put(schemas.attitude_key(a.kind, a.device_id), "attitude", a)
        for b in out.attitude_blocks:
            self._put(schemas.attitude_block_key(b.kind, b.device_id), "attitude_block", b, block=True)
        for s in out.swings:  # BLOCK: at <= 20 Hz per hook, a crane app must not lose any (docs/protocol.md)
            self._put(schemas.swing_key(s.device_id), "swing", s, block=True)
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
