"""Crane-hook physics: a spherical pendulum with torsion about the rope, and the ground truth an IMU on it sees.

Model (seed 001 Fig. 1): a massless rope of length `l(t)` hangs from the boom tip A to the hook centre B (hook and
load one point mass `m`). The rope direction is the unit vector `n` (ENU) from B up to A, so `B = A - l n`. With
the suspension-point acceleration `a_A` (trolley and slewing moves), gravity `g_vec = (0, 0, -g)` and other forces
per unit mass `w` (wind, air damping, tag-line pulls `F / m`), from `B'' = g_vec + (T/m) n + w`:

    a_ext = g_vec - a_A + w
    n'' = -(a_ext - (n . a_ext) n) / l - 2 (l'/l) n' - |n'|^2 n     (constrained motion on the unit sphere)
    T / m = l |n'|^2 - n . a_ext - l''                               (rope tension per unit mass)

Hoisting (`l' < 0`) pumps the swing up, lowering damps it (the Coriolis term `-2 (l'/l) n'`).

The hook twists about the rope by the torsion angle `φ`, a damped torsional oscillator
`J φ'' = -k φ - c φ' + τ_wind` (rope torsional stiffness `k`, damping `c`, hook inertia `J` about the rope;
the gyroscopic coupling with the swing is neglected). The hook attitude is

    q = q_swing(n) ⊗ q_z(ψ_rest + φ)

with `q_swing(n)` the shortest rotation taking earth up `e_z` onto `n` (so body z is the rope, pointing at the
boom tip) and `q_z(α)` a rotation by `α` about body z. Body rates come from `ω_b = 2 vec(q* ⊗ q')`, which
makes the gyroscope exactly consistent with the attitude. The specific force at the IMU, mounted at the lever
arm `r_b` (body frame) from B, is

    f_b = R^T ((T/m) n + w) + ω_b' × r_b + ω_b × (ω_b × r_b)

which is *not* gravity: for `r_b = 0` it always points along body z, whatever the swing.
A scenario may hold the hook still at its initial displacement for `hold_s` (specific force = gravity
reaction) and then release it. Integration: classical RK4 at `internal_rate_hz` (1 kHz), the state re-projected
onto `|n| = 1, n . n' = 0` after each step; outputs are sampled every `internal_rate_hz / output_rate_hz` steps.
Pure: time passed in.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray

from devices import _quat

FloatArray = NDArray[np.float64]


@dataclass(frozen=True)
class HookPhysicsSettings:
    """The crane and hook. Torsion frequency `sqrt(k/J)/2π` ≈ 0.2 Hz and damping ratio ≈ 0.02 by default."""

    rope_length_m: float = 10.0
    gravity_m_s2: float = 9.81
    swing_damping_1_s: float = 0.0  # linear air damping of the swing, force per unit mass per (m/s)
    hook_mass_kg: float = 500.0
    torsion_inertia_kg_m2: float = 20.0  # hook's moment of inertia about the rope
    torsion_stiffness_n_m_rad: float = 31.58  # rope torsional stiffness k
    torsion_damping_n_m_s_rad: float = 1.0  # rope torsional damping c
    rest_heading_rad: float = 0.0  # heading of body x when hanging untwisted (CCW from East)
    lever_arm_m: tuple[float, float, float] = (0.1, 0.0, 0.0)  # IMU position from the hook centre B, body frame
    earth_field_uT: tuple[float, float, float] = (0.0, 20.0, -40.0)  # ENU: north and downward components
    internal_rate_hz: float = 1000.0


@dataclass(frozen=True)
class TrolleyMove:
    """Constant horizontal acceleration `acc_m_s2` (ENU x, y) of the boom tip from `start_s` for `duration_s`."""

    start_s: float
    duration_s: float
    acc_m_s2: tuple[float, float]


def trolley_traverse(start_s: float, distance_m: float, bearing_rad: float, acc_m_s2: float = 0.3) -> tuple[
    TrolleyMove, TrolleyMove, TrolleyMove
]:
    """A start-cruise-stop move of `distance_m` towards `bearing_rad` (CCW from East) at cruise speed 0.5 m/s."""
    cruise_m_s = 0.5
    t_acc = cruise_m_s / acc_m_s2
    t_cruise = max(0.0, (distance_m - cruise_m_s * t_acc) / cruise_m_s)
    ax, ay = acc_m_s2 * math.cos(bearing_rad), acc_m_s2 * math.sin(bearing_rad)
    return (
        TrolleyMove(start_s, t_acc, (ax, ay)),
        TrolleyMove(start_s + t_acc, t_cruise, (0.0, 0.0)),
        TrolleyMove(start_s + t_acc + t_cruise, t_acc, (-ax, -ay)),
    )


@dataclass(frozen=True)
class SlewMove:
    """The boom tip turns about the crane's mast by `angle_rad` (CCW seen from above) in `duration_s` from `start_s`:
    trapezoidal angular rate (ramps of `ramp_s`, default a third of the duration) at `radius_m` from the mast.
    `mast_bearing_rad` is the boom tip's bearing seen from the mast at the start of the move (CCW from East)."""

    start_s: float
    duration_s: float
    angle_rad: float
    radius_m: float = 30.0
    mast_bearing_rad: float = 0.0
    ramp_s: float = 0.0  # 0: a third of the duration


