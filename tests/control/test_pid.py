"""PID and cascade: limits, anti-windup, derivative kick, derivative filter, bumpless transfer, step tracking."""

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from gateway.control.cascade import Cascade, CascadeSettings
from gateway.control.pid import Pid, PidSettings, filtered_derivative
from gateway.control.plants import PAPER_PLANTS, LtiPlant

DT = 0.01


def first_order_run(pid: Pid, setpoints: np.ndarray, y0: float = 0.0, tau_s: float = 0.5):
    """Drive y' = (u − y)/τ (exact ZOH) with the PID from y0; returns (y, u)."""
    a = math.exp(-DT / tau_s)
    y = y0
    ys, us = np.empty(setpoints.size), np.empty(setpoints.size)
    for k, r in enumerate(setpoints):
        u = pid.update(float(r), y, DT)
        ys[k], us[k] = y, u
        y = a * y + (1 - a) * u
    return ys, us


@settings(max_examples=60, deadline=None)
@given(
    st.lists(st.floats(-100, 100), min_size=2, max_size=50),
    st.floats(0.0, 10.0),
    st.floats(0.0, 10.0),
    st.floats(0.0, 1.0),
)
def test_output_always_within_limits(measurements, kp, ki, kd):
    pid = Pid(PidSettings(kp, ki, kd, derivative_filter_s=0.02, output_min=-1.5, output_max=2.0))
    for m in measurements:
        u = pid.update(3.0, m, DT)
        assert -1.5 <= u <= 2.0


def test_integral_clamps_while_saturated_and_recovery_is_bounded():
    # Setpoint 5 is unreachable with u <= 1 for 10 s, then 0.5 is requested.
    s = PidSettings(kp=1.0, ki=4.0, output_min=-1.0, output_max=1.0)
    r = np.r_[np.full(1000, 5.0), np.full(1000, 0.5)]
    pid = Pid(s)
    y, u = first_order_run(pid, r[:1000])
    assert np.all(u[200:] == 1.0)
    assert pid.state.integral <= 1.0 + 1e-12  # clamped at the output limit, not ∫e (would be ~40)
    y2, _ = first_order_run(pid, r[1000:], y0=float(y[-1]))
    # Back-calculation: recovery into ±10 % of the new setpoint within 1.5 s (plant τ = 0.5 s).
    recovery_s = settle_time_s(y2, 0.5, 0.05)
    assert recovery_s < 1.5
    # Without anti-windup (plain ∫e, no clamp, no tracking) the same manoeuvre takes much longer.
    assert _naive_pi_recovery(r) > 3 * recovery_s


def settle_time_s(y: np.ndarray, target: float, tol: float) -> float:
    """First time after which y stays within target ± tol (inf if it never does)."""
    outside = np.flatnonzero(np.abs(y - target) >= tol)
    if outside.size == 0:
        return 0.0
    return math.inf if outside[-1] == y.size - 1 else float((outside[-1] + 1) * DT)


def _naive_pi_recovery(r: np.ndarray, tau_s: float = 0.5) -> float:
    """Recovery time (s) of a textbook PI with a saturated actuator and an unlimited integrator."""
    a = math.exp(-DT / tau_s)
    y, integ = 0.0, 0.0
    ys = np.empty(r.size)
    for k, rk in enumerate(r):
        e = rk - y
        u = min(1.0, max(-1.0, 1.0 * e + integ))
        integ += 4.0 * e * DT
        ys[k] = y
        y = a * y + (1 - a) * u
    return settle_time_s(ys[1000:], 0.5, 0.05)


def test_no_derivative_kick_on_setpoint_step():
    on_meas = Pid(PidSettings(kp=2.0, kd=1.0, derivative_filter_s=0.01))
    on_err = Pid(PidSettings(kp=2.0, kd=1.0, derivative_filter_s=0.01, derivative_on="error"))
    for pid in (on_meas, on_err):
        pid.update(0.0, 0.3, DT)
        pid.update(0.0, 0.3, DT)
    # Setpoint steps 0 -> 1 with the measurement constant at 0.3.
    assert on_meas.update(1.0, 0.3, DT) == pytest.approx(2.0 * 0.7, abs=1e-12)
    kicked = on_err.update(1.0, 0.3, DT)
    assert kicked - 2.0 * 0.7 == pytest.approx(1.0 / (0.01 + DT), rel=1e-9)  # kd·Δe/(T_f + dt)


def test_filtered_derivative_of_a_ramp_converges_to_kd_times_slope():
    d, x_prev = 0.0, 0.0
    for k in range(1, 500):
        x = 0.7 * k * DT
        d = filtered_derivative(d, x, x_prev, kd=2.0, tf_s=0.05, dt_s=DT)
        x_prev = x
    assert d == pytest.approx(1.4, rel=1e-9)


def test_derivative_filter_attenuates_measurement_noise():
    rng = np.random.default_rng(1)
    noise = rng.normal(0.0, 0.01, 5000)

    def d_std(tf_s: float) -> float:
        pid = Pid(PidSettings(kp=0.0, kd=1.0, derivative_filter_s=tf_s))
        return float(np.std([pid.update(0.0, float(n), DT) for n in noise]))

    raw, filtered = d_std(0.0), d_std(0.1)
    assert raw == pytest.approx(0.01 * math.sqrt(2) / DT, rel=0.05)  # differenced white noise
    assert filtered < raw / 5


def test_manual_to_auto_is_bumpless():
    pid = Pid(PidSettings(kp=1.5, ki=2.0, kd=0.1, derivative_filter_s=0.02, output_min=-1, output_max=1))
    for _ in range(50):
        pid.track(0.6, setpoint=0.2, measurement=0.1, dt_s=DT)
    assert pid.update(0.2, 0.1, DT) == pytest.approx(0.6, abs=1e-9)


def test_reset_preloads_output():
    pid = Pid(PidSettings(kp=1.0, ki=1.0))
    pid.update(5.0, 0.0, DT)
    pid.reset(0.25)
    assert pid.update(0.0, 0.0, DT) == pytest.approx(0.25)


def test_cascade_tracks_a_step_on_g1():
    plant = LtiPlant(PAPER_PLANTS["pitch"], 1e-3)
    c = Cascade(
        CascadeSettings(
            PidSettings(50.0, 0.0, 0.0, derivative_filter_s=0.01),
            PidSettings(0.3, 0.01, 0.001, derivative_filter_s=0.01),
        )
    )
    y = []
    for _ in range(300):
        u = c.update(1.0, plant.output, plant.output_rate(), 1e-3)
        plant.step(u)
        y.append(plant.output)
    y_arr = np.array(y)
    assert y_arr[-1] == pytest.approx(1.0, abs=0.02)  # within 2 % after 0.3 s
    assert y_arr.max() < 1.1  # overshoot < 10 %


def test_cascade_inner_saturation_freezes_outer_integral():
    s = CascadeSettings(PidSettings(1.0, 5.0), PidSettings(1.0, 0.0, output_min=-0.1, output_max=0.1))
    c = Cascade(s)
    for _ in range(100):
        assert c.update(1.0, 0.0, 0.0, DT) == pytest.approx(0.1)
    assert c.outer.state.integral == pytest.approx(0.0, abs=1e-12)


def test_cascade_feedforward_is_added_and_saturated():
    c = Cascade(CascadeSettings(PidSettings(1.0), PidSettings(1.0, output_min=-1.0, output_max=1.0)))
    assert c.update(0.2, 0.2, 0.0, DT, feedforward=0.5) == pytest.approx(0.5)
    assert c.update(0.2, 0.2, 0.0, DT, feedforward=3.0) == pytest.approx(1.0)
