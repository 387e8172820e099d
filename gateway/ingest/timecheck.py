"""Time sanity of device packets: schema-valid but extreme timestamps must cost only that device's output.

The wire schema allows any `t0_us` / `wall_t0_us` in [0, 2**63). Fusion and the rules work in float seconds and the
outputs add the device's wall offset to its device time, so some valid values break them: a `wall_t0_us` of 0 or
2**63 - 1 makes an output time negative or past 2**63, a `t0_us` near 2**63 leaves float seconds without sample
resolution, and a block whose time runs backwards overflows the rules' exponential decay. Checked here, once per
packet, before the pipeline:

| check | verdict | reason counted |
|---|---|---|
| packet end `t0_us + (n-1)/rate` >= `MAX_DEVICE_TIME_US` (2**53 µs, 285 years since boot) | dropped | `time_range` |
| `wall_t0_us` more than `MAX_WALL_SKEW_S` from the gateway's clock | kept without its wall time | `wall_time_ignored` |
| same boot, `t0_us` more than `MAX_BACK_S` before the newest packet's end | dropped | `time_backwards` |
| same boot, `t0_us` more than `MAX_JUMP_S` after the newest packet's end | dropped | `time_jump` |

A device whose clock really did jump (without a new boot_id) is not silenced: after `RESYNC_PACKETS` dropped packets
that agree with each other, the new timeline is taken and the device's fusion restarts from a fresh warm-up.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Final

MAX_DEVICE_TIME_US = 2**53
MAX_WALL_SKEW_S = 7 * 86400.0
MAX_BACK_S = 2.0
MAX_JUMP_S = 3600.0
RESYNC_PACKETS = 3
RESYNC_STEP_S = 10.0  # consecutive dropped packets agree when each starts within this of the previous one's end


@dataclass(frozen=True, slots=True)
class TimeVerdict:
    """`reason` None: accept. `restart`: accepted on a new timeline, the device's fusion must restart first."""

    reason: str | None = None
    restart: bool = False

    @property
    def accept(self) -> bool:
        return self.reason is None or self.restart


ACCEPTED: Final = TimeVerdict()
"""The verdict of a packet on the device's timeline (nearly every packet): one shared instance, not one each."""


@dataclass
class DeviceClock:
    """Device-time bookkeeping of one device's IMU stream (see module docstring)."""

    boot_id: int | None = None
    end_us: int = 0
    pending: list[int] = field(default_factory=list)  # ends of consecutive dropped packets that agree

    def check(self, boot_id: int, t0_us: int, end_us: int) -> TimeVerdict:
        """Classify one packet (already sequence-checked as new data) spanning device time [t0_us, end_us]."""
        if end_us >= MAX_DEVICE_TIME_US:
            return TimeVerdict("time_range")
        if boot_id != self.boot_id:  # a new boot starts a new timeline
            self.boot_id, self.end_us, self.pending = boot_id, end_us, []
            return ACCEPTED
        if self.end_us - MAX_BACK_S * 1e6 <= t0_us <= self.end_us + MAX_JUMP_S * 1e6:
            if end_us > self.end_us:
                self.end_us = end_us
            if self.pending:  # (not a new empty list per packet)
                self.pending = []
            return ACCEPTED
        reason = "time_backwards" if t0_us < self.end_us else "time_jump"
        prev = self.pending[-1] if self.pending else None
        if prev is not None and prev - MAX_BACK_S * 1e6 <= t0_us <= prev + RESYNC_STEP_S * 1e6:
            self.pending.append(end_us)
        else:
            self.pending = [end_us]
        if len(self.pending) >= RESYNC_PACKETS:
            self.end_us, self.pending = end_us, []
            return TimeVerdict(reason, restart=True)
        return TimeVerdict(reason)


def wall_time_plausible(wall_t0_us: int, now_s: float) -> bool:
    """True when a device's realtime clock is within `MAX_WALL_SKEW_S` of the gateway's."""
    return abs(wall_t0_us * 1e-6 - now_s) <= MAX_WALL_SKEW_S
