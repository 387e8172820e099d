"""A device kind that exists only in the tests: a wave buoy with an IMU, to prove that a kind is one handler module
plus one row in the kind table (docs/design.md, "Adding a device kind").

The buoy's IMU packets are fused like any other; its own logic is the tilt of its mast (body z) from the vertical,
published as `BuoyTilt` messages at packet ends, and a `capsize` alarm above `tilt_warn_deg`.
"""

from __future__ import annotations

import math
from typing import Any, ClassVar

import numpy as np
from pydantic import BaseModel, ConfigDict, Field

from gateway import schemas
from gateway.alarm.engine import Condition, Severity
from gateway.kinds import KINDS, KindRow
from gateway.kinds.base import FusedDevice, KindBase, KindBatch, KindContext, Output, Published, Timed, timed


class BuoyThresholds(BaseModel):
    """The buoy's configuration: defaults + per-device overrides go through `Pipeline.effective` like a rod's."""

    model_config = ConfigDict(frozen=True, extra="forbid")

    tilt_warn_deg: float = Field(default=45.0, gt=0.0, le=180.0)


class BuoyTilt(schemas.WireModel):
    """The buoy's output message, on its own topic row (a built-in kind's row goes in `schemas.TOPICS`)."""

    device_id: str
    seq: int
    t_us: int
    tilt_rad: float


T_BUOY_TILT = schemas.Topic("buoy_tilt", "gw/{kind}/{id}/tilt", ("buoy",), BuoyTilt, schemas.ENCODING_GW, "output")


class BuoyKind(KindBase):
    name: ClassVar[str] = "buoy"
    # Attitude/Height would need "buoy" among their wire kinds (a row of the protocol's Topic table, which these
    # tests cannot add): until then the buoy publishes only its own message.
    imu_outputs: ClassVar[bool] = False

    def __init__(self) -> None:
        self.capsized: dict[str, bool] = {}

    def thresholds_model(self) -> type[BaseModel]:
        return BuoyThresholds

    def new_state(self, ctx: KindContext, dev: FusedDevice, th: Any) -> dict[str, float]:
        return {"warn_rad": math.radians(th.tilt_warn_deg)}

    def apply(self, ctx: KindContext, dev: FusedDevice, th: Any) -> bool:
        dev.state["warn_rad"] = math.radians(th.tilt_warn_deg)
        return True

    def post(self, ctx: KindContext, kb: KindBatch, now_s: float, out: Output) -> list[Timed]:
        x, y = kb.q[:, 1], kb.q[:, 2]
        tilt = np.arccos(np.clip(1.0 - 2.0 * (x * x + y * y), -1.0, 1.0))  # all buoys at once: angle of body z
        conds: list[Timed] = []
        for i, f in enumerate(kb.items):
            rows, dev = kb.rows(i), f.dev
            out.extra += [Published(T_BUOY_TILT, "buoy", dev.device_id, BuoyTilt(
                device_id=dev.device_id, seq=seq, t_us=t_us, tilt_rad=float(tilt[rows][j]))) for j, seq, t_us in f.ends]
            over = bool(tilt[rows].max() > dev.state["warn_rad"])
            if over != self.capsized.get(dev.device_id, False):
                self.capsized[dev.device_id] = over
                sev = Severity.WARNING if over else None
                conds += timed(dev, [Condition(dev.device_id, "capsize", sev, float(f.t_s[-1]),
                                               value=float(tilt[rows].max()))])  # fmt: skip
        return conds


ROW = KindRow("buoy", lambda _: BuoyKind())  # the one row a real kind adds to gateway.kinds.KINDS
TABLE = (*KINDS, ROW)