@dataclass(frozen=True)
class Hoist:
    """Rope paid in (`speed_m_s` < 0, hoisting) or out (> 0, lowering) from `start_s` for `duration_s`: trapezoidal
    rope speed with ramps of `ramp_s` (within the duration)."""

    start_s: float
    duration_s: float
    speed_m_s: float
    ramp_s: float = 1.0


@dataclass(frozen=True)
class Pull:
    """A horizontal force on the load (a tag line): `force_n` (ENU x, y, newtons) from `start_s` for `duration_s`,
    ramped up and let go over `ramp_s` (raised cosine) within the duration."""

    start_s: float
    duration_s: float
    force_n: tuple[float, float]
    ramp_s: float = 0.3


def _trapezoid(t_s: FloatArray, start_s: float, duration_s: float, ramp_s: float) -> tuple[FloatArray, FloatArray,
                                                                                         FloatArray]:
    """Unit trapezoid rate profile `(∫, value, derivative)` over time: 0 -> 1 over `ramp_s`, hold, 1 -> 0."""
    ramp = max(min(ramp_s, 0.5 * duration_s), 1e-9)
    tau = np.clip(t_s - start_s, 0.0, duration_s)
    up = np.minimum(tau, ramp)
    down = np.clip(tau - (duration_s - ramp), 0.0, ramp)
    value = up / ramp - down / ramp
    integral = up * up / (2.0 * ramp) + (tau - up) - down * down / (2.0 * ramp)
    inside = (t_s > start_s) & (t_s < start_s + duration_s)
    deriv = np.where(inside & (tau < ramp), 1.0 / ramp, 0.0) - np.where(inside & (tau > duration_s - ramp),
                                                                         1.0 / ramp, 0.0)  # fmt: skip
    return integral, value, deriv


def rope_length(l0_m: float, hoists: tuple[Hoist, ...], t_s: FloatArray) -> tuple[FloatArray, FloatArray, FloatArray]:
    """`(l, l', l'')` at times `t_s` from the initial length and the hoist profile (m, m/s, m/s²)."""
    l, ld, ldd = np.full(np.shape(t_s), l0_m), np.zeros(np.shape(t_s)), np.zeros(np.shape(t_s))
    for h in hoists:
        i, v, d = _trapezoid(np.asarray(t_s, dtype=np.float64), h.start_s, h.duration_s, h.ramp_s)
        l, ld, ldd = l + h.speed_m_s * i, ld + h.speed_m_s * v, ldd + h.speed_m_s * d
    return l, ld, ldd


def pull_force(pulls: tuple[Pull, ...], mass_kg: float, t_s: FloatArray) -> FloatArray:
    """Tag-line force per unit mass (..., 3) in m/s² at times `t_s`."""
    out = np.zeros((*np.shape(t_s), 3))
    for p in pulls:
        tau = np.clip((np.asarray(t_s) - p.start_s), 0.0, p.duration_s)
        ramp = max(min(p.ramp_s, 0.5 * p.duration_s), 1e-9)
        up = 0.5 - 0.5 * np.cos(np.pi * np.minimum(tau, ramp) / ramp)
        down = 0.5 - 0.5 * np.cos(np.pi * np.clip(tau - (p.duration_s - ramp), 0.0, ramp) / ramp)
        shape = np.where((t_s > p.start_s) & (t_s < p.start_s + p.duration_s), up - down, 0.0)
        out[..., 0] += shape * p.force_n[0] / mass_kg
        out[..., 1] += shape * p.force_n[1] / mass_kg
    return out


