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
        eul, conds, max_age_s = kb.euler, [], ctx.settings.reel_max_age_s
        for i, f in enumerate(kb.items):
            dev, rows = f.dev, kb.rows(i)
            try:
                reel, tension = self.reel.get(dev.device_id), None
                if reel is not None and reel[0].tension_n is not None and now_s - reel[1] <= max_age_s:
                    tension = np.full(f.t_s.shape, reel[0].tension_n)
                st: RodState = dev.state
                # The rules decide sample by sample: a burst gives the same alarms in one call as packet by packet.
                blk, new = st.rules.update(f.t_s, eul[rows, 1], eul[rows, 0], eul[rows, 2], acc_up[rows], tension)
                st.baseline_rad = blk.baseline_rad
                if self.auto_reel.on.get(dev.device_id):
                    self.auto_reel.step(dev.device_id, float(f.t_s[-1]), float(eul[rows.stop - 1, 1]) - st.baseline_rad,
                                        reel[0] if reel else None, now_s, out)  # fmt: skip
                conds += timed(dev, new)
            except Exception as exc:  # only this rod restarts
                ctx.fail(dev, exc, out)
        return conds
