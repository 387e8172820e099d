"""The hook filter's torsion 1σ (`HookFilter.torsion_std_rad`, a Swing's `torsion_std_rad`): its heading gradient
against the closed form, and whether the σ is honest on the suite's cranes with boards the floor was not chosen on
(`bench.hook_torsion_std` is the full measurement)."""

from __future__ import annotations

import math
import re

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from bench.hook_torsion_std import coverage, main, torsion_errors
from gateway.fusion.hook_filter import (
    _ALPHA,
    _HARD_IRON,
    _TORSION_STATES,
    N_STATE,
    HookFilter,
    HookFilterSettings,
    _heading_gradient,
)

DT_S = 0.01


def _started(use_mag: bool = True) -> HookFilter:
    """A hook filter started hanging still (50 samples) in a field of 20 µT North, 44 µT down, 5 µT of hard iron."""
    f = HookFilter(HookFilterSettings(rope_length_m=8.0, rope_length_known=True), use_mag=use_mag)
    rng = np.random.default_rng(3)
    gyr = rng.normal(0.0, 1e-3, (50, 3))
    acc = np.tile([0.0, 0.0, 9.80665], (50, 1)) + rng.normal(0.0, 0.01, (50, 3))
    mag = np.tile([3.0, 20.0 - 4.0, -44.0 + 1.0], (50, 1)) + rng.normal(0.0, 0.2, (50, 3))
    f.start(gyr, acc, mag if use_mag else None, DT_S)
    return f


def test_the_heading_gradient_is_the_closed_form_of_the_output_north() -> None:
    """With no soft iron learnt the output heading is α + β, β = atan2(e, n) of the held field
    `m_ref - M h`: ∂/∂α = 1 and ∂β/∂h = (n ∂e/∂h - e ∂n/∂h) / (e² + n²) with ∂(e, n)/∂h = -(M's rows 0, 1), to 1e-6."""
    f = _started()
    x = f.x.copy()
    x[_HARD_IRON] = [2.0, -1.5, 0.7]  # a hard iron learnt part way
    params = f._output_params()
    grad = np.empty(_TORSION_STATES.shape[0])
    _heading_gradient(x.copy(), params, _TORSION_STATES, grad)
    assert f.mag_ref_frame is not None and f.mag_ref_uT is not None
    m = f.mag_ref_frame
    east, north, _ = f.mag_ref_uT - m @ x[_HARD_IRON]
    d_beta = (north * -m[0] - east * -m[1]) / (east**2 + north**2)
    col = {int(s): j for j, s in enumerate(_TORSION_STATES)}
    assert abs(grad[col[_ALPHA]] - 1.0) < 1e-6
    for k in range(3):
        assert abs(grad[col[_HARD_IRON.start + k]] - d_beta[k]) < 1e-6, (k, grad, d_beta)


@settings(max_examples=40, deadline=None)
@given(st.floats(1e-6, 0.5), st.floats(-math.pi, math.pi), st.floats(0.0, 2.0))
def test_without_a_compass_the_sigma_is_the_twist_state_and_the_floor(var_alpha: float, alpha: float,
                                                                               floor_deg: float) -> None:  # fmt: skip
    """6D (or after a compass drop): no North is held, so σ² is α's variance plus the floor's square (relative
    1e-8: the gradient's central difference), whatever α, the swing and the rest of the covariance."""
    f = _started(use_mag=False)
    rng = np.random.default_rng(int(1e6 * var_alpha))
    f.settings = HookFilterSettings(rope_length_m=8.0, rope_length_known=True, torsion_std_floor_deg=floor_deg)
    f.x[0:4] = rng.normal(0.0, 0.05, 4)  # a swing: the swing-twist split keeps it out of the heading
    f.x[_ALPHA] = alpha
    a = rng.normal(size=(N_STATE, N_STATE))
    f.P = a @ a.T * 1e-3
    f.P[_ALPHA, :] = f.P[:, _ALPHA] = 0.0
    f.P[_ALPHA, _ALPHA] = var_alpha
    want = var_alpha + math.radians(floor_deg) ** 2
    assert abs(f.torsion_std_rad**2 - want) < 1e-8 * want


def test_the_sigma_holds_the_torsion_error_on_boards_it_was_not_chosen_on() -> None:
    """Tuning cranes 1-6 on two more MPU-6050-class boards each (`sensor_draw` 1, 2; the floor was chosen on 1-30
    with draws 1-4 as a whole, not on these 40-s draws), the rest heading configured: in the first 5 s the error
    (11.5° RMS in the first second: the hard iron not learnt yet) is within 2σ on every sample (measured 100 %), after
    them on 88.5 % (75.3 % without the 0.5° floor); σ reads 14° in the first second and 0.66° after 5 s (median),
    so it is not vacuous. Bounds: 2σ ≥ 95 % early, ≥ 85 % late; late median σ ≤ 1.5°, first-second σ ≥ 5°."""
    runs = [torsion_errors(seed, draw, "legacy", 40.0, {}, 100.0) for seed in range(1, 7) for draw in (1, 2)]
    t, err, std = (np.concatenate([r[i] for r in runs]) for i in range(3))
    late, first = t > 5.0, t <= 1.0
    assert math.degrees(float(np.sqrt(np.mean(err[first] ** 2)))) > 5.0  # the case is real: an early error to hold
    assert coverage(err[~late], std[~late])[1] >= 0.95
    assert coverage(err[late], std[late])[1] >= 0.85
    assert math.degrees(float(np.median(std[late]))) <= 1.5
    assert math.degrees(float(np.median(std[first]))) >= 5.0


def test_the_bench_prints_the_shares_by_window(capsys: pytest.CaptureFixture[str]) -> None:
    """`python -m bench.hook_torsion_std` on one crane and board, 10 s: the three windows' 1σ / 2σ / 3σ shares and
    the worst runs, each share a percentage."""
    assert main(["--seeds", "1", "--draws", "1", "--duration", "10", "--worst", "1"]) == 0
    out = capsys.readouterr().out
    rows = re.findall(r"(first 5 s|after 5 s|whole run):\s+([\d.]+) /\s+([\d.]+) /\s+([\d.]+) %", out)
    assert [r[0] for r in rows] == ["first 5 s", "after 5 s", "whole run"], out
    for _, *shares in rows:
        one, two, three = map(float, shares)
        assert 0.0 <= one <= two <= three <= 100.0, out
    assert "1/1:" in out, out