def slew_acceleration(slews: tuple[SlewMove, ...], t_s: FloatArray) -> FloatArray:
    """Boom-tip acceleration (..., 3) of the slewing moves (tangential + centripetal; they add where they overlap)."""
    out = np.zeros((*np.shape(t_s), 3))
    for m in slews:
        ramp = m.ramp_s if m.ramp_s > 0.0 else m.duration_s / 3.0
        rate = m.angle_rad / (m.duration_s - ramp)  # cruise angular rate: area of the trapezoid = angle
        i, v, d = _trapezoid(np.asarray(t_s, dtype=np.float64), m.start_s, m.duration_s, ramp)
        beta = m.mast_bearing_rad + rate * i
        w, wd = rate * v, rate * d
        c, s = np.cos(beta), np.sin(beta)
        out[..., 0] += m.radius_m * (-wd * s - w * w * c)
        out[..., 1] += m.radius_m * (wd * c - w * w * s)
    return out


@dataclass(frozen=True)
class HookScenario:
    """What happens: initial swing (angle, bearing of the hook's displacement, sideways rate), moves and wind."""

    duration_s: float = 30.0
    output_rate_hz: float = 100.0
    initial_swing_rad: float = 0.0
    initial_swing_bearing_rad: float = 0.0  # direction of the hook's horizontal displacement, CCW from East
    initial_sideways_rate_rad_s: float = 0.0  # rope rate perpendicular to the swing plane (elliptic/conical swing)
    initial_torsion_rad: float = 0.0
    initial_torsion_rate_rad_s: float = 0.0
    hold_s: float = 0.0  # held still at the initial displacement until then (rates ignored), then released
    trolley_moves: tuple[TrolleyMove, ...] = ()
    wind_mean_m_s2: tuple[float, float] = (0.0, 0.0)  # steady wind force per unit mass, ENU x, y
    wind_std_m_s2: float = 0.0  # gusts: Ornstein-Uhlenbeck force per unit mass, per horizontal axis
    wind_tau_s: float = 2.0  # gust correlation time
    wind_torque_std_n_m: float = 0.0  # gust torque about the rope (same correlation time)
    slews: tuple[SlewMove, ...] = ()
    hoists: tuple[Hoist, ...] = ()  # rope length changes (settings.rope_length_m is the length at t = 0)
    pulls: tuple[Pull, ...] = ()  # tag-line forces on the load (settings.hook_mass_kg is hook + load)
    seed: int = 0


@dataclass(frozen=True)
class HookTruth:
    """Ground truth at every output sample (N samples); body frame = hook IMU frame."""

    t_s: FloatArray  # (N,)
    quat: FloatArray  # (N, 4) hook attitude, wxyz, body -> ENU
    gyr_rad_s: FloatArray  # (N, 3) body angular rate
    acc_m_s2: FloatArray  # (N, 3) specific force at the IMU, body frame
    mag_uT: FloatArray  # (N, 3) earth field in the body frame
    swing_rad: FloatArray  # (N,) Θ: angle between the rope and the vertical
    swing_bearing_rad: FloatArray  # (N,) bearing of the hook's horizontal displacement, CCW from East
    torsion_rad: FloatArray  # (N,) φ: twist about the rope relative to the rest heading
    rope_dir: FloatArray  # (N, 3) n, unit vector from the hook up to the boom tip, ENU
    rope_rate_1_s: FloatArray  # (N, 3) n'
    tension_per_mass_m_s2: FloatArray  # (N,) T / m
    suspension_pos_m: FloatArray  # (N, 3) boom tip A, ENU (starts at (0, 0, l))
    suspension_vel_m_s: FloatArray  # (N, 3)
    suspension_acc_m_s2: FloatArray  # (N, 3)
    hook_pos_m: FloatArray  # (N, 3) hook centre B
    extra: dict[str, FloatArray] = field(default_factory=dict)


