"""A device's real sample rate, measured from its packets' `t0_us`, for devices whose `rate_hz` is not what they
sample at.

Why: fusion integrates the gyroscope with dt = 1 / `rate_hz`. A device that declares its IMU's nominal output rate
while the IMU's own oscillator runs a little off (an MPU-6050's internal clock is specified to ±2 % over temperature;
a recording replayed with its rate rounded) turns every rotation into a scaled one: on BROAD's 15 real trials the
default filter's total RMSE goes 1.79° → 3.45° with rate_hz 1 % high and → 5.75° at 2 % (VQF 2.63° → 5.65° / 9.54°;
`python -m bench.rate_mismatch`).
The device's `t0_us` (its microsecond clock, a crystal) says how fast the samples really come.

How: within one boot, the samples from an anchor packet to the newest (by `seq`, lost packets included) over the
`t0_us` between them (`SampleRateMeter`): a `t0_us` stamped with jitter (docs/protocol.md: up to ±25 ms) costs only
the two ends, ±18 ms over the 20-s minimum is 0.09 %. Old evidence fades (both sums halve once they hold `FORGET_S`)
so a rate that drifts with temperature is followed. The measured rate replaces `rate_hz` when it differs
from it by more than `APPLY_REL` (0.1 %) and by more than twice what jitter could explain, and stops replacing it
below `RELEASE_REL` (0.05 %): a device whose two clocks agree is fused as declared, bit for bit.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Final

from gateway.fusion.gaps import JITTER_TOL_S
from gateway.ingest.sequence import REORDER_WINDOW
from gateway.schemas import RATE_MAX_HZ, RATE_MIN_HZ, UINT32

MIN_EVIDENCE_S: Final = 20.0
"""Device seconds of following-on packets before the measured rate is trusted."""
FORGET_S: Final = 300.0
"""When the evidence reaches this many seconds, both sums are halved (a fading memory of 5-10 minutes)."""
APPLY_REL: Final = 0.001
"""Relative difference from the declared rate above which the measured one is used (and above twice the
measurement's own uncertainty, `SampleRateMeter.uncertainty_rel`). BROAD's 15 trials lose 0.64° of total RMSE with
rate_hz 0.5 % off, so a small threshold pays."""
RELEASE_REL: Final = 0.0005
"""Relative difference below which the declared rate is used again (hysteresis)."""
REFRESH_REL: Final = 0.0005
"""A used rate is updated when the measurement has moved by more than this (not on every packet)."""
DECIDE_EVERY_US: Final = 1_000_000
"""Device time between two looks at the evidence (a packet in between costs a few comparisons, not a decision)."""
MAX_STEP_S: Final = 0.5
"""A `t0_us` step longer than the packet's span by more than this (or back by more) is a pause or a clock step, not
the sample clock: it is left out. Shorter steps back are jitter and count (the sums telescope only if they do)."""


@dataclass
class SampleRateMeter:
    """The sample rate of one device's IMU stream (see the module docstring). `update` per accepted packet, in
    arrival order; it returns the rate the pipeline should use (the declared one unless they disagree).

    Evidence comes in segments: from an anchor packet to the newest one, the samples of the packets between them (a
    lost packet counts with the size its neighbours had, when all of the segment's packets have one size) over the
    `t0_us` between them. Jitter thus costs only a segment's two ends, however many packets are lost. A pause, a clock
    step, or a loss between packets of different sizes commits the segment and opens the next."""

    boot_id: int | None = None
    declared_hz: float = 0.0
    anchor_t0_us: int = 0  # the open segment: from its first packet's t0_us ...
    open_samples: int = 0  # ... the samples up to its newest packet's t0_us
    uniform_n: int | None = None  # the packet size, while every packet of the segment had it
    last_seq: int = 0
    last_t0_us: int = 0
    last_n: int = 0
    samples: float = 0.0  # committed segments' samples, faded
    seconds: float = 0.0  # and their device seconds, faded alike
    segments: float = 0.0  # and how many segments they came from, faded alike
    used_hz: float | None = None  # the measured rate in use, None while the declared one is
    decided_us: int = -(2**62)  # t0_us of the last decision

    @property
    def evidence_s(self) -> float:
        """Device seconds of evidence: committed plus the open segment."""
        return self.seconds + (self.last_t0_us - self.anchor_t0_us) * 1e-6

    @property
    def uncertainty_rel(self) -> float:
        """Bound of the measured rate's relative error from jitter: two ends of up to `gaps.JITTER_TOL_S` (how far a
        `t0_us` may sit from the sample clock, docs/protocol.md) per segment, independent between segments."""
        return 2.0 * JITTER_TOL_S * math.sqrt(self.segments + 1.0) / max(self.evidence_s, 1e-9)

    @property
    def measured_hz(self) -> float | None:
        """Samples per device second over the evidence, once there is `MIN_EVIDENCE_S` of it."""
        seconds = self.evidence_s
        return (self.samples + self.open_samples) / seconds if seconds >= MIN_EVIDENCE_S else None

    def _open(self, seq: int, t0_us: int, n: int) -> None:
        self.anchor_t0_us, self.open_samples, self.uniform_n = t0_us, 0, n
        self.last_seq, self.last_t0_us, self.last_n = seq, t0_us, n

    def _commit(self) -> None:
        if self.last_t0_us > self.anchor_t0_us:
            self.samples += self.open_samples
            self.seconds += (self.last_t0_us - self.anchor_t0_us) * 1e-6
            self.segments += 1.0

    def update(self, boot_id: int, seq: int, t0_us: int, n: int, rate_hz: float) -> float:
        """Take one packet (n samples from device time `t0_us`, declared `rate_hz`); the rate to fuse it at."""
        if boot_id != self.boot_id or rate_hz != self.declared_hz:  # a new timeline or a new configuration
            self.boot_id, self.declared_hz = boot_id, rate_hz
            self.samples = self.seconds = self.segments = 0.0
            self.used_hz = None
            self.decided_us = -(2**62)
            self._open(seq, t0_us, n)
            return rate_hz
        ahead = (seq - self.last_seq) % UINT32
        if not 0 < ahead < REORDER_WINDOW:  # as `ingest.sequence` tells a jump
            return self._decide(rate_hz)  # a late (reordered) packet, or a far jump: no evidence either way
        step_s = (t0_us - self.last_t0_us) * 1e-6
        known = ahead == 1 or self.uniform_n == self.last_n == n  # lost packets count when all have one size
        if known and -MAX_STEP_S < step_s <= ahead * self.last_n / rate_hz + MAX_STEP_S:
            self.open_samples += ahead * self.last_n
            if n != self.uniform_n:
                self.uniform_n = None
            self.last_seq, self.last_t0_us, self.last_n = seq, t0_us, n
        else:  # a pause, a clock step, or lost packets of unknown size: a new segment from here
            self._commit()
            self._open(seq, t0_us, n)
        if self.evidence_s >= FORGET_S:
            self._commit()
            self.samples *= 0.5
            self.seconds *= 0.5
            self.segments *= 0.5
            self._open(seq, t0_us, n)
        if 0 <= t0_us - self.decided_us < DECIDE_EVERY_US:  # the decision is revisited once a device second
            return rate_hz if self.used_hz is None else self.used_hz
        self.decided_us = t0_us
        return self._decide(rate_hz)

    def _decide(self, rate_hz: float) -> float:
        measured = self.measured_hz
        if measured is None:
            return rate_hz if self.used_hz is None else self.used_hz
        measured = min(max(measured, RATE_MIN_HZ), RATE_MAX_HZ)  # the wire's range, whatever the clock says
        off = abs(measured / rate_hz - 1.0)
        if self.used_hz is None:
            if off > max(APPLY_REL, 2.0 * self.uncertainty_rel):
                self.used_hz = measured
        elif off < RELEASE_REL:
            self.used_hz = None
        elif abs(measured / self.used_hz - 1.0) > REFRESH_REL:
            self.used_hz = measured
        return rate_hz if self.used_hz is None else self.used_hz
