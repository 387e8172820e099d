"""Live vertical velocity and height (heave) of one device from its fused attitude (seed 002 eq. 6-8), drift held.

Per sample (attitude q from the device's filter, specific force f in m/s², dt in s):

    f_up  = (q ⊗ f ⊗ q*)_z                   vertical specific force (eq. 6-7, Coriolis/transport terms left out)
    a_up  = f_up − g                         g learnt at rest (below), so the accelerometer's vertical offset and
                                             scale error do not integrate
    V_z  += ∫ a_up − V_z / tau_v  dt         trapezoidal (eq. 8 integrand); the leak only once free-running
    H    += ∫ V_z − H / tau_h     dt         eq. 8; H leaks towards the last rest height only once free-running

Drift is held by three things:
- **rest detection**: |ω| < `rest_gyr_rad_s` and | |f| − g | < `rest_acc_m_s2` for `rest_time_s` → V_z = 0 (zero
  velocity update), H held, and g follows f_up with time constant `gravity_tau_s` (on samples with |a_up| below
  `onset_acc_m_s2`, so a starting motion does not leak into g). An IMU cannot tell rest from steady motion, so
  while |V_z| ≥ `rest_speed_m_s` the quiet spell must last `rest_time_moving_s` instead: a steady
  hoist shorter than that keeps its velocity, and a velocity that drifted is still reset after a longer rest. The
  detector notices a start only once |a| passes its threshold, so the motion integrated since |a_up| last was below
  `onset_acc_m_s2` is handed back to V_z and H when rest ends;
- **the depth sensor** where the device has one (`depth_m` samples, NaN between): a second-order complementary
  observer pulls H towards −depth and V_z along with it (crossover `depth_crossover_rad_s`, damping 0.7), so the
  height is then "minus the depth" and its drift is bounded by the sensor;
- **a high-pass once free-running**: after `leak_after_s` without rest or depth (a hook that keeps swinging, minutes
  of hand-held motion) velocity and height leak (`velocity_leak_tau_s`, `height_leak_tau_s`) towards the last rest
  height and g follows f_up slowly (`gravity_tau_moving_s`: over a swing or a ride the mean vertical acceleration is
  zero), so the output becomes heave about that height instead of a drift without bound; `aided` says `highpass`.
  Moves between rests shorter than `leak_after_s` (hoisting) are integrated without leaks.

`run_heave` is the batch form (numba), `HeaveEstimator` the streaming one the gateway calls per device and block;
both run the same step.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from gateway.fusion import quaternion as quat
from gateway.fusion.base import FloatArray
from gateway.fusion.quaternion import njit

# state: V_z, H, previous a_up, g, rest timer, have-previous, rest height, time since the last depth sample, depth seen,
# onset velocity and height (integrated since |a_up| was last below the onset level), previous at-rest flag, time
# since the last rest or depth sample
N_STATE = 13
(S_V, S_H, S_APREV, S_G, S_REST_T, S_HAVE, S_HREST, S_DEPTH_AGE, S_DEPTH_SEEN, S_VON, S_HON,
 S_WAS_REST, S_FREE_T) = range(N_STATE)
# per-sample output columns: H, V_z, at rest (0/1), aided (0 none, 1 rest, 2 depth, 3 highpass)
AIDED_NAMES: tuple[str, ...] = ("none", "rest", "depth", "highpass")
DEPTH_DAMPING = 0.7


@dataclass(frozen=True)
class HeaveSettings:
    """Rest detector, gravity learning, depth observer and leaks; a tau of 0 turns that leak off."""

    rest_gyr_rad_s: float = 0.05
    """Rest when |ω| (raw, rad/s) stays below this ..."""
    rest_acc_m_s2: float = 0.3
    """... and | |f| − g | (m/s²) below this ..."""
    rest_time_s: float = 0.2
    """... for this long (s) ..."""
    rest_speed_m_s: float = 0.1
    """... while the estimated |V_z| is below this; above it ..."""
    rest_time_moving_s: float = 3.0
    """... the quiet spell must last this long (s): steady motion looks like rest to an IMU."""
    onset_acc_m_s2: float = 0.05
    """|a_up| below which a motion has not started yet (the onset integral restarts there), m/s²."""
    gravity_tau_s: float = 10.0
    """At rest, g follows the vertical specific force with this time constant (s)."""
    gravity_m_s2: float = quat.GRAVITY_M_S2
    """g before the first rest (the gateway seeds it from the warm-up window)."""
    depth_crossover_rad_s: float = 1.0
    """Crossover of the depth observer (rad/s): above it the accelerometer, below it the depth sensor."""
    depth_max_age_s: float = 1.0
    """A depth sample older than this no longer counts as aiding."""
    leak_after_s: float = 10.0
    """Free-running (no rest, no depth) this long (s), the leaks below apply; 0: always; inf: never."""
    velocity_leak_tau_s: float = 2.0
    """Velocity leak time constant once free-running (s); 0: none."""
    height_leak_tau_s: float = 5.0
    """Height leak towards the last rest height once free-running (s); 0: none."""
    gravity_tau_moving_s: float = 30.0
    """Once free-running, g follows f_up with this time constant (s); 0: g only learnt at rest."""

    def as_array(self) -> FloatArray:
        return np.array([self.rest_gyr_rad_s, self.rest_acc_m_s2, self.rest_time_s, self.gravity_tau_s,
                         self.depth_crossover_rad_s, self.depth_max_age_s, _rate(self.velocity_leak_tau_s),
                         _rate(self.height_leak_tau_s), self.rest_speed_m_s, self.rest_time_moving_s,
                         self.onset_acc_m_s2, self.leak_after_s, self.gravity_tau_moving_s])  # fmt: skip


def _rate(tau_s: float) -> float:
    return 0.0 if tau_s <= 0.0 or not np.isfinite(tau_s) else 1.0 / tau_s


def initial_state(gravity_m_s2: float = quat.GRAVITY_M_S2, height_m: float = 0.0) -> FloatArray:
    """State at rest at `height_m`, with g as given."""
    s = np.zeros(N_STATE)
    s[S_G], s[S_H], s[S_HREST], s[S_DEPTH_AGE] = gravity_m_s2, height_m, height_m, np.inf
    return s


@njit
def heave_step(state: FloatArray, f_up_m_s2: float, gyr_norm_rad_s: float, acc_norm_m_s2: float, depth_m: float,
               dt_s: float, params: FloatArray) -> tuple[float, float, float, float]:  # fmt: skip
    """Advance `state` by one sample in place; returns (H m, V_z m/s, at rest 0/1, aided index)."""
    rest_gyr, rest_acc, rest_time, g_tau, w_c, depth_age_max, kv, kh = (
        params[0], params[1], params[2], params[3], params[4], params[5], params[6], params[7])
    rest_speed, rest_time_moving, onset, leak_after, g_tau_moving = params[8], params[9], params[10], params[11], \
        params[12]
    free = state[S_FREE_T] >= leak_after
    if not free:
        kv, kh = 0.0, 0.0
    elif g_tau_moving > 0.0:
        state[S_G] += min(1.0, dt_s / g_tau_moving) * (f_up_m_s2 - state[S_G])
    a_up = f_up_m_s2 - state[S_G]
    if state[S_HAVE] > 0.0:
        v, h = state[S_V], state[S_H]
        v_new = (v * (1.0 - 0.5 * kv * dt_s) + 0.5 * (state[S_APREV] + a_up) * dt_s) / (1.0 + 0.5 * kv * dt_s)
        h_rel = h - state[S_HREST]
        h_rel = (h_rel * (1.0 - 0.5 * kh * dt_s) + 0.5 * (v + v_new) * dt_s) / (1.0 + 0.5 * kh * dt_s)
        state[S_V], state[S_H] = v_new, state[S_HREST] + h_rel
    state[S_HAVE] = 1.0
    state[S_APREV] = a_up
    if abs(a_up) < onset:
        state[S_VON], state[S_HON] = 0.0, 0.0
    else:
        state[S_VON] += a_up * dt_s
        state[S_HON] += state[S_VON] * dt_s
    # rest detection: zero velocity, hold height, learn g
    if gyr_norm_rad_s < rest_gyr and abs(acc_norm_m_s2 - state[S_G]) < rest_acc:
        state[S_REST_T] += dt_s
    else:
        state[S_REST_T] = 0.0
    at_rest = state[S_REST_T] >= (rest_time if abs(state[S_V]) < rest_speed else rest_time_moving)
    aided = 0.0
    if state[S_WAS_REST] > 0.0 and not at_rest:  # a motion began while the detector still said rest
        state[S_V] = state[S_VON]
        state[S_H] += state[S_HON]
    if at_rest:
        state[S_V] = 0.0
        if state[S_WAS_REST] > 0.0:
            state[S_H] = state[S_HREST]  # hold the height rest began at
        else:
            state[S_HREST] = state[S_H]
        if g_tau > 0.0 and abs(a_up) < onset:  # not from a motion that has begun but is not yet detected
            state[S_G] += min(1.0, dt_s / g_tau) * (f_up_m_s2 - state[S_G])
        state[S_APREV] = f_up_m_s2 - state[S_G]
        aided = 1.0
    # depth observer (second order): H → −depth
    state[S_DEPTH_AGE] += dt_s
    if np.isfinite(depth_m):
        dt_d = min(state[S_DEPTH_AGE], depth_age_max)
        e = -depth_m - state[S_H]
        if state[S_DEPTH_SEEN] == 0.0:  # first depth sample: jump to it
            state[S_H] = -depth_m
            state[S_DEPTH_SEEN] = 1.0
        else:
            state[S_H] += min(1.0, 2.0 * DEPTH_DAMPING * w_c * dt_d) * e
            if not at_rest:
                state[S_V] += min(w_c * w_c * dt_d, 1.0 / max(dt_d, 1e-9)) * e
        state[S_HREST] = state[S_H] if at_rest else state[S_HREST]
        state[S_DEPTH_AGE] = 0.0
    state[S_WAS_REST] = 1.0 if at_rest else 0.0
    if state[S_DEPTH_SEEN] > 0.0 and state[S_DEPTH_AGE] <= depth_age_max:
        aided = 2.0
    state[S_FREE_T] = 0.0 if aided > 0.0 else state[S_FREE_T] + dt_s
    if aided == 0.0 and free:
        aided = 3.0
    return state[S_H], state[S_V], 1.0 if at_rest else 0.0, aided


@njit
def _heave_row(state: FloatArray, q: FloatArray, gyr_rad_s: FloatArray, acc_m_s2: FloatArray, depth_m: FloatArray,
               i: int, dt_s: float, params: FloatArray, out: FloatArray) -> None:  # fmt: skip
    """`heave_step` on row i of the blocks (the vertical specific force from the attitude), written to `out[i]`."""
    w, x, y, z = q[i, 0], q[i, 1], q[i, 2], q[i, 3]
    ax, ay, az = acc_m_s2[i, 0], acc_m_s2[i, 1], acc_m_s2[i, 2]
    f_up = 2.0 * (x * z - w * y) * ax + 2.0 * (y * z + w * x) * ay + (1.0 - 2.0 * (x * x + y * y)) * az
    g_norm = np.sqrt(gyr_rad_s[i, 0] ** 2 + gyr_rad_s[i, 1] ** 2 + gyr_rad_s[i, 2] ** 2)
    a_norm = np.sqrt(ax * ax + ay * ay + az * az)
    d = depth_m[i] if depth_m.shape[0] > 0 else np.nan
    h, v, r, a = heave_step(state, f_up, g_norm, a_norm, d, dt_s, params)
    out[i, 0], out[i, 1], out[i, 2], out[i, 3] = h, v, r, a


@njit
def heave_run(state: FloatArray, q: FloatArray, gyr_rad_s: FloatArray, acc_m_s2: FloatArray, depth_m: FloatArray,
              dt_s: float, params: FloatArray) -> FloatArray:  # fmt: skip
    """`heave_step` over a block: q (N, 4), gyro and specific force (N, 3), depth (N,) with NaN where none, or (0,)
    for no depth sensor. Returns (N, 4): H, V_z, at rest, aided. One call per block, no temporaries."""
    out = np.empty((acc_m_s2.shape[0], 4))
    for i in range(acc_m_s2.shape[0]):
        _heave_row(state, q, gyr_rad_s, acc_m_s2, depth_m, i, dt_s, params, out)
    return out


@njit
def heave_run_segments(states: FloatArray, q: FloatArray, gyr_rad_s: FloatArray, acc_m_s2: FloatArray,
                       depth_m: FloatArray, start: np.ndarray, stop: np.ndarray, dt_s: FloatArray,
                       params: FloatArray) -> FloatArray:  # fmt: skip
    """`heave_run` of several devices' blocks in one call: rows `start[k]:stop[k]` of the concatenated arrays are
    device k's, stepped with its own state row `states[k]` (advanced in place), `dt_s[k]` and `params[k]`; rows of
    no segment are left unset. The same arithmetic per sample as `heave_run`, so each device gets the same values."""
    out = np.empty((acc_m_s2.shape[0], 4))
    for k in range(start.shape[0]):
        for i in range(start[k], stop[k]):
            _heave_row(states[k], q, gyr_rad_s, acc_m_s2, depth_m, i, dt_s[k], params[k], out)
    return out


def run_heave(q: ArrayLike, gyr_rad_s: ArrayLike, acc_m_s2: ArrayLike, dt_s: float,
              settings: HeaveSettings | None = None, depth_m: ArrayLike | None = None,
              state: FloatArray | None = None) -> FloatArray:  # fmt: skip
    """Batch heave over a run: attitudes (N, 4), raw gyro and specific force (N, 3), optional depth (N,) with NaN
    where there is no sample. Returns (N, 4): H (m), V_z (m/s), at rest (0/1), aided (index into AIDED_NAMES).
    `state` (from `initial_state`) is advanced in place when given."""
    s = settings or HeaveSettings()
    st = initial_state(s.gravity_m_s2) if state is None else state
    return _run(st, q, gyr_rad_s, acc_m_s2, dt_s, depth_m, s.as_array())


_NO_DEPTH = np.zeros(0)


def _run(state: FloatArray, q: ArrayLike, gyr_rad_s: ArrayLike, acc_m_s2: ArrayLike, dt_s: float,
         depth_m: ArrayLike | None, params: FloatArray) -> FloatArray:  # fmt: skip
    def f64(a: ArrayLike) -> FloatArray:
        return np.ascontiguousarray(a, dtype=np.float64)

    depth = _NO_DEPTH if depth_m is None else f64(depth_m)
    return heave_run(state, f64(q), f64(gyr_rad_s), f64(acc_m_s2), depth, float(dt_s), params)


class HeaveEstimator:
    """Streaming heave of one device: `update(q, gyr, acc, dt, depth)` per block, state kept between blocks."""

    def __init__(self, settings: HeaveSettings | None = None, gravity_m_s2: float | None = None) -> None:
        self.settings = settings or HeaveSettings()
        self.state = initial_state(self.settings.gravity_m_s2 if gravity_m_s2 is None else gravity_m_s2)
        self._params = self.settings.as_array()

    def update(self, q: ArrayLike, gyr_rad_s: ArrayLike, acc_m_s2: ArrayLike, dt_s: float,
               depth_m: ArrayLike | None = None) -> FloatArray:  # fmt: skip
        """(N, 4) rows of H, V_z, at rest, aided for the block's samples."""
        return _run(self.state, q, gyr_rad_s, acc_m_s2, dt_s, depth_m, self._params)

    @property
    def params(self) -> FloatArray:
        """The settings as the kernels take them (`HeaveSettings.as_array`)."""
        return self._params

    @property
    def gravity_m_s2(self) -> float:
        """g as learnt at rest (m/s²)."""
        return float(self.state[S_G])
