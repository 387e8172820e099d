"""IoT-style alarm lifecycle (as ThingsBoard does it): one active alarm per (device, type), updated not duplicated.

Rules emit `Condition`s (severity, or None when the condition has cleared); `AlarmEngine.evaluate` turns them
into `AlarmChange`s (raised / updated / cleared / acknowledged) that the service persists and publishes.
Acknowledging does not clear; an escalation of severity resets the acknowledgement so the operator sees it.
Times are passed in (device or gateway seconds); the engine never reads a clock.
"""

from __future__ import annotations

import uuid
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass, field, replace
from enum import StrEnum
from types import MappingProxyType
from typing import Literal

DetailValue = float | int | str | bool | None


class Severity(StrEnum):
    """Alarm severity, most severe first (ThingsBoard's five levels)."""

    CRITICAL = "critical"
    MAJOR = "major"
    MINOR = "minor"
    WARNING = "warning"
    INDETERMINATE = "indeterminate"

    @property
    def rank(self) -> int:
        """Larger is more severe: critical 4 .. indeterminate 0."""
        return _RANK[self]


_RANK = {Severity.CRITICAL: 4, Severity.MAJOR: 3, Severity.MINOR: 2, Severity.WARNING: 1, Severity.INDETERMINATE: 0}


class AlarmStatus(StrEnum):
    ACTIVE = "active"
    CLEARED = "cleared"


ChangeKind = Literal["raised", "updated", "cleared", "acknowledged"]


def _frozen(details: Mapping[str, DetailValue]) -> Mapping[str, DetailValue]:
    return MappingProxyType(dict(details))


@dataclass(frozen=True, slots=True)
class Condition:
    """One rule's verdict for (device, type) at `t_s`: `severity=None` means the condition has cleared."""

    device_id: str
    type: str
    severity: Severity | None
    t_s: float
    value: float = 0.0
    threshold: float = 0.0
    message: str = ""
    details: Mapping[str, DetailValue] = field(default_factory=dict)


@dataclass(frozen=True, slots=True)
class Alarm:
    """An alarm record (what the store persists); `peak` is the largest |value| seen, `count` the updates."""

    id: str
    device_id: str
    type: str
    severity: Severity
    status: AlarmStatus
    started_at: float
    updated_at: float
    value: float
    threshold: float
    message: str
    peak: float = 0.0
    count: int = 1
    acknowledged: bool = False
    acknowledged_at: float | None = None
    acknowledged_by: str | None = None
    cleared_at: float | None = None
    details: Mapping[str, DetailValue] = field(default_factory=dict)

    @property
    def active(self) -> bool:
        return self.status is AlarmStatus.ACTIVE


@dataclass(frozen=True, slots=True)
class AlarmChange:
    """What happened to an alarm, with its state afterwards."""

    kind: ChangeKind
    alarm: Alarm


def _new_id() -> str:
    return uuid.uuid4().hex


