"""The smart rod: bite / drop-back / line-guard rules on the fused pitch, reel status, and auto reel.

Per batch, the tip's vertical acceleration of every rod is computed in one call over the concatenated blocks;
the rules then run per rod (they keep per-device latches and decide sample by sample).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, ClassVar

import numpy as np

from gateway import schemas
from gateway.alarm.bite import tip_acc_up
from gateway.alarm.rules import RodAlarms
from gateway.config import RodThresholds
from gateway.kinds.base import FusedDevice, KindBase, KindBatch, KindContext, Output, Timed, timed

if TYPE_CHECKING:
    from pydantic import BaseModel

    from gateway.control.auto_reel import AutoReel


@dataclass
class RodState:
    """A rod's rules and the rest pitch they track."""

    rules: RodAlarms
    baseline_rad: float = float("nan")


class RodKind(KindBase):
    """Rod handler; `reel` holds each rod's latest ReelStatus and its arrival (gateway wall time)."""

    name: ClassVar[str] = "rod"
    fused: ClassVar[bool] = True
    bridge_lost_samples: ClassVar[bool] = True  # bridged with a tapered gyro: fewer false alarms (fusion.md)
    bridge_gyro_taper_s: ClassVar[float] = 0.05  # a line across a ringing tip's gap raised false bites (fusion.md)
    packet_types: ClassVar[tuple[type[Any], ...]] = (schemas.ReelStatus,)

    def __init__(self, auto_reel: AutoReel) -> None:
        self.auto_reel = auto_reel
        self.reel: dict[str, tuple[schemas.ReelStatus, float]] = {}

    def thresholds_model(self) -> type[BaseModel]:
        return RodThresholds

    def new_state(self, ctx: KindContext, dev: FusedDevice, th: Any) -> RodState:
        self.auto_reel.attach(dev.device_id)
        return RodState(RodAlarms(dev.device_id, th if isinstance(th, RodThresholds) else None))

    def apply(self, ctx: KindContext, dev: FusedDevice, th: Any) -> bool:
        if isinstance(th, RodThresholds):
            dev.state.rules.set_thresholds(th)
        return True

    def on_packet(self, ctx: KindContext, packet: Any, now_s: float) -> None:
        self.reel[packet.device_id] = (packet, now_s)

    def post(self, ctx: KindContext, kb: KindBatch, now_s: float, out: Output) -> list[Timed]:
        acc_up = tip_acc_up(kb.q, kb.acc)
        # contiguous, so each rod's slice is the block layout the bite kernel was compiled for (bite_fast.warm_up)
        pitch, conds, max_age_s = np.ascontiguousarray(kb.euler[:, 1]), [], ctx.settings.reel_max_age_s
        reels, auto = self.reel, self.auto_reel.on
        # roll and yaw are not passed: the rules never use them (a rod turned about its axis is no bite)
        for f, a, b in zip(kb.items, kb.start.tolist(), kb.stop.tolist(), strict=True):
            dev = f.dev
            try:
                reel, tension = reels.get(dev.device_id), None
                if reel is not None and reel[0].tension_n is not None and now_s - reel[1] <= max_age_s:
                    tension = reel[0].tension_n  # one value for the block: the rules make an array only if needed
                st: RodState = dev.state
                # The rules decide sample by sample: a burst gives the same alarms in one call as packet by packet.
                blk, new = st.rules.update(f.t_s, pitch[a:b], None, None, acc_up[a:b], tension)
                st.baseline_rad = blk.baseline_rad
                if auto.get(dev.device_id):
                    self.auto_reel.step(dev.device_id, float(f.t_s[-1]), float(pitch[b - 1]) - st.baseline_rad,
                                        reel[0] if reel else None, now_s, out)  # fmt: skip
                if new:
                    conds += timed(dev, new)
            except Exception as exc:  # only this rod restarts
                ctx.fail(dev, exc, out)
        return conds
