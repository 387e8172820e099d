"""The hook EKF's fast kernel (`ekf_run`'s sparse, allocation-free arithmetic) against the textbook dense step it
replaced, and its covariance arithmetic against the dense formulas.

The reference is a frozen copy of the dense step as it was before the kernel was rewritten (main at 8d0bfa2:
`F P Fᵀ`, `H P Hᵀ` with `np.linalg.solve`/`inv`, Joseph's form with `I - K H` formed), in plain numpy here, built
on the module's public model functions (`process`, `measurement`, their forward-difference Jacobians,
`process_noise`) and its gating helpers. A copy rather than stored outputs: a change of the *model* (the process,
the measurement, a noise) reaches both sides, so the test keeps checking the arithmetic; a change of `ekf_step`'s
gating logic must be made here too (the test then says the two disagree), which is the point of a frozen copy.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from bench.hook_suite import RATE_HZ, WARMUP_S, make_case, suite_board
from devices.hook_physics import simulate
from gateway.fusion import hook_filter as hf

DT_S = 1.0 / RATE_HZ


def reference_inflate(p_pred, h_jac, hx, z, params, r_diag):
    y = z[:2] - hx[:2]
    hs = h_jac[:2]
    s = hs @ p_pred @ hs.T + np.diag(r_diag[:2])
    d2 = y @ np.linalg.solve(s, y)
    out = p_pred.copy()
    gate = params[hf._GATE]
    if d2 > gate:
        extra = (y[0] * y[0] + y[1] * y[1]) * (1.0 - gate / d2)
        out[2, 2] += extra
        out[3, 3] += extra
    return out


def reference_step(x, p, z, u, dt_s, params, q_psd, r_diag, monitor):  # noqa: C901 (a frozen copy)
    """`ekf_step` as it was at 8d0bfa2, dense numpy."""
    m = z.shape[0]
    f_jac = hf.process_jacobian(x, dt_s, u, params)
    x_pred = hf.process(x, dt_s, u, params)
    if params[hf._L_FORCE_TAU] > 0.0:  # the hoist round: the length's column sees the force's running mean
        hf._smooth_force_in_length_column(x, dt_s, u, params, monitor, f_jac)
    if hf._hoist_runs(x, monitor, params):  # ... and a running hoist's rope speed does not revert
        x_pred[hf._L_RATE] = x[hf._L_RATE] + dt_s * x[hf._L_ACC]
        f_jac[hf._L_RATE, hf._L_RATE] = 1.0
        f_jac[hf._L_RATE, hf._L_ACC] = dt_s
    p_pred = f_jac @ p @ f_jac.T + np.diag(hf.process_noise(x, dt_s, q_psd, params))
    h_full, h_jac_full = hf.measurement_jacobian(x_pred, params)
    hx, h_jac = h_full[:m], h_jac_full[:m]
    y = z[:2] - hx[:2]
    s2 = h_jac[:2] @ p_pred @ h_jac[:2].T + np.diag(r_diag[:2])
    monitor[0] += (y @ np.linalg.solve(s2, y) - monitor[0]) * min(1.0, dt_s / params[hf._NIS_TAU])
    moving = monitor[0] > params[hf._NIS_GATE]
    monitor[5] = 0.0
    w0, w1 = hf._whiten(y, s2)
    if params[hf._MEAN_GATE] > 0.0 and hf._mean_test(w0, w1, params[hf._MEAN_TAU], params[hf._MEAN_GATE], dt_s,
                                                     monitor, 2):  # fmt: skip
        monitor[2] = monitor[3] = 0.0
        monitor[6] = monitor[7] = 0.0
        monitor[5] = 1.0
        monitor[4] = params[hf._MOVE_HOLD]
        monitor[8] = params[hf._TRACK_S]
        for i in (17, 18):
            p_pred[i, i] += params[hf._TIP_MOVE] * params[hf._TIP_MOVE]
        p_pred[hf._LOG_L, hf._LOG_L] += params[hf._JUMP_ROPE] * params[hf._JUMP_ROPE]
    elif params[hf._SLOW_GATE] > 0.0 and hf._mean_test(w0, w1, params[hf._SLOW_TAU], params[hf._SLOW_GATE], dt_s,
                                                       monitor, 6):  # fmt: skip
        monitor[6] = monitor[7] = 0.0
        monitor[8] = params[hf._TRACK_S]
        for i in (17, 18):
            p_pred[i, i] += params[hf._SLOW_OPEN] * params[hf._SLOW_OPEN]
    if monitor[8] > 0.0:
        monitor[8] -= dt_s
        a2 = x_pred[17] * x_pred[17] + x_pred[18] * x_pred[18]
        cap = params[hf._TRACK_CAP]
        scale = min(1.0, a2 / (cap * cap)) if cap > 0.0 else 1.0
        for i in (17, 18):
            p_pred[i, i] += params[hf._TRACK_PSD] * dt_s * scale
    if params[hf._TURN_PSD] > 0.0:
        ax, ay = x_pred[17], x_pred[18]
        q = params[hf._TURN_PSD] * dt_s * min(1.0, params[hf._TURN_CAP] ** 2 / max(ax * ax + ay * ay, 1e-12))
        p_pred[17, 17] += q * ay * ay
        p_pred[18, 18] += q * ax * ax
        p_pred[17, 18] -= q * ax * ay
        p_pred[18, 17] -= q * ax * ay
    jump = monitor[4] > 0.0
    monitor[4] -= dt_s
    move_std = params[hf._TIP_MOVE] if moving else params[hf._TIP_GATE_STD]
    if params[hf._TIP_GATE] > 0.0:
        tip2 = (x_pred[17] ** 2 + x_pred[18] ** 2) / (params[hf._TIP_STD] * params[hf._TIP_STD])
        if tip2 > params[hf._TIP_GATE]:
            monitor[1] = max(params[hf._MOVE_HOLD], 0.5 * dt_s)
    if monitor[1] > 0.0:
        moving = True
        monitor[1] -= dt_s
    if moving:
        for i in (17, 18):
            p_pred[i, i] = max(p_pred[i, i], move_std**2)
    ramp = False
    if params[hf._HOIST_GATE] > 0.0:  # the hoist round's ramp test on the tension channel
        s3 = h_jac[3] @ p_pred @ h_jac[3] + r_diag[3]
        ramp = hf._hoist_test((z[3] - hx[3]) / math.sqrt(s3), x_pred[hf._L_ACC], dt_s, params, monitor)
        if ramp:
            p_pred[hf._L_ACC, hf._L_ACC] = max(p_pred[hf._L_ACC, hf._L_ACC], params[hf._HOIST_OPEN] ** 2)
    p_inflated = reference_inflate(p_pred, h_jac, hx, z, params, r_diag)
    surprised = p_inflated[2, 2] > p_pred[2, 2]
    p_pred = p_inflated
    rmat = np.diag(r_diag)
    pht = p_pred @ h_jac.T
    k = pht @ np.linalg.inv(h_jac @ pht + rmat)
    hf._restrict_gain(k, surprised, hf._length_observability(x_pred, monitor, params, dt_s))
    if ramp:
        k[hf._ACC_BIAS, :] = 0.0
    if (moving or jump) and params[hf._MOVE_FREEZE] > 0.0:
        for j in range(k.shape[1]):
            for i in (14, 15, 16):
                k[i, j] = 0.0
            if params[hf._MOVE_FREEZE] < 1.5:
                for i in (6, 7):
                    k[i, j] = 0.0
    x_new = x_pred + k @ (z - hx)
    i_kh = np.eye(hf.N_STATE) - k @ h_jac
    p_new = i_kh @ p_pred @ i_kh.T + k @ rmat @ k.T
    hf._post_update(x_new, params)
    return x_new, p_new


def reference_run(x0, p0, z, u, dt_s, params, q_psd, r_diag, monitor, hist_x, hist_p, hist_z, hist_u, hist_mon,
                  hist_n):  # fmt: skip
    """`ekf_run` as it was at 8d0bfa2 (the jump rollback included), over `reference_step`."""
    n, m = z.shape
    b = hist_x.shape[0]
    out, lengths = np.empty((n, 4)), np.empty(n)
    x, p = x0.copy(), p0.copy()
    if hist_n[1] != m:
        hist_n[0], hist_n[1] = 0, m
    quiet = params.copy()
    quiet[hf._MEAN_GATE] = quiet[hf._SLOW_GATE] = 0.0
    for i in range(n):
        k = hist_n[0] % b
        hist_x[k], hist_p[k], hist_mon[k] = x, p, monitor
        hist_z[k, :m], hist_u[k] = z[i], u[i]
        hist_n[0] += 1
        x, p = reference_step(x, p, z[i], u[i], dt_s, params, q_psd, r_diag, monitor)
        if monitor[19] > 0.0 and monitor[5] == 0.0 and b > 1 and params[hf._HOIST_BACK] > 0.0:  # a hoist ramp starts
            j0 = hist_n[0] - min(hist_n[0], b)
            x, p = hist_x[j0 % b].copy(), hist_p[j0 % b].copy()
            mon = hist_mon[j0 % b].copy()
            mon[15], mon[16] = params[hf._HOIST_HOLD], params[hf._HOIST_CRUISE]
            for j in range(j0, hist_n[0]):
                x, p = reference_step(x, p, hist_z[j % b, :m], hist_u[j % b], dt_s, quiet, q_psd, r_diag, mon)
            monitor[0], monitor[1], monitor[9] = mon[0], mon[1], mon[9]
            monitor[14:17] = mon[14:17]
            monitor[19] = 0.0
            hist_n[0] = 0
        if monitor[5] > 0.0 and b > 1:
            j0 = hist_n[0] - min(hist_n[0], b)
            x, p = hist_x[j0 % b].copy(), hist_p[j0 % b].copy()
            mon = hist_mon[j0 % b].copy()
            mon[8] = params[hf._TRACK_S]
            for t in (17, 18):
                p[t, t] += params[hf._TIP_MOVE] * params[hf._TIP_MOVE]
            p[hf._LOG_L, hf._LOG_L] += params[hf._JUMP_ROPE] * params[hf._JUMP_ROPE]
            for j in range(j0, hist_n[0]):
                x, p = reference_step(x, p, hist_z[j % b, :m], hist_u[j % b], dt_s, quiet, q_psd, r_diag, mon)
            monitor[0], monitor[1] = mon[0], mon[1]
            hist_n[0] = 0
        out[i] = hf.attitude_and_rate(x)[0]
        lengths[i] = math.exp(x[hf._LOG_L])
    return out, lengths, x, p


def suite_samples(seed: int, duration_s: float):
    case = make_case(seed, duration_s)
    truth = simulate(case.physics, case.scenario)
    sensor = suite_board(seed, "calibrated")
    gyr, acc, mag = sensor.measure(truth.gyr_rad_s, truth.acc_m_s2, truth.mag_uT, DT_S)
    return case, gyr, acc, mag


def started(case, gyr, acc, mag, over=None):
    """Started as bench.hook_suite starts it (rope length told), with the settings overrides `over`."""
    f = hf.HookFilter(hf.HookFilterSettings(rope_length_m=case.physics.rope_length_m, rope_length_known=True,
                                            **(over or {})), use_mag=mag is not None)  # fmt: skip
    n = int(WARMUP_S * RATE_HZ)
    f.start(gyr[:n], acc[:n], None if mag is None else mag[:n], DT_S)
    return f


def angle_rad(qa: np.ndarray, qb: np.ndarray) -> np.ndarray:
    """Rotation angle between quaternion rows (sign-aligned; from the chord, exact near 0 unlike arccos)."""
    sign = np.sign(np.sum(qa * qb, axis=1))[:, None]
    return 4.0 * np.arcsin(np.clip(0.5 * np.linalg.norm(qa - sign * qb, axis=1), 0.0, 1.0))


@pytest.mark.parametrize("seed", [1, 2, 3, 13])
@pytest.mark.parametrize("use_mag", [True, False])
def test_the_kernel_gives_the_dense_steps_estimates_on_suite_cranes(seed, use_mag):
    """60 s of a suite crane (moves, pulls, jumps and their rollbacks; seed 13: two hoists, their ramps' rollbacks):
    per sample the attitude within 1e-6 rad and the
    rope length within 5e-6 relative of the dense reference (measured: ≤ 2e-7 rad, ≤ 6e-8, seed 13 through its
    hoists 1.5e-6; the forward-difference
    Jacobians amplify rounding differences of the state by 1/1e-7, so the two do not agree to the last bit), the
    same gate state at the end and the final covariance within 1e-4 of each entry's scale √(P_ii P_jj)."""
    case, gyr, acc, mag = suite_samples(seed, 60.0)
    mag = mag if use_mag else None
    # without the eleventh round's re-run from the jump test's onset, the thirteenth round's held tracking and
    # length hold, the legacy-board round's output turned to the learnt field's North and the thirty-fourth session's
    # compass gain on the swing (`mag_tilt_gain`), which the reference predates
    over = hf.TIP_ROUND | hf.SLEW_ROUND | hf.IRON_ROUND | hf.TILT_GAIN_ROUND
    fast, ref = started(case, gyr, acc, mag, over), started(case, gyr, acc, mag, over)
    q_fast, l_fast = fast.run_with_length(gyr, acc, mag, DT_S)
    # the reference sees exactly what `run_with_length` hands `ekf_run`
    cols = [gyr, acc[:, 2:3] - ref.acc_z_offset_m_s2] + ([mag] if use_mag else [])
    z = np.ascontiguousarray(np.concatenate(cols, axis=1))
    u = ref._inputs(gyr, acc, DT_S)
    hist_x, hist_p, hist_z, hist_u, hist_mon, hist_n = ref._rings(DT_S)  # the reference keeps whole covariances
    rings = (hist_x, np.zeros((hist_p.shape[0], hf.N_STATE, hf.N_STATE)), hist_z, hist_u, hist_mon, hist_n)
    q_ref, l_ref, x_ref, p_ref = reference_run(ref.x, ref.P, z, u, DT_S, ref._params(use_mag), ref._q_psd,
                                               ref._r_diag(z.shape[1]), ref._monitor, *rings)  # fmt: skip
    assert np.max(angle_rad(q_fast, q_ref)) <= 1e-6
    assert np.max(np.abs(l_fast / l_ref - 1.0)) <= 5e-6
    assert np.array_equal(fast._monitor[4:6] > 0.0, ref._monitor[4:6] > 0.0)  # the same gate state at the end
    scale = np.sqrt(np.outer(np.diag(p_ref), np.diag(p_ref)))  # covariance differences as correlations
    assert np.max(np.abs(fast.P - p_ref) / scale) <= 1e-4


def random_spd(rng: np.random.Generator, n: int) -> np.ndarray:
    """A covariance with the filter's spread of scales (1e-10 .. 1) and correlations."""
    a = rng.normal(size=(n, n)) * np.exp(rng.uniform(-11.0, 0.0, size=n))[:, None]
    return a @ a.T + np.diag(np.exp(rng.uniform(-23.0, 0.0, size=n)))


@settings(max_examples=30, deadline=None)
@given(seed=st.integers(0, 2**31), m=st.sampled_from([3, 4, 7]),
       restricted=st.lists(st.tuples(st.integers(0, 23), st.integers(0, 6)), max_size=8))
def test_the_covariance_update_is_josephs_form_for_a_restricted_gain(seed, m, restricted):
    """`P - Wᵀ W + D S Dᵀ` equals `(I - K H) P (I - K H)ᵀ + K R Kᵀ` for a gain with any rows zeroed (the gain
    restriction and the move freeze zero entries of it), and is exactly symmetric."""
    rng = np.random.default_rng(seed)
    n = hf.N_STATE
    p = random_spd(rng, n)
    h = rng.normal(size=(m, n)) * (rng.random(size=(m, n)) < 0.4)
    r_diag = np.exp(rng.uniform(-13.0, 2.0, size=m))
    vecs, mats, hm, ss, idx, cnt = hf._workspace()
    hm[0, :m] = h
    hf._nonzero_columns(hm[0], m, idx, cnt)
    hf._innovation_covariance(p, hm[0], m, r_diag, idx, cnt, hm[1], ss[0])
    hf._kalman_gain(hm[1], ss[0], m, ss[1], hm[3], hm[2])
    s = h @ p @ h.T + np.diag(r_diag)
    k_dense = p @ h.T @ np.linalg.inv(s)
    assert np.allclose(hm[2, :m].T, k_dense, rtol=1e-6, atol=1e-9 * np.abs(k_dense).max())
    hm[4, :m] = hm[2, :m]
    for i, c in restricted:
        hm[2, c % m, i] = 0.0
    k = hm[2, :m].T.copy()
    out = np.empty_like(p)
    hf._covariance_update(p, hm[3], hm[2], hm[4], ss[0], m, cnt, mats[1], out)
    i_kh = np.eye(n) - k @ h
    joseph = i_kh @ p @ i_kh.T + k @ np.diag(r_diag) @ k.T
    scale = np.sqrt(np.outer(np.diag(p), np.diag(p)))
    assert np.max(np.abs(out - joseph) / scale) < 1e-9
    assert np.array_equal(out, out.T)


@settings(max_examples=30, deadline=None)
@given(seed=st.integers(0, 2**31))
def test_the_sparse_prediction_is_f_p_ft_plus_q(seed):
    """`_predict_covariance` over F's non-zeros equals the dense `F P Fᵀ + diag(q)` for a Jacobian of the process's
    shape (identity rows, a few dense rows), and is exactly symmetric."""
    rng = np.random.default_rng(seed)
    n = hf.N_STATE
    x = np.zeros(n)
    x[:4] = rng.normal(scale=0.1, size=4)
    x[4:6] = rng.normal(size=2)
    x[hf._LOG_L] = rng.uniform(0.0, 3.0)
    x[15:21] = rng.normal(scale=0.1, size=6)
    u = rng.normal(scale=0.5, size=hf.N_INPUT)
    params = hf.HookFilter()._params(use_mag=False)
    f = hf.process_jacobian(x, DT_S, u, params)
    p = random_spd(rng, n)
    q = np.exp(rng.uniform(-20.0, -5.0, size=n))
    vecs, mats, hm, ss, idx, cnt = hf._workspace()
    hf._predict_covariance(f, p, q, mats[1], mats[2])
    dense = f @ p @ f.T + np.diag(q)
    scale = np.sqrt(np.outer(np.diag(dense), np.diag(dense)))
    assert np.max(np.abs(mats[2] - dense) / scale) < 1e-12
    assert np.array_equal(mats[2], mats[2].T)


def test_the_covariance_stays_symmetric_and_positive_definite_on_a_long_run():
    """120 s of a suite crane with a trolley move, a slew and a hoist (jumps, rollbacks and their re-runs from the
    jump test's onset, surprises), checked every second: P exactly symmetric, its smallest eigenvalue positive
    relative to its scale."""
    case, gyr, acc, mag = suite_samples(4, 120.0)
    f = started(case, gyr, acc, mag)
    worst = math.inf
    for i in range(0, gyr.shape[0], 100):
        f.run_with_length(gyr[i:i + 100], acc[i:i + 100], mag[i:i + 100], DT_S)
        assert np.array_equal(f.P, f.P.T)
        d = 1.0 / np.sqrt(np.diag(f.P))
        worst = min(worst, float(np.linalg.eigvalsh(f.P * np.outer(d, d)).min()))
    assert worst > 1e-9


@settings(max_examples=100, deadline=None)
@given(seed=st.integers(0, 2**31), use_mag=st.booleans(), force_on=st.booleans(), rate_tau=st.booleans())
def test_the_exact_jacobians_are_the_plain_forward_differences(seed, use_mag, force_on, rate_tau):
    """`_process_jacobian_into` and `_measurement_jacobian_into` (analytic: the RK4's tangent-linear model, the body
    rate's closed form) against the plain definitions, one `process` / `measurement` per column (forward
    differences, step 1e-7), over random states: each entry within 1e-5 relative or 1e-7 (1 + |f_i(x)| + l)
    absolute, the forward differences' own error (rounding `|f_i| 2⁻⁵² / 1e-7`, truncation `1e-7/2 × ∂²f_i`, e.g.
    `2 l` for the tension's `l |n'|²` in the swing rate). The predicted state and measurement are bit for bit the
    plain ones. It can fail: without the rate difference's term in the tension row, the lever arm's `ω'` term in the
    force input, `l'` in the tension row's chained pendulum acceleration, or the lever arm's columns in the tension
    row, it does."""
    rng = np.random.default_rng(seed)
    x = np.concatenate([rng.normal(scale=0.2, size=4), rng.normal(size=2), rng.normal(scale=0.05, size=8),
                        [rng.uniform(-1.0, 4.0)], rng.normal(scale=0.3, size=6), rng.normal(size=3),
                        rng.normal(scale=0.03, size=4), rng.normal(scale=0.02, size=1)])  # fmt: skip
    u = rng.normal(size=hf.N_INPUT)
    f = hf.HookFilter()
    f.mag_ref_uT = np.array([0.0, 20.0, -40.0])
    params = f._params(use_mag)
    params[hf._FORCE_ON] = 1.0 if force_on else 0.0
    params[hf._L_RATE_TAU] = 30.0 if rate_tau else 0.0
    length = math.exp(x[hf._LOG_L])
    f0, f_jac = np.empty(hf.N_STATE), np.empty((hf.N_STATE, hf.N_STATE))
    hf._process_jacobian_into(x, DT_S, u, params, f0, f_jac, np.empty((hf.N_STATE, hf.N_STATE)))
    f_plain = hf.process_jacobian(x, DT_S, u, params)
    assert np.array_equal(f0, hf.process(x, DT_S, u, params))
    tol = 1e-5 * np.abs(f_plain) + 1e-7 * (1.0 + np.abs(f0) + length)[:, None]
    assert np.all(np.abs(f_jac - f_plain) <= tol)
    h0, h_jac = np.empty(7), np.empty((7, hf.N_STATE))
    hf._measurement_jacobian_into(x, params, h0, h_jac, np.empty((hf.N_STATE, hf.N_STATE)))
    h0_plain, h_plain = hf.measurement_jacobian(x, params)
    assert np.array_equal(h0, h0_plain)
    tol = 1e-5 * np.abs(h_plain) + 1e-7 * (1.0 + np.abs(h0) + length)[:, None]
    assert np.all(np.abs(h_jac - h_plain) <= tol)


@settings(max_examples=50, deadline=None)
@given(seed=st.integers(0, 2**31))
def test_a_packed_covariance_comes_back_bit_for_bit(seed: int) -> None:
    """The rollback ring keeps each covariance's upper triangle (`_pack_sym`, 435 of 841 numbers: 4 s of them per
    hook); the kernel keeps P exactly symmetric, so unpacking must give the same matrix to the last bit, or a
    rollback would restart from a different covariance than the one the filter had."""
    p = random_spd(np.random.default_rng(seed), hf.N_STATE)
    p = np.triu(p) + np.triu(p, 1).T  # exactly symmetric, as the kernel keeps it
    packed, back = np.empty(hf.N_PACKED), np.full((hf.N_STATE, hf.N_STATE), np.nan)
    hf._pack_sym(p, packed)
    hf._unpack_sym(packed, back)
    assert np.array_equal(back, p)
    assert np.array_equal(hf._ring_p(packed[None, :], 0), p)


def test_the_rollback_ring_keeps_covariances_packed() -> None:
    """4 s of covariances at 100 Hz: 400 rows of 435 numbers (1.39 MB) instead of 400 × 29 × 29 (2.69 MB)."""
    f = hf.HookFilter(hf.HookFilterSettings())
    _, hist_p, *_ = f._rings(DT_S)
    assert hist_p.shape == (round(f.settings.move_rollback_max_s / DT_S), hf.N_PACKED) and hf.N_PACKED == 435