def _ou_process(
    rng: np.random.Generator, n: int, x0: FloatArray, std: float, tau_s: float, dt_s: float
) -> FloatArray:
    """n Ornstein-Uhlenbeck samples (n, dims) continuing from `x0`, stationary std `std`, correlation `tau_s`."""
    out = np.zeros((n, x0.shape[0]))
    if std <= 0.0 or n == 0:
        return out
    a = math.exp(-dt_s / tau_s)
    noise = rng.standard_normal((n, x0.shape[0])) * (std * math.sqrt(1.0 - a * a))
    x = x0.copy()
    for i in range(n):
        x = a * x + noise[i]
        out[i] = x
    return out


def suspension_acceleration(moves: tuple[TrolleyMove, ...], t_s: FloatArray,
                            slews: tuple[SlewMove, ...] = ()) -> FloatArray:
    """Boom-tip acceleration (..., 3) at times `t_s` from the scripted moves (they add where they overlap)."""
    acc = slew_acceleration(slews, t_s) if slews else np.zeros((*np.shape(t_s), 3))
    for m in moves:
        on = (t_s >= m.start_s) & (t_s < m.start_s + m.duration_s)
        acc[on, 0] += m.acc_m_s2[0]
        acc[on, 1] += m.acc_m_s2[1]
    return acc


def rope_accel(
    n: FloatArray, v: FloatArray, a_ext: FloatArray, rope_length_m: float | FloatArray, damping_1_s: float
) -> tuple[FloatArray, FloatArray]:
    """`(n'', T/m)` for rope direction `n` and rate `v`, (..., 3) each; `a_ext` excludes the swing damping."""
    a = a_ext + damping_1_s * rope_length_m * v  # air damping opposes the hook's velocity -l n'
    n_dot_a = np.sum(n * a, axis=-1, keepdims=True)
    v2 = np.sum(v * v, axis=-1, keepdims=True)
    ndd = -(a - n_dot_a * n) / rope_length_m - v2 * n
    return ndd, (rope_length_m * v2 - n_dot_a)[..., 0]


def swing_quaternion(n: FloatArray) -> FloatArray:
    """Shortest rotation (..., 4) taking earth up `e_z` onto the unit vector `n` (..., 3); undefined at `n = -e_z`."""
    s = np.sqrt(2.0 * (1.0 + n[..., 2]))
    return np.stack([0.5 * s, -n[..., 1] / s, n[..., 0] / s, np.zeros_like(s)], axis=-1)


def _swing_quaternion_rate(n: FloatArray, v: FloatArray) -> FloatArray:
    """Time derivative of `swing_quaternion(n)` for `n' = v`."""
    s = np.sqrt(2.0 * (1.0 + n[..., 2]))
    sd = v[..., 2] / s
    p = np.stack([1.0 + n[..., 2], -n[..., 1], n[..., 0], np.zeros_like(s)], axis=-1)
    pd = np.stack([v[..., 2], -v[..., 1], v[..., 0], np.zeros_like(s)], axis=-1)
    rate: FloatArray = pd / s[..., None] - p * (sd / (s * s))[..., None]
    return rate


def _twist_quaternion(alpha_rad: FloatArray) -> FloatArray:
    z = np.zeros_like(alpha_rad)
    return np.stack([np.cos(0.5 * alpha_rad), z, z, np.sin(0.5 * alpha_rad)], axis=-1)


def hook_attitude_and_rate(
    n: FloatArray, v: FloatArray, alpha_rad: FloatArray, alpha_rate_rad_s: FloatArray
) -> tuple[FloatArray, FloatArray]:
    """Attitude `q_swing(n) ⊗ q_z(α)` (..., 4) and body rate `2 vec(q* ⊗ q')` (..., 3) in rad/s."""
    qs = swing_quaternion(n)
    qz = _twist_quaternion(alpha_rad)
    qzd = 0.5 * alpha_rate_rad_s[..., None] * np.stack(
        [-np.sin(0.5 * alpha_rad), np.zeros_like(alpha_rad), np.zeros_like(alpha_rad), np.cos(0.5 * alpha_rad)],
        axis=-1,
    )
    q = _quat.multiply(qs, qz)
    qd = _quat.multiply(_swing_quaternion_rate(n, v), qz) + _quat.multiply(qs, qzd)
    return q, 2.0 * _quat.multiply(_quat.conjugate(q), qd)[..., 1:]


