"""Default filter (VQF-class): streaming forms agree, unit norm, bias at rest, scale in motion, rejection of external
acceleration and magnetic disturbances, 6D/9D, rate independence, and accuracy on short BROAD slices.

Synthetic thresholds are set from measured values with margin, and each test shows that the quantity it bounds is
large without the mechanism under test (so a broken mechanism fails the test)."""

from __future__ import annotations

from functools import lru_cache
from pathlib import Path

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from gateway.fusion import _default_kernels as K
from gateway.fusion import broad
from gateway.fusion import quaternion as quat
from gateway.fusion.default import DefaultFilter, DefaultSettings, attitude_from_rest
from gateway.fusion.registry import make_filter
from tests.conftest import BROAD_DIR
from tests.fusion.conftest import (
    FIELD_ENU_UT,
    assert_quat_close,
    load_named,
    static_imu,
    synthetic_imu,
    trial_slice,
    unit_quats,
    vectors,
)

G = quat.GRAVITY_M_S2


def _deg(q_est: np.ndarray, q_ref: np.ndarray) -> np.ndarray:
    return np.degrees(quat.angle_between(q_est, q_ref))


def _tilt_deg(q_est: np.ndarray, q_ref: np.ndarray) -> np.ndarray:
    """Inclination error (BROAD definition) in degrees."""
    return np.degrees(broad.error_angles(broad.error_quaternion(q_est, q_ref))[2])


def _heading_deg(q_est: np.ndarray, q_ref: np.ndarray) -> np.ndarray:
    return np.degrees(broad.error_angles(broad.error_quaternion(q_est, q_ref))[1])


# ---- forms of the same computation --------------------------------------------------------------------------


def test_update_update_block_and_run_agree():
    d = synthetic_imu(15.0, seed=1, gyr_bias_rad_s=np.array([0.01, -0.02, 0.005]), ext_acc_m_s2=2.0)
    for use_mag in (True, False):
        mag = d["mag"] if use_mag else None
        fs = [DefaultFilter(use_mag=use_mag) for _ in range(3)]
        for f in fs:
            f.initialise(d["acc"][0], d["mag"][0])
        q_run = fs[0].run(d["gyr"], d["acc"], mag, d["dt_s"])
        q_blk = np.vstack([
            fs[1].update_block(d["gyr"][i : i + 10], d["acc"][i : i + 10], None if mag is None else mag[i : i + 10],
                               d["dt_s"])
            for i in range(0, len(d["gyr"]), 10)
        ])
        q_upd = np.array([
            fs[2].update(d["gyr"][i], d["acc"][i], None if mag is None else mag[i], d["dt_s"])
            for i in range(len(d["gyr"]))
        ])
        np.testing.assert_allclose(q_blk, q_run, atol=1e-12, rtol=0)
        np.testing.assert_allclose(q_upd, q_run, atol=1e-12, rtol=0)
        np.testing.assert_allclose(fs[0].quaternion, q_run[-1])


def test_fixed_kernel_refuses_other_types_even_when_another_kernel_compiled_it_first():
    """With a cold numba cache a batched kernel may compile the one-device kernel as its callee before `_fixed` sees
    it; compilation must still be switched off, so a list gives TypeError (the caller converts), not a compile."""
    from numba import njit

    from gateway.fusion._default_kernels import _fixed

    @njit
    def callee(x):  # type: ignore[no-untyped-def]
        return x[0] * 2.0

    @njit
    def caller(x):  # type: ignore[no-untyped-def]
        return callee(x)

    assert caller(np.ones(3)) == 2.0 and callee.signatures  # compiled as a callee first
    fixed = _fixed(callee, "float64(float64[::1])")
    assert fixed(np.ones(2)) == 2.0
    with pytest.raises(TypeError):
        fixed([1.0, 2.0])


