"""The dashboard stream across shards: every endpoint's `/ws/stream` shows the devices of all shards.

The shard that serves a device already builds its tick entries (series since the last tick, acceleration points,
link fields, and on full ticks the device card with readings, reel state and alarms: gateway/api/ws.py). While
some other endpoint has dashboard clients, the owners publish their tick frames on `gw/shard/{id}/live` (at the
tick rate, 10 Hz; the entries are as bounded as a local client's), and that endpoint merges the other shards'
devices into the frames it sends. An endpoint asks by putting `gw/shard/{id}/want_live` once a second while
it has clients; a shard publishes its frames for `WANT_TTL_S` after the last request, so without dashboards
nothing flows.

Bounds: per remote device the samples since this endpoint's last tick (at most `series_max` per field, older ones
dropped) and its last card; at most `max_devices` remote devices. A device is forgotten as soon as its shard leaves
the live set or another shard serves it, and after `STALE_S` without a frame from its shard.
"""

from __future__ import annotations

import json
import logging
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

from gateway import schemas
from gateway.ingest.bus import Bus
from gateway.shard.ownership import Ownership

log = logging.getLogger("gateway.shard")
WANT_EVERY_S = 1.0
WANT_TTL_S = 3.0
STALE_S = 5.0
SAMPLE_KEYS = ("series", "acc")  # columnar samples: {"t_s": [...], field: [...]}, appended tick after tick


@dataclass
class _Remote:
    """What this endpoint holds of one device of another shard until its next tick."""

    shard: str
    kind: str
    seen_s: float
    card: dict[str, Any] | None = None
    link: dict[str, Any] | None = None
    samples: dict[str, dict[str, list[Any]]] = field(default_factory=dict)

    def add_samples(self, name: str, cols: dict[str, list[Any]], keep: int) -> None:
        mine = self.samples.setdefault(name, {})
        for k, v in cols.items():
            col = mine.setdefault(k, [])
            col.extend(v)
            if len(col) > keep:
                del col[: len(col) - keep]

    def take(self, device_id: str, full: bool) -> dict[str, Any]:
        """The entry of this endpoint's tick (as LiveStream builds for its own devices); the samples are moved."""
        entry: dict[str, Any] = dict(self.card) if full and self.card is not None else {}
        entry.update(device_id=device_id, kind=self.kind)
        entry["series"] = self.samples.pop("series", None) or {"t_s": []}
        acc = self.samples.pop("acc", None)
        if acc is not None:
            entry["acc"] = acc
        if self.link:
            entry["link"] = self.link
        return entry