@dataclass
class _State:
    """Integrator state between chunks (ENU; `step` counts internal steps since t = 0)."""

    s: list[float]  # nx, ny, nz, vx, vy, vz, phi, phi_rate
    susp: list[float]  # boom-tip x, y, vx, vy
    gust: FloatArray  # (2,) OU wind force per unit mass
    gust_torque: FloatArray  # (1,) OU torque
    step: int = 0


def _initial_state(scenario: HookScenario, rng: np.random.Generator) -> _State:
    th0, b0 = scenario.initial_swing_rad, scenario.initial_swing_bearing_rad
    w0 = 0.0 if scenario.hold_s > 0 else scenario.initial_sideways_rate_rad_s
    pd = 0.0 if scenario.hold_s > 0 else scenario.initial_torsion_rate_rad_s
    # The hook is displaced towards b0, so the rope (hook -> tip) leans the other way.
    s = [
        -math.sin(th0) * math.cos(b0), -math.sin(th0) * math.sin(b0), math.cos(th0),
        -math.sin(b0) * w0, math.cos(b0) * w0, 0.0, scenario.initial_torsion_rad, pd,
    ]  # fmt: skip
    return _State(
        s, [0.0, 0.0, 0.0, 0.0], rng.standard_normal(2) * scenario.wind_std_m_s2,
        rng.standard_normal(1) * scenario.wind_torque_std_n_m,
    )


