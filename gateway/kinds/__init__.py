"""Device kinds: one handler module per kind and one row per kind in `KINDS` (see docs/design.md, "Adding a
device kind"). The pipeline builds one handler per row; a test can pass its own table with an extra row."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import TYPE_CHECKING

from gateway.kinds.ball import BallKind
from gateway.kinds.base import DeviceKind
from gateway.kinds.hook import HookKind
from gateway.kinds.imu import PlainImuKind
from gateway.kinds.rod import RodKind

if TYPE_CHECKING:
    from gateway.control.auto_reel import AutoReel


@dataclass(frozen=True)
class KindServices:
    """What a handler may need from the gateway besides its own state."""

    auto_reel: AutoReel


@dataclass(frozen=True)
class KindRow:
    """One device kind: its wire name and how to build its handler."""

    name: str
    make: Callable[[KindServices], DeviceKind]


KINDS: tuple[KindRow, ...] = (
    KindRow("rod", lambda s: RodKind(s.auto_reel)),
    KindRow("hook", lambda s: HookKind()),
    KindRow("ball", lambda s: BallKind()),
    KindRow("imu", lambda s: PlainImuKind()),
)
