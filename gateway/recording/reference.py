"""Reference (ground-truth) packets of imported real recordings: `rig/{kind}/{id}/reference`.

The simulators' truth packets (`rig.truth.v1`) need unit quaternions and simulator fields; an optical reference
has gaps (markers lost) and a scoring mask instead. One ReferencePacket mirrors one ImuPacket: same `boot_id`,
`seq`, `t0_us`, `rate_hz` and sample count, so data and reference join on `(device_id, boot_id, seq)`.
The gateway does not subscribe to this key; the `score` command reads it.
"""

from __future__ import annotations

from typing import Final, Literal

from pydantic import BaseModel, ConfigDict, Field

ENCODING_REFERENCE: Final = "application/json;schema=rig.reference.v1"
TOPIC: Final = "reference"


def reference_key(kind: str, device_id: str) -> str:
    """`rig/{kind}/{id}/reference`."""
    return f"rig/{kind}/{device_id}/{TOPIC}"


class ReferencePacket(BaseModel):
    """Optical reference per IMU sample: attitude body -> ENU (null where lost), position (m), scoring mask."""

    model_config = ConfigDict(strict=True, frozen=True, extra="forbid")

    v: Literal[1] = 1
    device_id: str
    kind: str
    boot_id: int = Field(ge=0, lt=2**32)
    seq: int = Field(ge=0, lt=2**32)
    t0_us: int = Field(ge=0)
    rate_hz: float = Field(gt=0.0)
    quat_wxyz: list[tuple[float, float, float, float] | None]
    pos_m: list[tuple[float, float, float] | None] | None = None
    movement: list[bool]
    source: str | None = None