def _integrate(
    settings: HookPhysicsSettings, scenario: HookScenario, state: _State, n_out: int, rng: np.random.Generator
) -> dict[str, FloatArray]:
    """RK4 over the internal grid for `n_out` output samples from `state` (advanced in place); returns the state
    at each output sample (plain-float loop: fast in CPython)."""
    rate = settings.internal_rate_hz
    sub = round(rate / scenario.output_rate_hz)
    if abs(sub * scenario.output_rate_hz - rate) > 1e-9 * rate:
        raise ValueError("internal_rate_hz must be an integer multiple of output_rate_hz")
    dt = 1.0 / rate
    n_steps = n_out * sub
    gust = _ou_process(rng, n_steps, state.gust, scenario.wind_std_m_s2, scenario.wind_tau_s, dt)
    gust_torque = _ou_process(rng, n_steps, state.gust_torque, scenario.wind_torque_std_n_m, scenario.wind_tau_s, dt)
    if n_steps:
        state.gust, state.gust_torque = gust[-1].copy(), gust_torque[-1].copy()
    t_grid = (state.step + np.arange(n_steps, dtype=np.float64)) * dt
    t_mid = t_grid + 0.5 * dt  # forcing held over each step
    a_susp = suspension_acceleration(scenario.trolley_moves, t_mid, scenario.slews)
    wind = np.zeros((n_steps, 3))
    wind[:, :2] = gust + np.asarray(scenario.wind_mean_m_s2)
    wind += pull_force(scenario.pulls, settings.hook_mass_kg, t_mid)
    len_l, len_d, _ = rope_length(settings.rope_length_m, scenario.hoists, t_mid)
    len_l_l, len_d_l = len_l.tolist(), len_d.tolist()
    g, c = settings.gravity_m_s2, settings.swing_damping_1_s
    k_j = settings.torsion_stiffness_n_m_rad / settings.torsion_inertia_kg_m2
    c_j = settings.torsion_damping_n_m_s_rad / settings.torsion_inertia_kg_m2
    inv_j = 1.0 / settings.torsion_inertia_kg_m2
    wx_l, wy_l, ax_l, ay_l, tq_l = (
        wind[:, 0].tolist(), wind[:, 1].tolist(), a_susp[:, 0].tolist(), a_susp[:, 1].tolist(),
        gust_torque[:, 0].tolist(),
    )  # fmt: skip
    nx, ny, nz, vx, vy, vz, ph, pd = state.s
    px, py, vxa, vya = state.susp
    n_hold = int(round(scenario.hold_s * rate))

    def deriv(
        s: tuple[float, float, float, float, float, float, float, float], ex: float, ey: float, ez: float, tq: float,
        l: float, ld: float,
    ) -> tuple[float, float, float, float, float, float, float, float]:
        nx, ny, nz, vx, vy, vz, ph, pd = s
        axx, ayy, azz = ex + c * l * vx, ey + c * l * vy, ez + c * l * vz
        nda = nx * axx + ny * ayy + nz * azz
        v2 = vx * vx + vy * vy + vz * vz
        k = 2.0 * ld / l
        return (
            vx, vy, vz,
            -(axx - nda * nx) / l - v2 * nx - k * vx, -(ayy - nda * ny) / l - v2 * ny - k * vy,
            -(azz - nda * nz) / l - v2 * nz - k * vz,
            pd, -k_j * ph - c_j * pd + inv_j * tq,
        )  # fmt: skip

    keys = ("n", "v", "phi", "phi_rate", "susp_pos", "susp_vel", "wind", "torque", "t")
    out: dict[str, list[object]] = {k: [] for k in keys}

    for i in range(n_steps):
        if i % sub == 0:
            out["n"].append((nx, ny, nz))
            out["v"].append((vx, vy, vz))
            out["phi"].append(ph)
            out["phi_rate"].append(pd)
            out["susp_pos"].append((px, py, settings.rope_length_m))
            out["susp_vel"].append((vxa, vya, 0.0))
            out["wind"].append((wx_l[i], wy_l[i], 0.0))
            out["torque"].append(tq_l[i])
            out["t"].append((state.step + i) * dt)
        if state.step + i < n_hold:
            continue
        ex, ey, ez = wx_l[i] - ax_l[i], wy_l[i] - ay_l[i], -g
        tq, li, ldi = tq_l[i], len_l_l[i], len_d_l[i]
        s0 = (nx, ny, nz, vx, vy, vz, ph, pd)
        k1 = deriv(s0, ex, ey, ez, tq, li, ldi)
        k2 = deriv(tuple(a + 0.5 * dt * b for a, b in zip(s0, k1, strict=True)), ex, ey, ez, tq, li, ldi)  # type: ignore[arg-type]
        k3 = deriv(tuple(a + 0.5 * dt * b for a, b in zip(s0, k2, strict=True)), ex, ey, ez, tq, li, ldi)  # type: ignore[arg-type]
        k4 = deriv(tuple(a + dt * b for a, b in zip(s0, k3, strict=True)), ex, ey, ez, tq, li, ldi)  # type: ignore[arg-type]
        nx, ny, nz, vx, vy, vz, ph, pd = (
            a + dt / 6.0 * (b1 + 2.0 * b2 + 2.0 * b3 + b4) for a, b1, b2, b3, b4 in zip(s0, k1, k2, k3, k4, strict=True)
        )
        # Back onto the constraint manifold: |n| = 1 and n . n' = 0.
        norm = math.sqrt(nx * nx + ny * ny + nz * nz)
        nx, ny, nz = nx / norm, ny / norm, nz / norm
        ndv = nx * vx + ny * vy + nz * vz
        vx, vy, vz = vx - ndv * nx, vy - ndv * ny, vz - ndv * nz
        px += vxa * dt + 0.5 * ax_l[i] * dt * dt
        py += vya * dt + 0.5 * ay_l[i] * dt * dt
        vxa += ax_l[i] * dt
        vya += ay_l[i] * dt
    state.s = [nx, ny, nz, vx, vy, vz, ph, pd]
    state.susp = [px, py, vxa, vya]
    state.step += n_steps
    arrays = {k: np.asarray(v, dtype=np.float64) for k, v in out.items()}
    for k, dims in (("n", 3), ("v", 3), ("susp_pos", 3), ("susp_vel", 3), ("wind", 3)):
        arrays[k] = arrays[k].reshape(-1, dims)
    return arrays


def simulate(settings: HookPhysicsSettings, scenario: HookScenario) -> HookTruth:
    """Integrate the scenario and return the ground truth at `scenario.output_rate_hz`."""
    return HookStream(settings, scenario).advance(int(round(scenario.duration_s * scenario.output_rate_hz)))


class HookStream:
    """The same simulation in chunks, for live devices: `advance(n)` returns the next n output samples."""

    def __init__(self, settings: HookPhysicsSettings, scenario: HookScenario) -> None:
        self.settings, self.scenario = settings, scenario
        self.rng = np.random.default_rng(scenario.seed)
        self.state = _initial_state(scenario, self.rng)

    def advance(self, n_samples: int) -> HookTruth:
        """Integrate `n_samples` output samples further; the truth of those samples."""
        st = _integrate(self.settings, self.scenario, self.state, n_samples, self.rng)
        return _truth(self.settings, self.scenario, st)


