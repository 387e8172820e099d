"""Filters by name, for the evaluate command, benches, the replay view and the gateway's per-device choice.

The `-paper` names are the papers' filters as written (docs/fusion.md, "Paper variants"): `kf-paper` seed 000's
angle Kalman filter with Fig. 4's cross-product gyro correction, `ekf-paper` seed 001's quaternion EKF,
`mahony-paper` seed 004's PI filter without our integral clamp and anti-windup. `complementary` is seed 002 eq. 5
as written already.
"""

from __future__ import annotations

import importlib

from gateway.fusion.base import AttitudeFilter

# name -> "module:callable"; the callable (a class or factory) takes keyword `use_mag`. Imported lazily, so modules
# stay independent.
FILTERS: dict[str, str] = {
    "default": "gateway.fusion.default:DefaultFilter",
    "mahony": "gateway.fusion.mahony:MahonyFilter",
    "mahony-paper": "gateway.fusion.registry:mahony_paper",
    "complementary": "gateway.fusion.complementary:ComplementaryFilter",
    "adaptive": "gateway.fusion.complementary:AdaptiveComplementaryFilter",
    "hook": "gateway.fusion.hook_filter:HookFilter",
    "kf": "gateway.fusion.kf:KalmanAngleFilter",
    "kf-paper": "gateway.fusion.registry:kf_paper",
    "ekf": "gateway.fusion.ekf:QuaternionEkf",
    "ekf-paper": "gateway.fusion.registry:ekf_paper",
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
    instance.name = name
    return instance


def kf_paper(*, use_mag: bool = True) -> AttitudeFilter:
    """Seed 000's angle KF as written: no bias learning, no gates, Fig. 4's cross-product gyro correction on."""
    from gateway.fusion.kf import FIG4_KI_RAD_S2, FIG4_KP_RAD_S, KalmanAngleFilter, KfSettings

    settings = KfSettings(paper=True, fig4_kp_rad_s=FIG4_KP_RAD_S, fig4_ki_rad_s2=FIG4_KI_RAD_S2)
    return KalmanAngleFilter(settings, use_mag=use_mag)


def ekf_paper(*, use_mag: bool = True) -> AttitudeFilter:
    """Seed 001's quaternion EKF as written: no bias states, no gating, full magnetometer innovation."""
    from gateway.fusion.ekf import EkfSettings, QuaternionEkf

    return QuaternionEkf(EkfSettings(paper=True), use_mag=use_mag)


def mahony_paper(*, use_mag: bool = True) -> AttitudeFilter:
    """Seed 004's Mahony PI filter as written: the integral is neither clamped nor paused on large errors."""
    from gateway.fusion.mahony import MahonyFilter, MahonySettings

    return MahonyFilter(MahonySettings(integral_limit_rad_s=float("inf"), integral_error_max=float("inf")),
                        use_mag=use_mag)
