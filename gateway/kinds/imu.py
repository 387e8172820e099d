"""A plain IMU (kind `imu`): live attitude and height for any small IMU device, and nothing a rod or a hook adds.

For anyone who needs attitude from many IMUs (a machine part, a tool, a limb, a recording replayed): packets on
`rig/imu/{id}/imu` are fused by the default filter (or the device's `filter_name`) and published on
`gw/imu/{id}/attitude` and `/height` like a rod's, with no alarms of its own (a rod's bite rules would read a
hand-held IMU's motion as bites). Lost samples are bridged with a straight line, not a rod's tapered gyro: the taper
is there for a ringing rod tip, and costs a smoothly turning IMU dearly (BROAD's 15 real trials with 2 % of
10-sample packets lost: docs/fusion.md, "Lost packets").
"""

from __future__ import annotations

from typing import ClassVar

from pydantic import BaseModel

from gateway.config import ImuSettings
from gateway.kinds.base import KindBase


class PlainImuKind(KindBase):
    """Attitude and height only (the pipeline's outputs of every fused kind); no rules, no state."""

    name: ClassVar[str] = "imu"
    bridge_lost_samples: ClassVar[bool] = True  # a line across the gap (no taper: see the module docstring)

    def thresholds_model(self) -> type[BaseModel]:
        return ImuSettings
