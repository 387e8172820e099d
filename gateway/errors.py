"""The gateway's error tree (wire decoding errors live with the wire models in `gateway.schemas`).

    GatewayError
    ├── UnknownDevice      no such device (REST: 404)
    ├── BadSettings        thresholds or settings that do not validate (REST: 422)
    └── NotAvailable       a feature that is not wired in this build (REST: 501)
"""

from __future__ import annotations


class GatewayError(Exception):
    """Base of every error the gateway raises on purpose."""


class UnknownDevice(GatewayError):
    """No device with this id has been seen or configured."""

    def __init__(self, device_id: str) -> None:
        super().__init__(f"unknown device {device_id!r}")
        self.device_id = device_id


class BadSettings(GatewayError):
    """Thresholds or settings that do not validate; `errors` are human-readable messages."""

    def __init__(self, errors: list[str]) -> None:
        super().__init__("; ".join(errors))
        self.errors = errors


class NotAvailable(GatewayError):
    """A feature whose module has not landed (e.g. a filter name that is not registered)."""
