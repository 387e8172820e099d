"""Which shard serves which device: rendezvous (highest-random-weight) hashing over the live shard set.

Every shard sees the same live set (zenoh liveliness tokens `gw/shard/{shard_id}/{devices}`), so every shard
computes the same owner for a device without talking to the others. When a shard leaves, only its devices move
(each to the shard with the next-highest weight); when one joins, it takes about 1/N of the devices.

A shard may be limited to device ids matching glob patterns (`--devices 'site1-*'`); a device is then shared out
only among the live shards whose patterns match it. The patterns travel in the token key, hex-encoded (a key chunk
cannot hold `*`), so the others know them too. Pure: no I/O, no clocks.
"""

from __future__ import annotations

import fnmatch
import hashlib
import re
from collections.abc import Iterable
from dataclasses import dataclass

SHARD_TOKEN_PREFIX = "gw/shard"
SEL_SHARD_TOKENS = "gw/shard/*/*"  # gw/shard/{shard_id}/{hex patterns | all}
ALL_DEVICES = "all"
SHARD_ID_RE = re.compile(r"^[A-Za-z0-9_-]{1,64}$")


@dataclass(frozen=True, slots=True)
class ShardInfo:
    """A live shard: its id and the device-id glob patterns it serves (empty: every device)."""

    shard_id: str
    patterns: tuple[str, ...] = ()

    def serves(self, device_id: str) -> bool:
        return not self.patterns or any(fnmatch.fnmatchcase(device_id, p) for p in self.patterns)

    @property
    def token_key(self) -> str:
        """The liveliness key this shard declares."""
        chunk = ALL_DEVICES if not self.patterns else "\n".join(self.patterns).encode().hex()
        return f"{SHARD_TOKEN_PREFIX}/{self.shard_id}/{chunk}"

    @classmethod
    def from_token_key(cls, key: str) -> ShardInfo | None:
        """Inverse of `token_key`; None for a key that is not a shard token (ignored)."""
        parts = key.split("/")
        if len(parts) != 4 or "/".join(parts[:2]) != SHARD_TOKEN_PREFIX or not SHARD_ID_RE.match(parts[2]):
            return None
        if parts[3] == ALL_DEVICES:
            return cls(parts[2])
        try:
            patterns = tuple(bytes.fromhex(parts[3]).decode().split("\n"))
        except ValueError:
            return None
        return cls(parts[2], patterns)


def weight(shard_id: str, device_id: str) -> int:
    """The rendezvous weight of (shard, device): a 64-bit hash, the same on every machine and Python run."""
    digest = hashlib.blake2b(f"{shard_id}\x00{device_id}".encode(), digest_size=8).digest()
    return int.from_bytes(digest, "big")


def owner_of(device_id: str, shards: Iterable[ShardInfo]) -> str | None:
    """The shard that serves `device_id`: the highest weight among the shards that serve its id (ties, which need
    a 64-bit collision, go to the smaller shard id); None when no live shard serves it."""
    best: tuple[int, str] | None = None
    for s in shards:
        if s.serves(device_id):
            cand = (weight(s.shard_id, device_id), s.shard_id)
            if best is None or cand[0] > best[0] or (cand[0] == best[0] and cand[1] < best[1]):
                best = cand
    return None if best is None else best[1]


def glob_to_key_chunk(pattern: str) -> str | None:
    """A device-id glob as a zenoh key-expression chunk (`site1-*` -> `site1-$*`, `*` -> `*`), or None when it
    cannot be one (`?`, `[...]`): the shard then subscribes to every device and filters by id itself."""
    if any(c in pattern for c in "?[]") or not pattern:
        return None
    if pattern == "*":
        return "*"
    return pattern.replace("*", "$*")


class Ownership:
    """This shard's view: the live shards and, cached per device, whether this shard serves it.

    `owns` is called for every packet on zenoh's threads: a dict lookup after the first call per device. `update`
    (on the event loop) swaps in a new cache, so a concurrent `owns` sees the old or the new one, never a mix."""

    def __init__(self, me: ShardInfo) -> None:
        self.me = me
        self.live: dict[str, ShardInfo] = {me.shard_id: me}
        self._cache: dict[str, bool] = {}

    def owns(self, device_id: str) -> bool:
        hit = self._cache.get(device_id)
        if hit is None:
            hit = owner_of(device_id, self.live.values()) == self.me.shard_id
            self._cache[device_id] = hit
        return hit

    def owner(self, device_id: str) -> str | None:
        return owner_of(device_id, self.live.values())

    def update(self, info: ShardInfo, alive: bool) -> bool:
        """A shard token appeared or vanished; True when the live set changed. This shard stays in its own set
        (its token is declared for as long as it runs)."""
        if info.shard_id == self.me.shard_id:
            return False
        if alive == (self.live.get(info.shard_id) == info):
            return False
        live = dict(self.live)
        if alive:
            live[info.shard_id] = info
        else:
            live.pop(info.shard_id, None)
        self.live = live
        self._cache = {}
        return True