def test_any_array_form_gives_the_same_result_and_bad_shapes_are_refused():
    """C-contiguous float64 packets go straight to the kernel (numba checks their types); strided views, float32 and
    lists are converted, and from then on every call converts. Each form gives the same quaternions, before and after
    the switch; mismatched shapes raise ValueError (the kernel does not bounds-check, so this must not read past an
    array)."""
    d = synthetic_imu(6.0, seed=3, ext_acc_m_s2=1.0)
    n = len(d["gyr"]) - len(d["gyr"]) % 20
    for use_mag in (True, False):
        mag = d["mag"] if use_mag else None
        ref = DefaultFilter(use_mag=use_mag)
        ref.initialise(d["acc"][0], d["mag"][0])
        q_ref = ref.run(d["gyr"][:n], d["acc"][:n], None if mag is None else mag[:n], d["dt_s"])
        f = DefaultFilter(use_mag=use_mag)
        f.initialise(d["acc"][0], d["mag"][0])
        forms = [
            lambda a, s: a[s],  # contiguous: the fast path
            lambda a, s: np.repeat(a[s], 2, axis=1)[:, ::2],  # a strided view of the same values
            lambda a, s: a[s].tolist(),
            lambda a, s: a[s],  # contiguous again, now through the conversion
        ]
        out = []
        for i in range(0, n, 20):
            form = forms[(i // 20) % 4 if i < 4 * 20 else 3]
            s = np.s_[i : i + 20]
            out.append(f.update_block(form(d["gyr"], s), form(d["acc"], s), None if mag is None else form(mag, s),
                                      d["dt_s"]))
        assert not f._fast_block  # the switch did happen
        np.testing.assert_allclose(np.vstack(out), q_ref, atol=1e-12, rtol=0)
        g = DefaultFilter(use_mag=use_mag)
        g.initialise(d["acc"][0], d["mag"][0])
        q_one = [g.update(np.repeat(d["gyr"][i], 2)[::2] if i >= 20 else d["gyr"][i], d["acc"][i].tolist(),
                          None if mag is None else mag[i], d["dt_s"]) for i in range(40)]
        assert not g._fast_sample
        np.testing.assert_allclose(q_one, q_ref[:40], atol=1e-12, rtol=0)
    f = DefaultFilter()
    for gyr, acc, mag in (
        (d["gyr"][:10], d["acc"][:9], d["mag"][:10]),  # fast path, acc short
        (d["gyr"][:10], d["acc"][:10], d["mag"][:11]),
        (d["gyr"][:10, :2].copy(), d["acc"][:10, :2].copy(), d["mag"][:10, :2].copy()),
        (d["gyr"][:10].tolist(), d["acc"][:9].tolist(), d["mag"][:10]),  # converted path, acc short
        (d["gyr"][0], d["acc"][0], d["mag"][0]),  # a sample where a block belongs
    ):
        with pytest.raises(ValueError):
            f.update_block(gyr, acc, mag, 0.01)
    with pytest.raises(ValueError):
        f.update(d["gyr"][0, :2], d["acc"][0, :2], d["mag"][0, :2], 0.01)
    with pytest.raises(ValueError):
        f.update(d["gyr"][:2], d["acc"][:2], d["mag"][:2], 0.01)


@pytest.mark.parametrize("rate_rad_s", [0.05, 3.0, 40.0])  # small steps take the Taylor series, large ones sin/cos
def test_strapdown_is_exact_for_a_constant_rate(rate_rad_s):
    """Without accelerometer readings (zero rows) the filter only integrates the gyro: after n samples of a constant
    rate about a fixed axis the attitude is exactly that rotation (checks the series used for small steps)."""
    n, dt = 2000, 0.005
    axis = np.array([1.0, -2.0, 0.5]) / np.linalg.norm([1.0, -2.0, 0.5])
    f = DefaultFilter(DefaultSettings(rest_bias=False, motion_bias=False, scale_estimation=False), use_mag=False)
    q = f.run(np.tile(rate_rad_s * axis, (n, 1)), np.zeros((n, 3)), None, dt)
    half = 0.5 * rate_rad_s * dt * np.arange(1, n + 1)
    expected = np.column_stack([np.cos(half), np.sin(half)[:, None] * axis])
    assert_quat_close(q, expected, atol=1e-11)


def test_heading_half_angle_kept_in_step_with_delta():
    """The output's heading rotation uses cos/sin(delta/2) carried in the state and turned by each small step; after
    a long 9D run (many steps, heading wraps at ±π as the body turns) it still equals the exact values."""
    d = synthetic_imu(120.0, seed=7, rate_amp_rad_s=2.0)
    f = DefaultFilter()
    f.initialise(d["acc"][0], d["mag"][0])
    q = f.run(d["gyr"], d["acc"], d["mag"], d["dt_s"])
    delta = f.state[K.S_DELTA]
    np.testing.assert_allclose(f.state[K.S_HEAD + 1 : K.S_HEAD + 3], [np.cos(delta / 2), np.sin(delta / 2)],
                               atol=1e-12, rtol=0)
    # and the output is that rotation applied to the body -> E6 attitude
    q6 = quat.multiply(f.state[K.S_QI : K.S_QI + 4], f.state[K.S_QG : K.S_QG + 4])
    assert_quat_close(q[-1], quat.multiply([np.cos(delta / 2), 0.0, 0.0, np.sin(delta / 2)], q6), atol=1e-12)
    assert _deg(q[-1], d["q_true"][-1]) < 3.0


def test_missing_and_invalid_samples():
    """NaN gyro rows hold the attitude, NaN/zero acc and mag rows are skipped readings; a bad dt is refused."""
    d = synthetic_imu(10.0, seed=4)
    gyr, acc, mag = d["gyr"].copy(), d["acc"].copy(), d["mag"].copy()
    gyr[300:310] = np.nan
    acc[400:450] = np.nan
    acc[500:550] = 0.0
    mag[600:700] = np.nan
    f = DefaultFilter()
    f.initialise(d["acc"][0], d["mag"][0])
    q = f.run(gyr, acc, mag, d["dt_s"])
    assert np.all(np.isfinite(q)) and np.all(np.isfinite(f.state))
    np.testing.assert_array_equal(q[300:310], np.tile(q[299], (10, 1)))
    # the 0.1 s gyro gap loses a few degrees of real rotation: inclination comes back (tau_acc), heading slowly
    assert _tilt_deg(q[-1], d["q_true"][-1]) < 1.0
    assert _deg(q[-1], d["q_true"][-1]) < 10.0
    with pytest.raises(ValueError):
        f.update(gyr[0], acc[0], mag[0], 0.0)
    with pytest.raises(ValueError):
        f.update_block(gyr[:10], acc[:10], mag[:10], -0.01)


def test_registered_as_default():
    f = make_filter("default", use_mag=False)
    assert isinstance(f, DefaultFilter) and not f.use_mag


@given(unit_quats(), vectors(30.0), vectors(50.0), vectors(80.0), st.floats(1e-3, 0.02), st.booleans())
def test_unit_norm_preserved(q0, gyr, acc, mag, dt, use_mag):
    f = DefaultFilter(use_mag=use_mag)
    f.state[K.S_QG : K.S_QG + 4] = q0
    for _ in range(5):
        q = f.update(gyr, acc, mag, dt)
    assert np.all(np.isfinite(q))
    assert np.linalg.norm(q) == pytest.approx(1.0, abs=1e-12)


@given(unit_quats(), st.booleans())
def test_initialise_reproduces_rest_attitude(q_true, with_mag):
    """From noise-free rest readings the start attitude is the truth (9D) or the truth's inclination (6D)."""
    acc = quat.rotate_inverse(q_true, [0.0, 0.0, G])
    mag = quat.rotate_inverse(q_true, FIELD_ENU_UT)
    q0 = attitude_from_rest(acc, mag if with_mag else None)
    if with_mag:
        assert_quat_close(q0, q_true, atol=1e-9)
    assert _tilt_deg(q0, q_true) < 1e-5


# ---- bias, scale -------------------------------------------------------------------------------------------


def test_rest_bias_converges_to_injected_bias():
    """At rest the bias estimate reaches an injected °/s-class bias within 0.02 °/s in 20 s and the attitude stays
    put (the heading moves < 2° while rest is being confirmed); with bias estimation off the same data drifts."""
    q_true = quat.normalise(np.array([0.9, 0.1, -0.2, 0.3]))
    bias = np.radians([3.0, -1.2, 0.5])  # MPU-6050 class: 1 °/s std start-up bias, 3 sigma on x
    d = static_imu(q_true, 20.0, rate_hz=200.0)
    gyr = d["gyr"] + bias + np.random.default_rng(0).normal(scale=0.003, size=d["gyr"].shape)
    f = DefaultFilter()
    f.initialise(d["acc"][0], d["mag"][0])
    q = f.run(gyr, d["acc"], d["mag"], d["dt_s"])
    assert f.rest_detected
    assert np.max(np.abs(np.degrees(f.bias_rad_s - bias))) < 0.02
    assert _tilt_deg(q[-1], q_true) < 0.1
    assert _deg(q[-1], q_true) < 2.0
    off = DefaultFilter(DefaultSettings(rest_bias=False, motion_bias=False), use_mag=False)
    off.initialise(d["acc"][0], None)
    q_off = off.run(gyr, d["acc"], None, d["dt_s"])
    assert _deg(q_off[-1], q_true) > 5.0 * _deg(q[-1], q_true)  # the uncorrected bias drifts the heading (10° vs 1°)


def test_motion_bias_and_scale_estimated():
    """In motion (no rest) a gyro with bias and ~1 % per-axis scale errors is calibrated online: the scale estimates
    take the right signs and sizes, and the 6D drift over the last 20 s of 120 s is well below that of a filter
    without bias/scale estimation (measured 4.3° vs 7.6°; the synthetic motion keeps heading poorly observable)."""
    d = synthetic_imu(120.0, rate_hz=100.0, seed=5, rate_amp_rad_s=1.5, gyr_bias_rad_s=np.radians([0.3, -0.4, 0.2]))
    true_rate = quat.to_rotvec(quat.multiply(quat.conjugate(d["q_true"][:-1]), d["q_true"][1:])) / d["dt_s"]
    gyr = d["gyr"].copy()
    gyr[:-1] += true_rate * np.array([0.01, -0.008, 0.012])  # per-axis scale errors
    gyr = np.vstack([gyr[:1], gyr[:-1]])  # filter convention: gyr[i] is the rate that led up to sample i
    errs = {}
    for name, s in (("on", DefaultSettings()), ("off", DefaultSettings(motion_bias=False, scale_estimation=False))):
        f = DefaultFilter(s, use_mag=False)
        f.state[K.S_QG : K.S_QG + 4] = d["q_true"][0]  # start at the truth, so any error is drift
        q = f.run(gyr, d["acc"], None, d["dt_s"])
        last = slice(-2000, None)
        errs[name] = float(np.sqrt(np.mean(_deg(q[last], d["q_true"][last]) ** 2)))
        if name == "on":
            k = f.state[K.S_SCALE : K.S_SCALE + 3]
            # rate * (1 + k) undoes the error: k ≈ -error
            # measured [-0.0032, 0.0068, -0.0085]: y and z close, x (least excited here) still converging
            np.testing.assert_allclose(k[1:], [0.008, -0.012], atol=0.005)
            assert np.all(np.sign(k) == [-1, 1, -1])
    assert errs["on"] < 0.7 * errs["off"]


# ---- rejection of disturbances -----------------------------------------------------------------------------


def _translation(seconds_each: float, acc_m_s2: float, rate_hz: float = 100.0) -> dict[str, np.ndarray]:
    """Level, still attitude; the body is pushed along x: +a for a while, then -a (a long linear acceleration)."""
    q_true = quat.normalise(np.array([1.0, 0.0, 0.0, 0.4]))
    n_rest, n_acc = int(3 * rate_hz), int(seconds_each * rate_hz)
    lin = np.zeros((n_rest + 2 * n_acc + n_rest, 3))
    lin[n_rest : n_rest + n_acc, 0] = acc_m_s2
    lin[n_rest + n_acc : n_rest + 2 * n_acc, 0] = -acc_m_s2
    acc = quat.rotate_inverse(q_true, lin + [0.0, 0.0, G])
    n = lin.shape[0]
    return {"q": np.tile(q_true, (n, 1)), "gyr": np.zeros((n, 3)), "acc": acc,
            "mag": np.tile(quat.rotate_inverse(q_true, FIELD_ENU_UT), (n, 1)), "dt_s": 1.0 / rate_hz}


def test_external_acceleration_rejected():
    """A 1 s push of 3 m/s² (then 1 s braking) reads as a 17° tilt to an accelerometer; the estimate tilts < 3.5°
    (measured 2.4°) and recovers. (A push held for ever is indistinguishable from tilt: this is a low-pass property.)"""
    d = _translation(1.0, 3.0)
    f = DefaultFilter(use_mag=False)
    f.initialise(d["acc"][0], None)
    q = f.run(d["gyr"], d["acc"], None, d["dt_s"])
    tilt = _tilt_deg(q, d["q"])
    naive = np.degrees(np.arctan2(3.0, G))
    assert naive > 15.0
    assert tilt.max() < 3.5
    assert tilt[-1] < 1.5  # and it recovers (0.9° three seconds later, measured)


def test_magnetic_disturbance_rejected():
    """A 25 µT field step for 20 s (norm +40 %): heading stays within 1°; without rejection it swings far."""
    q_true = quat.normalise(np.array([0.95, 0.05, -0.05, 0.3]))
    d = static_imu(q_true, 40.0, rate_hz=100.0)
    mag = d["mag"].copy()
    dist = quat.rotate_inverse(q_true, np.array([25.0, 0.0, 0.0]))
    mag[1000:3000] += dist
    swing = {}
    for on in (True, False):
        f = DefaultFilter(DefaultSettings(mag_rejection=on))
        f.initialise(d["acc"][0], d["mag"][0])
        q = f.run(d["gyr"], d["acc"], mag, d["dt_s"])
        swing[on] = float(_heading_deg(q, np.tile(q_true, (len(q), 1))).max())
    assert swing[True] < 1.0
    assert swing[False] > 10.0


def test_new_field_accepted_after_rotation():
    """After a permanent field change (e.g. moved to a new site) the filter adopts the new field while rotating."""
    d = synthetic_imu(120.0, rate_hz=100.0, seed=7, rate_amp_rad_s=1.5)
    mag = d["mag"].copy()
    rot = quat.from_axis_angle(np.array([0.0, 0.0, 1.0]), np.array(0.0))
    field2 = FIELD_ENU_UT * np.array([1.0, 1.3, 1.3])  # 30 % stronger, same direction
    mag[3000:] = quat.rotate_inverse(quat.multiply(rot, d["q_true"][3000:]), field2)
    f = DefaultFilter()
    f.initialise(d["acc"][0], d["mag"][0])
    q = f.run(d["gyr"], d["acc"], mag, d["dt_s"])
    assert not f.mag_disturbed
    assert f.state[K.S_MAG_REF_NORM] == pytest.approx(np.linalg.norm(field2), rel=0.05)
    assert _deg(q[-1], d["q_true"][-1]) < 3.0


# ---- 6D / 9D -----------------------------------------------------------------------------------------------


def test_6d_ignores_magnetometer_and_9d_finds_north():
    d = synthetic_imu(60.0, rate_hz=100.0, seed=2)
    q6a = DefaultFilter(use_mag=False).run(d["gyr"], d["acc"], d["mag"], d["dt_s"])
    q6b = DefaultFilter(use_mag=True).run(d["gyr"], d["acc"], None, d["dt_s"])
    np.testing.assert_array_equal(q6a, q6b)
    # 9D without initialisation: heading converges to the field from identity
    q9 = DefaultFilter().run(d["gyr"], d["acc"], d["mag"], d["dt_s"])
    assert _deg(q9[-500:], d["q_true"][-500:]).max() < 2.0
    assert _heading_deg(q6a[-500:], d["q_true"][-500:]).max() > 5.0  # 6D cannot know North


# ---- sample rate -------------------------------------------------------------------------------------------


@pytest.mark.parametrize("use_mag", [True, False])
def test_same_accuracy_at_50_200_and_1000_hz(use_mag):
    """One noise-free motion (with bias and external acceleration), sampled at three rates, same defaults: the RMS
    errors agree within 0.05° (measured spread < 0.01°), so time constants are in seconds, not samples."""
    rms = []
    for rate in (50.0, 200.0, 1000.0):
        d = synthetic_imu(40.0, rate_hz=rate, seed=11, rate_amp_rad_s=1.0, ext_acc_m_s2=1.0,
                          gyr_bias_rad_s=np.radians([0.3, -0.2, 0.1]), noise=False)
        # the generator's gyr[i] turns q[i] into q[i+1]; the filter's gyr[i] is the rate that led up to sample i
        gyr = np.vstack([d["gyr"][:1], d["gyr"][:-1]])
        f = DefaultFilter(use_mag=use_mag)
        f.initialise(d["acc"][0], d["mag"][0])
        q = f.run(gyr, d["acc"], d["mag"] if use_mag else None, d["dt_s"])
        err = _deg(q, d["q_true"]) if use_mag else _tilt_deg(q, d["q_true"])
        rms.append(float(np.sqrt(np.mean(err[len(err) // 4 :] ** 2))))
    assert max(rms) < 2.0
    assert max(rms) - min(rms) < 0.05


# ---- BROAD (real data, short slices) -----------------------------------------------------------------------
# First 100 s of each trial (movement starts after ~35-45 s, so 53-62 s of movement are scored). Measured with the
# defaults, total / inclination: 04 9D 0.75 / 0.55, 06 6D 0.73 / 0.65, 30 9D 1.70 / 1.12 (before issue 14: 0.88, 0.73,
# 2.21); VQF's C++ defaults on the same slices 1.08 / 0.60, 0.73 / 0.65, 2.04 / 1.27. Thresholds leave >= 30 % margin.

BROAD_CASES = [
    ("04_undisturbed_slow_rotation_with_breaks_A", "9D", 1.15, 0.75),
    ("06_undisturbed_fast_rotation_A", "6D", 1.0, 0.85),
    ("30_disturbed_stationary_magnet_C", "9D", 2.9, 1.45),
]


@pytest.mark.parametrize(("name", "mode", "max_total_deg", "max_incl_deg"), BROAD_CASES)
def test_broad_slices(broad_dir, name, mode, max_total_deg, max_incl_deg):
    trial = trial_slice(broad_dir, name, 100.0)
    q = broad.run_filter(DefaultFilter(use_mag=mode == "9D"), trial, mode)
    s = broad.score(q, trial, mode)
    assert s.total_deg < max_total_deg
    assert s.inclination_deg < max_incl_deg


# ---- disturbances: shocks, small magnets, re-acquisition, bias --------------------------------------------------


def test_shock_samples_skipped():
    """A tap rings the structure: a few samples of tens of g whose aliased values do not average out. A still device
    tapped every 0.5 s keeps its tilt within 0.05° (measured 0.0°); taking those samples drifts it by about a degree."""
    q_true = quat.normalise(np.array([0.97, 0.1, -0.15, 0.2]))
    d = static_imu(q_true, 30.0, rate_hz=200.0)
    acc = d["acc"].copy()
    rng = np.random.default_rng(3)
    for start in range(400, 6000, 100):  # after 2 s, every 0.5 s: 6 samples of ±(70..90) m/s² on random axes
        acc[start : start + 6] += rng.choice([-1.0, 1.0], size=(6, 3)) * rng.uniform(70.0, 90.0, size=(6, 3))
    tilt = {}
    for spike in (60.0, 0.0):
        f = DefaultFilter(DefaultSettings(acc_spike_m_s2=spike), use_mag=False)
        f.initialise(d["acc"][0], None)
        tilt[spike] = float(_tilt_deg(f.run(d["gyr"], acc, None, d["dt_s"]), np.tile(q_true, (len(acc), 1))).max())
    assert tilt[60.0] < 0.05
    assert tilt[0.0] > 0.3


def _attached_magnet(offset_uT: float, seed: int = 8, rate_amp_rad_s: float = 1.0) -> tuple[dict, np.ndarray, slice]:
    """Rotating device; from 30 s to 70 s a magnet fixed to the body adds `offset_uT` in a fixed body direction."""
    d = synthetic_imu(100.0, rate_hz=100.0, seed=seed, rate_amp_rad_s=rate_amp_rad_s)
    mag = d["mag"].copy()
    on = slice(3000, 7000)
    mag[on] += offset_uT * np.array([0.6, -0.48, 0.64])
    return d, mag, on


def test_bearing_test_sees_a_small_attached_magnet():
    """A small magnet on the body (4 µT: norm and dip change by less than the 10 % / 10° thresholds) turns the field's
    bearing with the body. Norm and dip never flag it; the optional bearing test flags 46 % of the magnet's 40 s
    (measured) and nothing before or after it."""
    d, mag, on = _attached_magnet(4.0, rate_amp_rad_s=2.0)
    h = quat.rotate(d["q_true"][on], mag[on])
    norm = np.linalg.norm(h, axis=1)
    dip = np.degrees(np.arcsin(-h[:, 2] / norm))
    dip0 = np.degrees(np.arcsin(-FIELD_ENU_UT[2] / np.linalg.norm(FIELD_ENU_UT)))
    assert np.abs(norm / np.linalg.norm(FIELD_ENU_UT) - 1).max() < 0.1 and np.abs(dip - dip0).max() < 10.0
    assert np.degrees(np.ptp(np.arctan2(h[:, 0], h[:, 1]))) > 15.0  # the bearing swings
    flagged = {}
    for th in (4.0, 0.0):
        f = DefaultFilter(DefaultSettings(mag_bearing_th_deg=th))
        f.initialise(d["acc"][0], d["mag"][0])
        dist = []
        for i in range(0, len(mag), 10):
            f.update_block(d["gyr"][i : i + 10], d["acc"][i : i + 10], mag[i : i + 10], d["dt_s"])
            dist.append(f.mag_disturbed)
        flagged[th] = np.array(dist)
    assert flagged[4.0][300:700].mean() > 0.3
    assert not flagged[4.0][50:300].any() and not flagged[4.0][750:].any()
    assert not flagged[0.0].any()


def test_heading_reacquired_quickly_after_rejection():
    """After 30 s of rejected field the heading variance has grown, so the gain is larger (about 1 + 30 s / tau_mag
    at first): a 10° heading error (as gyro drift would leave) is down to 1/e within 0.7 tau_mag of the field coming
    back (measured 12.2 s with tau_mag 20 s); the fixed gain takes about tau_mag (measured 20.6 s)."""
    q_true = quat.normalise(np.array([0.95, 0.05, -0.05, 0.3]))
    d = static_imu(q_true, 70.0, rate_hz=100.0)
    mag = d["mag"].copy()
    mag[500:3500] *= 1.5  # rejected (norm +50 %) from 5 s to 35 s
    t_1e = {}
    for kf in (True, False):
        f = DefaultFilter(DefaultSettings(mag_heading_kf=kf))
        f.initialise(d["acc"][0], d["mag"][0])
        f.run(d["gyr"][:1000], d["acc"][:1000], mag[:1000], d["dt_s"])
        assert f.mag_disturbed
        f.state[K.S_DELTA] += np.radians(10.0)  # heading error gathered while the field was rejected
        q = f.run(d["gyr"][1000:], d["acc"][1000:], mag[1000:], d["dt_s"])
        err = _heading_deg(q, np.tile(q_true, (len(q), 1)))
        back = 2500  # 35 s
        assert err[back - 1] == pytest.approx(10.0, abs=0.1)  # nothing corrected while rejected
        t_1e[kf] = float(np.argmax(err[back:] < 10.0 / np.e) * d["dt_s"])
    tau = DefaultSettings().tau_mag_s
    assert t_1e[True] < 0.7 * tau
    assert t_1e[False] > 0.9 * tau


def test_magnetic_disturbance_leaves_gyro_bias_alone():
    """The field never feeds the bias/scale filter, so a strong disturbance (an attached magnet) cannot drag the bias:
    the estimates are identical with and without it, and they are the injected bias."""
    d, mag, _ = _attached_magnet(30.0)
    bias = np.radians([0.4, -0.3, 0.2])
    out = []
    for m in (d["mag"], mag):
        f = DefaultFilter()
        f.initialise(d["acc"][0], d["mag"][0])
        f.run(d["gyr"] + bias, d["acc"], m, d["dt_s"])
        out.append(f.state[K.S_BIAS : K.S_SCALE + 3].copy())
    np.testing.assert_array_equal(out[0], out[1])
    assert np.abs(np.degrees(out[0][:3]) - [0.4, -0.3, 0.2]).max() < 0.1  # and it is the injected bias


# ---- BROAD, whole trials, against VQF: the per-trial guard ---------------------------------------------------
# Every trial in the BROAD folder (RIG_BROAD_DIR or ../shared/data/broad), each its own test so a failing trial names
# itself. The targets (issue 14): 9D total at most 1.1x VQF's on every trial and 0.9x on the mean; inclination not
# behind VQF's (a tie within 0.01° passes: trial 15, fast translation, is 0.006° behind; see docs/fusion.md); 6D mean
# ahead. On the 15 development trials, defaults: worst 9D ratio 1.04 (trial 34), mean 0.75x; these are in-sample
# figures, the cross-validated ones are in docs/fusion.md.

BROAD_TRIALS = sorted(p.stem for p in BROAD_DIR.glob("*.mat")) or ["no-broad-data"]


@lru_cache(maxsize=64)
def _scores(folder: str, name: str, mode: broad.Mode) -> tuple[broad.Score, broad.Score]:
    """(default filter, VQF defaults) on one whole trial."""
    vqf = pytest.importorskip("vqf")
    t = load_named(Path(folder), name)
    ours = broad.score(broad.run_filter(DefaultFilter(use_mag=mode == "9D"), t, mode), t, mode)
    out = vqf.VQF(t.dt_s).updateBatch(t.gyr_rad_s, t.acc_m_s2, t.mag_uT if mode == "9D" else None)
    return ours, broad.score(out["quat9D" if mode == "9D" else "quat6D"], t, mode)


@pytest.mark.parametrize("name", BROAD_TRIALS)
def test_broad_trial_not_behind_vqf(broad_dir, name):
    ours, ref = _scores(str(broad_dir), name, "9D")
    assert ours.total_deg <= 1.1 * ref.total_deg, f"{name}: 9D total {ours.total_deg:.2f} vs VQF {ref.total_deg:.2f}"
    assert ours.inclination_deg <= ref.inclination_deg + 0.01, (
        f"{name}: inclination {ours.inclination_deg:.3f} vs VQF {ref.inclination_deg:.3f}")
    ours6, ref6 = _scores(str(broad_dir), name, "6D")
    assert ours6.total_deg <= 1.2 * ref6.total_deg, (
        f"{name}: 6D total {ours6.total_deg:.2f} vs VQF {ref6.total_deg:.2f}")


def test_broad_means_ahead_of_vqf(broad_dir):
    names = sorted(p.stem for p in broad_dir.glob("*.mat"))
    for mode, factor in (("9D", 0.9), ("6D", 1.0)):
        pairs = [_scores(str(broad_dir), n, mode) for n in names]
        ours = np.mean([o.total_deg for o, _ in pairs])
        ref = np.mean([r.total_deg for _, r in pairs])
        assert ours <= factor * ref, f"{mode}: mean total {ours:.3f} vs VQF {ref:.3f} (target {factor}x)"


@pytest.mark.parametrize("name", ["14_undisturbed_slow_translation_with_breaks_B", "24_disturbed_tapping_A"])
def test_reduces_to_vqf_with_our_additions_off(broad_dir, name):
    """With scale estimation and shock skipping off and VQF's gains in our units (VQF defines tau by
    fc = √2/(2π tau): its tau_acc 3 s is 3/√2 here, bias clip 2 °/s), the 6D core is VQF's: inclination within
    0.002° of pip vqf's after the first 30 s (the start differs: VQF averages its first samples, we start from the
    rest reading). Measured 0.0001°. The rest-detection low-pass is left at our default, which must be VQF's 0.5 s
    converted the same way: taken over unconverted (0.5 s) it differs by up to 0.07° on these trials."""
    vqf = pytest.importorskip("vqf")
    t = load_named(broad_dir, name)
    settings = DefaultSettings(
        tau_acc_s=3.0 / np.sqrt(2.0), bias_clip_deg_s=2.0, scale_estimation=False, acc_spike_m_s2=0.0
    )
    q = broad.run_filter(DefaultFilter(settings, use_mag=False), t, "6D")
    q_vqf = vqf.VQF(t.dt_s).updateBatch(t.gyr_rad_s, t.acc_m_s2)["quat6D"]
    start = int(30.0 * t.rate_hz)
    assert _tilt_deg(q[start:], q_vqf[start:]).max() < 0.002


@given(st.floats(2.0, 60.0), st.sampled_from([0.002, 0.005, 0.01, 0.02]), st.floats(-170.0, 170.0))
def test_heading_kalman_gain_equals_fixed_gain_while_field_is_used(tau_mag_s, dt_s, error_deg):
    """The Kalman heading gain's random walk is chosen so that its steady-state gain is the fixed gain of `tau_mag_s`:
    with the field never rejected the two filters agree to rounding, whatever the heading error they correct."""
    q_true = quat.normalise(np.array([0.9, 0.2, -0.1, 0.35]))
    d = static_imu(q_true, 200 * dt_s, rate_hz=1.0 / dt_s)
    out = []
    for kf in (True, False):
        f = DefaultFilter(DefaultSettings(tau_mag_s=tau_mag_s, mag_heading_kf=kf, mag_rejection=False))
        f.initialise(d["acc"][0], d["mag"][0])
        f.state[K.S_DELTA] += np.radians(error_deg)
        out.append(f.run(d["gyr"], d["acc"], d["mag"], d["dt_s"]))
    np.testing.assert_allclose(out[0], out[1], atol=1e-12, rtol=0)
    assert _heading_deg(out[0][-1], q_true) < abs(error_deg) + 1e-9  # and it did correct
