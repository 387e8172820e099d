"""Filters by name, for the evaluate command, benches and the gateway's per-device choice."""

from __future__ import annotations

import importlib

from gateway.fusion.base import AttitudeFilter

# name -> "module:ClassName"; the class takes keyword `use_mag`. Imported lazily, so modules stay independent.
FILTERS: dict[str, str] = {
    "default": "gateway.fusion.default:DefaultFilter",
    "mahony": "gateway.fusion.mahony:MahonyFilter",
    "complementary": "gateway.fusion.complementary:ComplementaryFilter",
    "adaptive": "gateway.fusion.complementary:AdaptiveComplementaryFilter",
    "hook": "gateway.fusion.hook_filter:HookFilter",
    "kf": "gateway.fusion.kf:KalmanAngleFilter",
    "ekf": "gateway.fusion.ekf:QuaternionEkf",
}


def make_filter(name: str, *, use_mag: bool = True) -> AttitudeFilter:
    """Build a filter by registered name; raises KeyError listing the known names."""
    try:
        target = FILTERS[name]
    except KeyError:
        raise KeyError(f"unknown filter {name!r}; known: {', '.join(sorted(FILTERS))}") from None
    module_name, class_name = target.split(":")
    cls = getattr(importlib.import_module(module_name), class_name)
    instance: AttitudeFilter = cls(use_mag=use_mag)
    return instance