def _truth(settings: HookPhysicsSettings, scenario: HookScenario, st: dict[str, FloatArray]) -> HookTruth:
    """Ground truth (attitude, rates, specific force...) from integrator states at the output samples."""
    n, v, phi, phi_rate = st["n"], st["v"], st["phi"], st["phi_rate"]
    t = st["t"]
    dt_int = 1.0 / settings.internal_rate_hz
    t_mid = t + 0.5 * dt_int
    a_susp = suspension_acceleration(scenario.trolley_moves, t_mid, scenario.slews)
    g_vec = np.array([0.0, 0.0, -settings.gravity_m_s2])
    a_ext = g_vec - a_susp + st["wind"]
    l_m, l_rate, l_acc = rope_length(settings.rope_length_m, scenario.hoists, t_mid)
    l, c = l_m[:, None], settings.swing_damping_1_s
    ndd, tension = rope_accel(n, v, a_ext, l, c)
    ndd -= 2.0 * (l_rate / l_m)[:, None] * v
    tension -= l_acc
    k_j = settings.torsion_stiffness_n_m_rad / settings.torsion_inertia_kg_m2
    c_j = settings.torsion_damping_n_m_s_rad / settings.torsion_inertia_kg_m2
    phi_acc = -k_j * phi - c_j * phi_rate + st["torque"] / settings.torsion_inertia_kg_m2
    held = t < scenario.hold_s - 0.5 * dt_int
    ndd[held] = 0.0
    phi_acc[held] = 0.0
    alpha = settings.rest_heading_rad + phi
    q, w_b = hook_attitude_and_rate(n, v, alpha, phi_rate)
    # ω_b' as the derivative along the state's own velocity (central difference; error O(h²) ≈ 1e-10 rad/s²).
    h = 1e-5
    _, w_plus = hook_attitude_and_rate(n + h * v, v + h * ndd, alpha + h * phi_rate, phi_rate + h * phi_acc)
    _, w_minus = hook_attitude_and_rate(n - h * v, v - h * ndd, alpha - h * phi_rate, phi_rate - h * phi_acc)
    w_dot = (w_plus - w_minus) / (2.0 * h)
    r_b = np.asarray(settings.lever_arm_m, dtype=np.float64)
    f_b_earth = tension[:, None] * n + st["wind"] + c * l * v  # rope pull + wind, tag line, air damping per mass
    f_b_earth[held] = -g_vec  # held: the holding force balances gravity
    tension[held] = settings.gravity_m_s2 * n[held, 2]
    acc = _quat.rotate_inverse(q, f_b_earth) + np.cross(w_dot, r_b) + np.cross(w_b, np.cross(w_b, r_b))
    mag = _quat.rotate_inverse(q, np.broadcast_to(np.asarray(settings.earth_field_uT, dtype=np.float64), n.shape))
    susp = st["susp_pos"]
    return HookTruth(
        t_s=t,
        quat=q,
        gyr_rad_s=w_b,
        acc_m_s2=acc,
        mag_uT=mag,
        swing_rad=np.arccos(np.clip(n[:, 2], -1.0, 1.0)),
        swing_bearing_rad=np.arctan2(-n[:, 1], -n[:, 0]),
        torsion_rad=phi,
        rope_dir=n,
        rope_rate_1_s=v,
        tension_per_mass_m_s2=tension,
        suspension_pos_m=susp,
        suspension_vel_m_s=st["susp_vel"],
        suspension_acc_m_s2=a_susp,
        hook_pos_m=susp - l * n,
        extra={"gyr_dot_rad_s2": w_dot, "torsion_rate_rad_s": phi_rate, "rope_length_m": l_m, "rope_rate_m_s": l_rate,
               "force_m_s2": st["wind"]},
    )


def pendulum_energy_per_mass(truth: HookTruth, settings: HookPhysicsSettings) -> FloatArray:
    """Swing energy per unit mass in J/kg about a fixed boom tip: `½ l² |n'|² - g l n_z`."""
    l = settings.rope_length_m
    v2 = np.sum(truth.rope_rate_1_s**2, axis=-1)
    energy: FloatArray = 0.5 * l * l * v2 - settings.gravity_m_s2 * l * truth.rope_dir[:, 2]
    return energy
