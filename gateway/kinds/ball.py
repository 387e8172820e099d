"""The environment ball: latest readings per ball, and the spot ranking (at most every `spots_interval_s`)."""

from __future__ import annotations

import math
import time
from typing import TYPE_CHECKING, Any, ClassVar

import numpy as np

from gateway import schemas
from gateway.config import SpotPreferences
from gateway.kinds.base import KindBase, KindContext, Output
from gateway.spots import SpotReading, rank_spots

if TYPE_CHECKING:
    from pydantic import BaseModel


def thermocline_m(profile: list[schemas.ProfilePoint] | None) -> float | None:
    """Depth of the steepest temperature drop in a profile (None without at least 3 levels)."""
    if not profile or len(profile) < 3:
        return None
    pts = sorted(profile, key=lambda p: p.depth_m)
    grads = [
        (a.water_temp_c - b.water_temp_c) / max(b.depth_m - a.depth_m, 1e-6) for a, b in zip(pts, pts[1:], strict=False)
    ]
    i = int(np.argmax(grads))
    return 0.5 * (pts[i].depth_m + pts[i + 1].depth_m)


def _position(fix: schemas.GnssFix | None) -> dict[str, float]:
    """A spot's `lat_deg`/`lon_deg` from its ball's GNSS fix (none without a fix or with fix quality 0)."""
    return {} if fix is None or fix.fix_quality == 0 else {"lat_deg": fix.lat_deg, "lon_deg": fix.lon_deg}


class BallKind(KindBase):
    """Ball handler; `env` holds each ball's latest EnvPacket."""

    name: ClassVar[str] = "ball"
    fused: ClassVar[bool] = False
    packet_types: ClassVar[tuple[type[Any], ...]] = (schemas.EnvPacket,)

    def __init__(self) -> None:
        self.env: dict[str, schemas.EnvPacket] = {}
        self._last_spots_s = -math.inf
        self._dirty = False

    def thresholds_model(self) -> type[BaseModel]:
        return SpotPreferences

    def on_packet(self, ctx: KindContext, packet: Any, now_s: float) -> None:
        self.env[packet.device_id] = packet
        self._dirty = True

    def end_batch(self, ctx: KindContext, now_s: float, out: Output) -> None:
        if self._dirty and now_s - self._last_spots_s >= ctx.settings.spots_interval_s:
            out.spots = self.rank(now_s, ctx.thresholds(self.name, None))  # type: ignore[arg-type]
            self._last_spots_s, self._dirty = now_s, False

    def rank(self, now_s: float, prefs: SpotPreferences) -> schemas.SpotRanking:
        """Spots best first, from the latest reading at each spot (the newest ball wins a shared spot)."""
        latest: dict[str, schemas.EnvPacket] = {}
        for p in self.env.values():
            cur = latest.get(p.spot)
            if cur is None or (p.wall_t_us or 0) >= (cur.wall_t_us or 0):
                latest[p.spot] = p
        readings = [
            SpotReading(spot, p.water_temp_c, p.oxygen_mg_l, p.light_lux, p.probe_depth_m, thermocline_m(p.profile))
            for spot, p in latest.items()
        ]
        lt = time.localtime(now_s)
        ranked = rank_spots(readings, prefs, lt.tm_hour + lt.tm_min / 60.0)
        spots = [
            schemas.SpotScore(
                spot=s.spot_id, rank=i + 1, score=min(1.0, max(0.0, s.score)),
                device_id=latest[s.spot_id].device_id, last_seen_wall_us=latest[s.spot_id].wall_t_us,
                reasons=[r[:200] for r in s.reasons][:20], **_position(latest[s.spot_id].gnss),
            )
            for i, s in enumerate(ranked)
        ]  # fmt: skip
        return schemas.SpotRanking(wall_t_us=int(now_s * 1e6), spots=spots)