class LivePeers:
    """The `Peers` of a shard's LiveStream (gateway/api/ws.py). Bus callbacks only hand the payload to the event
    loop (`call_soon`); everything else runs there."""

    def __init__(
        self, bus: Bus, ownership: Ownership, shard_id: str, call_soon: Callable[..., Any], series_max: int = 200,
        max_devices: int = 2048, clock: Callable[[], float] = time.monotonic,
    ) -> None:  # fmt: skip
        self.bus = bus
        self.ownership = ownership
        self.shard_id = shard_id
        self.call_soon = call_soon
        self.series_max = series_max
        self.max_devices = max_devices
        self.clock = clock
        self.remote: dict[str, _Remote] = {}
        self.spots: dict[str, tuple[float, list[dict[str, Any]]]] = {}  # shard -> (seen, its ranking)
        self.frames_in = 0
        self.frames_out = 0
        self._wanted_until = -1.0
        self._asked_s = -WANT_EVERY_S

    def key(self, leaf: str) -> str:
        return f"gw/shard/{self.shard_id}/{leaf}"

    def subscribe(self) -> None:
        self.bus.subscribe("gw/shard/*/want_live", self._on_want)
        self.bus.subscribe("gw/shard/*/live", self._on_frame)

    # -- bus threads ----------------------------------------------------------------------------------------

    def _on_want(self, key: str, payload: bytes) -> None:
        if key != self.key("want_live"):
            self.call_soon(self._wanted)

    def _on_frame(self, key: str, payload: bytes) -> None:
        if key != self.key("live"):
            self.call_soon(self.take_frame, key.split("/")[2], payload)

    # -- event loop ---------------------------------------------------------------------------------------------

    def _wanted(self) -> None:
        self._wanted_until = self.clock() + WANT_TTL_S

    def wanted(self) -> bool:
        """Another endpoint has dashboard clients: publish this shard's frames."""
        return self.clock() < self._wanted_until

    def publish(self, frame: dict[str, Any]) -> None:
        """This shard's tick frame (its own devices only) for the other endpoints."""
        self.bus.put(self.key("live"), json.dumps(frame, separators=(",", ":"), default=str).encode(),
                     encoding=schemas.ENCODING_GW)  # fmt: skip
        self.frames_out += 1

    def listening(self, has_clients: bool) -> None:
        """Every tick: ask the others for their frames while this endpoint has clients; forget stale devices."""
        now = self.clock()
        if has_clients and now - self._asked_s >= WANT_EVERY_S:
            self._asked_s = now
            self.bus.put(self.key("want_live"), b"{}", encoding=schemas.ENCODING_GW)
        self.prune(now)

    def prune(self, now: float) -> None:
        live = self.ownership.live
        for d in [d for d, r in self.remote.items() if r.shard not in live or now - r.seen_s > STALE_S
                  or self.ownership.owner(d) != r.shard]:  # fmt: skip
            del self.remote[d]
        for s in [s for s, (seen, _) in self.spots.items() if s not in live or now - seen > STALE_S]:
            del self.spots[s]

    def take_frame(self, shard: str, payload: bytes) -> None:
        """Buffer another shard's tick frame: the samples of its devices, their last cards, its spot ranking."""
        if shard not in self.ownership.live:
            return
        try:
            frame = json.loads(payload)
            entries = frame["devices"]
        except (ValueError, KeyError, TypeError):
            log.warning("bad live frame from shard %s", shard[:64])
            return
        now = self.clock()
        self.frames_in += 1
        for e in entries:
            device_id = e.get("device_id") if isinstance(e, dict) else None
            if not isinstance(device_id, str) or self.ownership.owner(device_id) != shard:
                continue  # a frame sent just before the device moved: its new owner's frames follow
            r = self.remote.get(device_id)
            if r is None or r.shard != shard:
                if r is None and len(self.remote) >= self.max_devices:
                    continue
                r = self.remote[device_id] = _Remote(shard, str(e.get("kind")), now)
            r.seen_s = now
            for name in SAMPLE_KEYS:
                if isinstance(e.get(name), dict):
                    r.add_samples(name, e[name], self.series_max)
            if isinstance(e.get("link"), dict):
                r.link = e["link"]
            if "online" in e:  # a full card
                r.card = {k: v for k, v in e.items() if k not in (*SAMPLE_KEYS, "link")}
        if isinstance(frame.get("spots"), list):
            self.spots[shard] = (now, frame["spots"])

    def merge(self, frame: dict[str, Any]) -> None:
        """Add the other shards' devices (samples since the last tick; cards on full ticks) and spots."""
        full = bool(frame.get("full"))
        for device_id in sorted(self.remote):
            frame["devices"].append(self.remote[device_id].take(device_id, full))
        if full and self.spots:
            frame["spots"] = merge_spots([frame.get("spots") or [], *(s for _, s in self.spots.values())])


def merge_spots(rankings: list[list[dict[str, Any]]]) -> list[dict[str, Any]]:
    """One ranking from the shards' rankings (each of its own balls): best score first, a spot once (its best),
    ranks renumbered from 1."""
    best: dict[str, dict[str, Any]] = {}
    for ranking in rankings:
        for s in ranking:
            cur = best.get(s["spot"])
            if cur is None or s["score"] > cur["score"]:
                best[s["spot"]] = s
    out = sorted(best.values(), key=lambda s: (-s["score"], s["spot"]))
    return [{**s, "rank": i} for i, s in enumerate(out, start=1)]