class AlarmEngine:
    """Holds the active alarms and applies rule conditions to them.

    Args:
        active: alarms to resume with (e.g. the store's active rows after a restart).
        id_factory: makes alarm ids (injected so tests are deterministic).
    """

    def __init__(self, active: Iterable[Alarm] = (), id_factory: Callable[[], str] = _new_id) -> None:
        self._active: dict[tuple[str, str], Alarm] = {(a.device_id, a.type): a for a in active if a.active}
        self._new_id = id_factory

    def evaluate(self, conditions: Iterable[Condition]) -> list[AlarmChange]:
        """Apply conditions in order; returns only real changes (a repeated identical condition is no change)."""
        changes: list[AlarmChange] = []
        for c in conditions:
            change = self._apply(c)
            if change is not None:
                changes.append(change)
        return changes

    def _apply(self, c: Condition) -> AlarmChange | None:
        key = (c.device_id, c.type)
        current = self._active.get(key)
        if c.severity is None:
            if current is None:
                return None
            # the raise message stays (what happened); the rule's clear message is added (how it ended)
            msg = f"{current.message}; cleared: {c.message}" if c.message else current.message
            cleared = replace(current, status=AlarmStatus.CLEARED, cleared_at=c.t_s, updated_at=c.t_s, message=msg,
                              peak=max(current.peak, abs(c.value)))  # fmt: skip
            del self._active[key]
            return AlarmChange("cleared", cleared)
        if current is None:
            alarm = Alarm(
                id=self._new_id(), device_id=c.device_id, type=c.type, severity=c.severity,
                status=AlarmStatus.ACTIVE, started_at=c.t_s, updated_at=c.t_s, value=c.value,
                threshold=c.threshold, message=c.message, peak=abs(c.value), details=_frozen(c.details),
            )  # fmt: skip
            self._active[key] = alarm
            return AlarmChange("raised", alarm)
        if (c.severity, c.value, c.threshold, c.message) == (current.severity, current.value,
                                                            current.threshold, current.message):  # fmt: skip
            return None
        escalated = c.severity.rank > current.severity.rank
        updated = replace(
            current, severity=c.severity, updated_at=c.t_s, value=c.value, threshold=c.threshold,
            message=c.message, peak=max(current.peak, abs(c.value)), count=current.count + 1,
            details=_frozen(c.details),
            acknowledged=current.acknowledged and not escalated,
            acknowledged_at=None if escalated else current.acknowledged_at,
            acknowledged_by=None if escalated else current.acknowledged_by,
        )  # fmt: skip
        self._active[key] = updated
        return AlarmChange("updated", updated)

    def acknowledge(self, alarm_id: str, by: str, t_s: float) -> AlarmChange | None:
        """Mark an active alarm acknowledged (it stays active); None if no such active alarm or already acked."""
        for key, a in self._active.items():
            if a.id == alarm_id:
                if a.acknowledged:
                    return None
                acked = replace(a, acknowledged=True, acknowledged_at=t_s, acknowledged_by=by)
                self._active[key] = acked
                return AlarmChange("acknowledged", acked)
        return None

    def clear(self, alarm_id: str, by: str, t_s: float) -> AlarmChange | None:
        """Clear an active alarm by hand (e.g. a stale one whose rule state was lost in a restart); None if no such
        active alarm. The rule raises it again only after its condition has cleared and returned."""
        for key, a in self._active.items():
            if a.id == alarm_id:
                del self._active[key]
                msg = f"{a.message}; cleared by hand ({by})"
                return AlarmChange("cleared", replace(a, status=AlarmStatus.CLEARED, cleared_at=t_s, updated_at=t_s,
                                                      message=msg))  # fmt: skip
        return None

    def active(self, device_id: str | None = None) -> list[Alarm]:
        """Active alarms, optionally for one device, most severe first."""
        rows = [a for a in self._active.values() if device_id is None or a.device_id == device_id]
        return sorted(rows, key=lambda a: (-a.severity.rank, a.started_at))

    def resume(self, alarms: Iterable[Alarm]) -> None:
        """Take over active alarms raised elsewhere (a gateway shard that served their device before, from the
        store), as the constructor does after a restart: they update and clear here instead of being raised again."""
        for a in alarms:
            if a.active:
                self._active.setdefault((a.device_id, a.type), a)

    def release(self, device_id: str) -> list[Alarm]:
        """Stop holding a device's active alarms without clearing them (another shard serves the device now and
        resumes them); returns them."""
        keys = [k for k in self._active if k[0] == device_id]
        return [self._active.pop(k) for k in keys]

    def forget_device(self, device_id: str, t_s: float) -> list[AlarmChange]:
        """Clear every active alarm of a device (e.g. removed from the gateway)."""
        keys = [k for k in self._active if k[0] == device_id]
        return self.evaluate(Condition(device_id, k[1], None, t_s) for k in keys)


OFFLINE_TYPE = "device_offline"


def presence_condition(device_id: str, online: bool, t_s: float) -> Condition:
    """`device_offline` (major) while a device's liveliness token is gone; cleared when it is back."""
    if online:
        return Condition(device_id, OFFLINE_TYPE, None, t_s, 0.0, 0.0, f"{device_id} back online")
    msg = f"{device_id} offline: liveliness token lost (no data from it since)"
    return Condition(device_id, OFFLINE_TYPE, Severity.MAJOR, t_s, 0.0, 0.0, msg)
