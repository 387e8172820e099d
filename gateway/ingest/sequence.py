"""Sequence tracking of one device stream: loss, duplicates, reordering, reboots and a second publisher on a key.

Moved here from `gateway.schemas` (which now holds only the wire protocol): the gateway's ingest is its one user.
Arithmetic is modulo 2**32 (`schemas.UINT32`), the range of `seq` on the wire.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Final, Literal, TypeAlias

from gateway.schemas import UINT32

SeqStatus: TypeAlias = Literal["first", "ok", "lost", "duplicate", "reordered", "reboot", "conflict", "rival"]


@dataclass(frozen=True, slots=True)
class SeqResult:
    """Classification of one arriving packet; `lost` = packets newly found missing before this one (status lost)."""

    status: SeqStatus
    lost: int = 0

    @property
    def accept(self) -> bool:
        """True when the packet carries new data of the followed stream (not a duplicate, not the rival's)."""
        return self.status not in ("duplicate", "rival")

    @property
    def conflict(self) -> bool:
        """True when the packet shows a second publisher on the key (`conflict` or `rival`)."""
        return self.status in ("conflict", "rival")


SEQ_OK: Final = SeqResult("ok")
"""The result of the next packet of the followed stream (nearly every packet): one shared instance, not one each."""

REORDER_WINDOW: Final = 1024
"""Packets behind the newest that can still be a late (reordered) one; a jump ahead by this many or more is a jump."""
CONFLICT_EVIDENCE: Final = 2
"""New packets of the boot left behind, after a reboot, that prove it still publishes (one can be a late packet)."""


@dataclass
class SequenceTracker:
    """Classifies each packet's (boot_id, seq) of ONE device stream: ok, lost(n), duplicate, reordered, reboot, and
    conflict / rival when two publishers share the key.

    Arithmetic is modulo 2**32 so the wrap 0xFFFFFFFF -> 0 is ordinary. A seq ahead of the newest by d
    (0 < d < 2**31) is new; d - 1 packets were lost. A seq behind the newest within `window` is `reordered`
    if unseen (one previously lost packet arrived late: the counters subtract it from `lost`), else `duplicate`;
    further behind is counted as duplicate (too old to tell). A new boot_id restarts the stream (`reboot`);
    late packets of the boot before are stale and counted as duplicates.

    Two publishers: a real reboot silences the boot before it. When that boot instead goes on with new seqs
    (`CONFLICT_EVIDENCE` of them) another publisher is using the key (a spoofer, or two devices with one id). The
    tracker then goes back to the boot it followed first (`conflict`: this packet is accepted) and from then on
    classifies the newcomer's boot as `rival` (dropped, counted in `conflicts`): a forged boot_id can no longer
    make the real stream look stale. The same holds within one boot: after a jump ahead by `window` or more, when
    the sequence left behind goes on (`CONFLICT_EVIDENCE` packets), the tracker follows it again and packets near
    the jumped-to sequence are `rival`. A reboot after a boot that delivered fewer than `CONFLICT_EVIDENCE` packets
    (boots flapping, e.g. a spoofer with a new boot_id per packet) is accepted but reported as `conflict`.
    Which publisher is genuine cannot be known without authentication (zenoh access control, docs/security.md);
    the gateway raises a `device_conflict` alarm.
    Counters accumulate in `ok`, `lost`, `duplicates`, `reordered`, `reboots`, `conflicts`.
    """

    window: int = REORDER_WINDOW
    boot_id: int | None = None
    previous_boot_id: int | None = None
    previous_newest: int = 0
    previous_fresh: int = 0
    rival_boot_id: int | None = None
    jumped_from: int | None = None  # newest seq before the last jump ahead by >= window (same boot)
    jump_lost: int = 0
    jump_fresh: int = 0
    rival_seq: tuple[int, int] | None = None  # (boot, newest seq) of a second publisher using the same boot_id
    _boot_ok0: int = 0  # `ok` when the current boot started
    newest: int = 0
    _seen: set[int] = field(default_factory=set)
    ok: int = 0
    lost: int = 0
    duplicates: int = 0
    reordered: int = 0
    reboots: int = 0
    conflicts: int = 0

    def update(self, boot_id: int, seq: int) -> SeqResult:
        """Classify one packet and update the counters."""
        if boot_id == self.rival_boot_id and boot_id != self.boot_id:
            self.conflicts += 1
            return SeqResult("rival")
        if boot_id == self.previous_boot_id and boot_id != self.boot_id:
            ahead = (seq - self.previous_newest) % UINT32
            if 0 < ahead < UINT32 // 2:  # the boot left behind goes on: is it a second publisher?
                self.previous_newest = seq
                self.previous_fresh += 1
                if self.previous_fresh >= CONFLICT_EVIDENCE:
                    return self._resume_previous(seq)
            self.duplicates += 1  # a straggler from before the reboot: stale, not a second reboot
            return SeqResult("duplicate")
        if self.rival_seq is not None and boot_id == self.rival_seq[0]:
            d = (seq - self.rival_seq[1]) % UINT32
            if d < self.window or UINT32 - d < self.window:  # near the rival's sequence, not ours
                if 0 < d < self.window:
                    self.rival_seq = (boot_id, seq)
                self.conflicts += 1
                return SeqResult("rival")
        if self.boot_id is None or boot_id != self.boot_id:
            self.jumped_from = None
            self.previous_boot_id, self.previous_newest, self.previous_fresh = self.boot_id, self.newest, 0
            status: SeqStatus = "first" if self.boot_id is None else "reboot"
            if status == "reboot":
                self.reboots += 1
                if self.ok - self._boot_ok0 < CONFLICT_EVIDENCE:  # boots flapping: more than one publisher
                    status = "conflict"
                    self.conflicts += 1
            self.boot_id, self.newest, self._seen, self._boot_ok0 = boot_id, seq, {seq}, self.ok
            self.ok += 1
            return SeqResult(status)
        ahead = (seq - self.newest) % UINT32
        if ahead == 0:
            self.duplicates += 1
            return SeqResult("duplicate")
        if ahead < UINT32 // 2:
            if ahead >= self.window:  # a big jump: remember where from, in case that sequence goes on
                self.jumped_from, self.jump_lost, self.jump_fresh = self.newest, ahead - 1, 0
            self.newest = seq
            self._remember(seq)
            self.ok += 1
            if ahead > 1:
                self.lost += ahead - 1
                return SeqResult("lost", ahead - 1)
            return SEQ_OK
        behind = (self.newest - seq) % UINT32
        if behind < self.window and seq not in self._seen:
            self._remember(seq)
            self.reordered += 1
            self.lost = max(0, self.lost - 1)
            self.ok += 1
            return SeqResult("reordered")
        if self.jumped_from is not None and 0 < (seq - self.jumped_from) % UINT32 < self.window:
            self.jumped_from = seq  # the sequence left behind by the jump goes on: a second publisher?
            self.jump_fresh += 1
            if self.jump_fresh >= CONFLICT_EVIDENCE:
                return self._resume_sequence(boot_id, seq)
        self.duplicates += 1
        return SeqResult("duplicate")

    def _resume_sequence(self, boot_id: int, seq: int) -> SeqResult:
        """Two publishers with one boot_id (one jumped the seq ahead): follow the sequence seen first again."""
        self.rival_seq = (boot_id, self.newest)
        self.lost = max(0, self.lost - self.jump_lost)  # the jump's gap was not loss
        self.newest, self._seen, self.jumped_from = seq, {seq}, None
        self.conflicts += 1
        self.ok += 1
        return SeqResult("conflict")

    def _resume_previous(self, seq: int) -> SeqResult:
        """Two publishers: follow the boot seen first again; the newcomer's boot becomes the rival."""
        self.rival_boot_id = self.boot_id
        self.boot_id, self.previous_boot_id, self.previous_fresh = self.previous_boot_id, None, 0
        self.newest, self._seen, self._boot_ok0 = seq, {seq}, self.ok
        self.reboots = max(0, self.reboots - 1)  # it was not a reboot
        self.conflicts += 1
        self.ok += 1
        return SeqResult("conflict")

    def _remember(self, seq: int) -> None:
        self._seen.add(seq)
        if len(self._seen) > 2 * self.window:
            self._seen = {s for s in self._seen if (self.newest - s) % UINT32 < self.window}

