"""The compass's pull on the swing (`HookFilterSettings.mag_tilt_gain`): a field known to 0.5 µT, not to the 0.05 µT
its noise claims over 10 s, must not hold the swing off; and the suite's disturbed field (`steel_field`)."""

from __future__ import annotations

import math

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from bench.hook_suite import STEEL_MODES, STEEL_WAVELENGTH_M, simulate_seed, steel_field
from gateway.fusion import hook as hook_geo
from gateway.fusion.hook_filter import JUMP_ROPE_ROUND, TILT_GAIN_ROUND, HookFilter, HookFilterSettings
from tests.fusion.test_hook_compass import _run

RATE_HZ = 100.0


def _swing_errors_deg(seed: int, imu: str, seconds: float, calls: int, steel_uT: float = 0.0,
                      **overrides: float) -> tuple[HookFilter, np.ndarray, np.ndarray]:  # fmt: skip
    """Crane `seed` of the suite (its 120-s draws), told its rope, fed `calls` samples at a time for `seconds`: the
    filter, the sample times and the swing angle's errors (deg)."""
    case, truth, gyr, acc, mag = simulate_seed(seed, 120.0, imu, True, steel_uT=steel_uT)
    n = round(seconds * RATE_HZ)
    f = HookFilter(HookFilterSettings(rope_length_m=case.physics.rope_length_m, rope_length_known=True,
                                      **overrides))  # type: ignore[arg-type]
    q = _run(f, gyr[:n], acc[:n], mag[:n], calls)
    err = np.degrees(hook_geo.swing_angle(q) - truth.swing_rad[:n])
    return f, truth.t_s[:n], err


def test_a_sound_compass_does_not_hold_the_swing_off_through_a_trolley_cruise() -> None:
    """Fresh crane 3197 (8.8 m, legacy board, told): a trolley starts at 5 s and cruises from 6.6 s. At the full gain
    the compass held the swing's centre off (and with it a stale boom-tip acceleration) by 0.73° RMS over 9-19 s
    until the compass test dropped the sound compass at 20 s (torsion 5.6° over 2 min after); at 0.3 the swing
    follows the gyroscope (0.12°) and the compass is kept. The filter before is taken with the traverse's jump
    opening the told length by 10 % (`JUMP_ROPE_ROUND`), as it did then: either change alone keeps the compass
    (measured 0.115° at the full gain, 0.122° with the 10 % opening). 10-sample packets."""
    f, t, err = _swing_errors_deg(3197, "legacy", 25.0, 10)
    before, _, err_before = _swing_errors_deg(3197, "legacy", 25.0, 10, **TILT_GAIN_ROUND, **JUMP_ROPE_ROUND)
    cruise = (t >= 9.0) & (t < 19.0)
    rms, rms_before = (math.sqrt(float(np.mean(e[cruise] ** 2))) for e in (err, err_before))
    assert rms < 0.25 and f.compass != "dropped", (rms, f.compass)
    assert rms_before > 0.5 and before.compass == "dropped", (rms_before, before.compass)


def test_a_field_disturbed_where_the_hook_goes_pulls_the_swing_less() -> None:
    """Tuning crane 20 (calibrated board, told) in a field disturbed by 2 µT RMS where the hook goes (`steel_field`):
    whole-run Θ RMSE 0.071° against 0.135° at the full gain (undisturbed 0.064° and 0.077°)."""
    errors = {}
    for name, overrides in (("default", {}), ("full gain", TILT_GAIN_ROUND)):
        _, t, err = _swing_errors_deg(20, "calibrated", 120.0, 12_000, steel_uT=2.0, **overrides)
        errors[name] = math.sqrt(float(np.mean(err[t >= 0.5] ** 2)))
    assert errors["default"] < 0.1 and errors["default"] < 0.7 * errors["full gain"], errors


@settings(max_examples=25, deadline=None)
@given(seed=st.integers(0, 10_000), rms_uT=st.floats(0.1, 10.0))
def test_the_steel_field_has_its_rms_and_is_smooth(seed: int, rms_uT: float) -> None:
    """Over a 200-m cube the field's RMS is the one asked for (four modes: within 45 %); it is the same for the
    same seed, and no steeper than its modes allow (|Δb| ≤ Σ |k| |b| |Δp|, the shortest wavelength's |k|)."""
    rng = np.random.default_rng(seed)
    pos = rng.uniform(-100.0, 100.0, (4000, 3))
    b = steel_field(seed, pos, rms_uT)
    assert np.array_equal(b, steel_field(seed, pos, rms_uT))
    rms = math.sqrt(float(np.mean(np.sum(b**2, axis=1))))
    assert 0.55 * rms_uT < rms < 1.45 * rms_uT, rms
    step = rng.normal(size=(4000, 3)) * 0.1
    slope = STEEL_MODES * (2.0 * math.pi / STEEL_WAVELENGTH_M[0]) * rms_uT * math.sqrt(2.0 / STEEL_MODES)
    moved = np.linalg.norm(steel_field(seed, pos + step, rms_uT) - b, axis=1)
    assert np.all(moved <= slope * np.linalg.norm(step, axis=1) + 1e-12)
