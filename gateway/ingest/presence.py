"""Device presence from zenoh liveliness tokens `rig/{kind}/{id}`: online on PUT, offline on DELETE.

zenoh reports a token's DELETE when its session closes or the link times out (about 1 s on loopback with the
default lease), so a vanished device goes offline within that time. Pure bookkeeping: times are passed in.
"""

from __future__ import annotations

from dataclasses import dataclass

from gateway import schemas


def token_device(key: str) -> tuple[str, str] | None:
    """(kind, device id) of a device token key `rig/{kind}/{id}` with a known kind, else None; the id is not checked
    (`schemas.valid_device_id`)."""
    parts = key.split("/")
    if len(parts) != 3 or parts[0] != "rig" or parts[1] not in schemas.KINDS:
        return None
    return parts[1], parts[2]


@dataclass
class DevicePresence:
    """Online flag and when it last changed (wall seconds)."""

    kind: str
    device_id: str
    online: bool
    since_s: float


class Presence:
    """Device id -> presence; `update` returns the new state when it changed (for the event log), else None."""

    def __init__(self) -> None:
        self.devices: dict[str, DevicePresence] = {}
        self.invalid_tokens = 0  # tokens whose key is not `rig/{kind}/{valid device id}` (ignored)

    def update(self, token_key: str, alive: bool, now_s: float) -> DevicePresence | None:
        dev = token_device(token_key)
        if dev is None:
            return None
        kind, device_id = dev
        if not schemas.valid_device_id(device_id):  # e.g. `rig/rod/evil.tok`: it would break key building later
            self.invalid_tokens += 1
            return None
        cur = self.devices.get(device_id)
        if cur is not None and cur.online == alive:
            return None
        state = DevicePresence(kind, device_id, alive, now_s)
        self.devices[device_id] = state
        return state

    def online(self, device_id: str) -> bool:
        p = self.devices.get(device_id)
        return p is not None and p.online
