"""Randomised rod recordings for judging the bite alarm (issue 10): one rod per seed, labelled events, true attitude
and MPU-6050-like IMU samples. Pure numpy, no I/O.

    sc = make_scenario(seed=1000)                 # 5 min at 100 Hz, about 18 events
    sc.gyr_rad_s, sc.acc_m_s2, sc.mag_uT         # measured, (n, 3); sc.quat_wxyz / sc.euler_rad are the truth
    [(e.family, e.t_start_s, e.cross_s) for e in sc.events]

Events (kinds and ranges from issue 10; "down" = tip pulled below rest, in degrees of pitch):

- bite: pulled down to a hold of 12-24° (rise 0.1-0.6 s), ringing peaks up to 35°, held 0.5-5 s with 0-3
  tugs of 2-6°, then let go (0.1-0.5 s);
- run: pulled down 15-28° (rise 0.3-1.5 s), held 3-10 s while the fish swims (±3° wander), let go over 0.3-1 s;
- nibble: 1-6 taps 0.15-0.6 s apart, short pulls (40-150 ms) dipping the tip 1-6° in all, each with a 1-6 g jolt;
- knock: the rod or holder is knocked, a 15-40 Hz jolt of 2-6 g for 10-30 ms and a tip ring of at most 1.5°;
- wind: ±1-5° of sway (three 0.5-3 Hz components and a gust) for 5-30 s, twice that in yaw;
- handling: picked up and turned, yaw 10-60°, roll 5-40°, pitch within 2.5°, over 1-3 s;
- drop_back: the line goes slack, tip up 8-20° (rise 0.3-1.5 s) for 2-8 s, then re-tensioned over 0.5-2 s.

Tip model: a pull (bites, runs, nibbles, drop-backs; a command in degrees) drives a second-order tip mode (2-3 Hz,
damping 0.2-0.35, per rod; Tustin-discretised at 1 kHz), so ringing and overshoot come from that mode, on the pull
and on the release. Wind and handling move the angles directly. Jolts (taps, knocks) are smooth bursts (a
sin^2-windowed sine of 15-40 Hz) added to pitch and yaw, scaled so the tip's tangential acceleration peaks at the
drawn value (gravity comes on top). Rates and accelerations are central differences at 1 kHz, and the tip's
specific force and body rates follow from the kinematics (`rod_physics.tip_kinematics`, 0.8 m lever). Each
100 Hz sample is the mean of 10 such 1 kHz values (a stand-in for the sensor's low-pass), then goes through
`devices.common.SensorModel` with the MPU-6050 datasheet errors of `ImuErrorModel()` (20 mg accelerometer offset,
1 °/s gyro bias, noise, scale, misalignment, 5 µT hard iron) at ±2 g (AFS_SEL=0: knocks, taps and fast bites
clip) and ±500 °/s (FS_SEL=1, as the simulators; the fastest turn in the suite is ~250 °/s). Between events the
rod is quiet (6-14 s) but for a slow ±0.1-0.3° wave ripple; the first 8 s are quiet (gateway warm-up).
"""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass, field

import numpy as np
from numpy.typing import NDArray
from scipy.signal import bilinear, lfilter

from devices.common import EARTH_FIELD_ENU_UT, G_M_S2, ImuErrorModel, SensorModel, field_body
from devices.rod_physics import tip_kinematics

FloatArray = NDArray[np.float64]

FAMILIES: tuple[str, ...] = ("bite", "run", "nibble", "knock", "wind", "handling", "drop_back")
ALARMING: tuple[str, ...] = ("bite", "run")  # families that must raise a bite alarm; all others must not


@dataclass(frozen=True)
class ScenarioSettings:
    """Recording length, rates and the sensor; angles in degrees where the name says so."""

    duration_s: float = 300.0
    rate_hz: float = 100.0
    substeps: int = 10  # kinematics at rate_hz * substeps
    lever_m: float = 0.8
    quiet_start_s: float = 8.0
    gap_s: tuple[float, float] = (6.0, 14.0)
    theta1_deg: float = 10.0  # for the true crossing time of bites and runs
    acc_fs_g: float = 2.0
    gyro_fs_deg_s: float = 500.0
    max_bite_peak_deg: float = 35.0
    imu: ImuErrorModel = field(default_factory=ImuErrorModel)  # MPU-6050 datasheet errors (devices.common)

    def error_model(self) -> ImuErrorModel:
        """The IMU error model at this accelerometer and gyro full scale."""
        return dataclasses.replace(self.imu, acc_fs_m_s2=self.acc_fs_g * G_M_S2,
                                   gyro_fs_rad_s=math.radians(self.gyro_fs_deg_s))  # fmt: skip


@dataclass(frozen=True)
class ScenarioEvent:
    """One labelled event in recording time (s); `cross_s` is the first sample whose true pitch is theta1 or more
    below rest (bites and runs; nan otherwise); `peak_deg` the largest true excursion from rest it caused."""

    family: str
    t_start_s: float
    t_end_s: float
    cross_s: float = math.nan
    peak_deg: float = 0.0
    detail: str = ""


@dataclass(frozen=True)
class Scenario:
    """One rod recording: sample times (s, 0 = start), truth and measured IMU signals, each (n, ...)."""

    seed: int
    t_s: FloatArray
    rest_pitch_rad: float
    euler_rad: FloatArray  # true roll, pitch, yaw at each sample
    quat_wxyz: FloatArray
    gyr_rad_s: FloatArray
    acc_m_s2: FloatArray
    mag_uT: FloatArray
    acc_true_max_g: FloatArray  # largest |specific force| (g) in each sample's 10 ms, before the sensor
    events: tuple[ScenarioEvent, ...]

    @property
    def hours(self) -> float:
        """Recording length in hours (the first sample is at one sample period)."""
        return float(self.t_s[-1]) / 3600.0


def raised_cosine(t: FloatArray, t0_s: float, rise_s: float) -> FloatArray:
    """0 before t0, 1 after t0 + rise, a half cosine in between."""
    x = np.clip((t - t0_s) / max(rise_s, 1e-9), 0.0, 1.0)
    return 0.5 - 0.5 * np.cos(np.pi * x)


def plateau(t: FloatArray, t0_s: float, rise_s: float, hold_s: float, fall_s: float) -> FloatArray:
    """Up over rise_s from t0, held hold_s, down over fall_s (0..1)."""
    return raised_cosine(t, t0_s, rise_s) - raised_cosine(t, t0_s + rise_s + hold_s, fall_s)


def tip_mode(command_deg: FloatArray, fs_hz: float, freq_hz: float, damping: float) -> FloatArray:
    """Tip response x to a command u: x'' = wn^2 (u - x) - 2 zeta wn x' (Tustin at fs_hz), from rest."""
    wn = 2 * math.pi * freq_hz
    b, a = bilinear([wn * wn], [1.0, 2 * damping * wn, wn * wn], fs=fs_hz)
    out: FloatArray = lfilter(b, a, command_deg)
    return out


def jolt(t: FloatArray, t0_s: float, peak_m_s2: float, freq_hz: float, dur_s: float, lever_m: float
         ) -> tuple[FloatArray, FloatArray, FloatArray]:  # fmt: skip
    """A burst of the tip angle, sin^2-windowed sine over `dur_s` from t0 (smooth at both ends), scaled so that its
    tangential acceleration (lever x angular acceleration) peaks at `peak_m_s2`: (rad, rad/s, rad/s^2)."""
    x = np.clip((t - t0_s) / dur_s, 0.0, 1.0)
    angle = np.sin(np.pi * x) ** 2 * np.sin(2 * np.pi * freq_hz * (t - t0_s))
    dt = float(t[1] - t[0])
    rate = np.gradient(angle, dt)
    acc = np.gradient(rate, dt)
    k = peak_m_s2 / (lever_m * max(float(np.abs(acc).max()), 1e-12))
    return k * angle, k * rate, k * acc


class _Builder:
    """Accumulates pull commands (deg, down > 0), direct pitch/yaw/roll offsets (deg) and jolts on a 1 kHz grid."""

    def __init__(self, s: ScenarioSettings, rng: np.random.Generator) -> None:
        self.s, self.rng = s, rng
        self.fs = s.rate_hz * s.substeps
        n = int(round(s.duration_s * self.fs))
        self.t = (np.arange(n) + 1) / self.fs
        self.freq_hz, self.damping = rng.uniform(2.0, 3.0), rng.uniform(0.2, 0.35)
        self.down = np.zeros(n)  # tip-mode output, deg down
        self.direct = np.zeros((n, 3))  # roll, pitch, yaw offsets, deg (kinematic motions)
        self.jolt = np.zeros((3, n, 2))  # (angle, rate, acc) x samples x (pitch, yaw), rad
        self.events: list[ScenarioEvent] = []

    def window(self, t0: float, t1: float) -> slice:
        return slice(max(0, int(t0 * self.fs) - 1), min(self.t.size, int(math.ceil(t1 * self.fs)) + 1))

    def pull(self, t0: float, t1: float, command: FloatArray, max_peak_deg: float | None = None) -> FloatArray:
        """Add a tip-mode response to a command over [t0, t1 + 3 s]; scaled down if it would exceed a peak."""
        sl = self.window(t0, t1 + 3.0)
        resp = tip_mode(command[sl], self.fs, self.freq_hz, self.damping)
        peak = float(np.abs(resp).max())
        if max_peak_deg is not None and peak > max_peak_deg:
            resp *= max_peak_deg / peak
        self.down[sl] += resp
        return resp

    def add_jolt(self, t0: float, peak_g: float, freq_hz: float, dur_s: float) -> None:
        """A jolt split at random between the vertical (pitch) and lateral (yaw) directions."""
        share = self.rng.uniform(0.5, 1.0)
        sl = self.window(t0 - 0.01, t0 + dur_s + 0.01)
        for axis, part in ((0, share), (1, math.sqrt(1 - share * share))):
            sign = self.rng.choice([-1.0, 1.0])
            for i, y in enumerate(jolt(self.t[sl], t0, part * peak_g * G_M_S2, freq_hz, dur_s, self.s.lever_m)):
                self.jolt[i, sl, axis] += sign * y

    # -- families ------------------------------------------------------------------------------------------------

    def bite(self, t0: float) -> float:
        r, t = self.rng, self.t
        depth, rise, hold, fall = r.uniform(12, 24), r.uniform(0.1, 0.6), r.uniform(0.5, 5.0), r.uniform(0.1, 0.5)
        u = depth * plateau(t, t0, rise, hold, fall)
        for _ in range(int(r.integers(0, 4))):
            tug = r.uniform(t0 + rise, t0 + rise + hold)
            u += r.uniform(2, 6) * plateau(t, tug, 0.05, r.uniform(0.0, 0.3), 0.05) * (t < t0 + rise + hold)
        t1 = t0 + rise + hold + fall
        self.pull(t0, t1, u, self.s.max_bite_peak_deg)
        self.events.append(ScenarioEvent("bite", t0, t1, detail=f"hold {depth:.1f} deg, rise {rise:.2f} s"))
        return t1

    def run(self, t0: float) -> float:
        r, t = self.rng, self.t
        depth, rise, hold, fall = r.uniform(15, 28), r.uniform(0.3, 1.5), r.uniform(3, 10), r.uniform(0.3, 1.0)
        wander = 3.0 * np.sin(2 * np.pi * r.uniform(0.1, 0.5) * (t - t0) + r.uniform(0, 2 * np.pi))
        env = plateau(t, t0, rise, hold, fall)
        u = depth * env + wander * env * raised_cosine(t, t0 + rise, 0.5)
        t1 = t0 + rise + hold + fall
        self.pull(t0, t1, u)
        self.events.append(ScenarioEvent("run", t0, t1, detail=f"hold {depth:.1f} deg, rise {rise:.2f} s"))
        return t1

    def nibble(self, t0: float) -> float:
        r, t = self.rng, self.t
        taps, tt = int(r.integers(1, 7)), t0
        u = np.zeros_like(t)
        starts = []
        for _ in range(taps):
            w = r.uniform(0.04, 0.15)
            u += r.uniform(0.5, 1.0) * plateau(t, tt, w / 2, 0.0, w / 2)
            starts.append(tt)
            tt += r.uniform(0.15, 0.6)
        sl = self.window(t0, tt + 3.0)
        resp = tip_mode(u[sl], self.fs, self.freq_hz, self.damping)
        target = r.uniform(1.0, 6.0)
        self.down[sl] += resp * target / max(float(resp.max()), 1e-9)
        for ts in starts:
            self.add_jolt(ts, r.uniform(1.0, 6.0), r.uniform(15, 40), r.uniform(0.01, 0.03))
        self.events.append(ScenarioEvent("nibble", t0, tt, detail=f"{taps} taps, dip {target:.1f} deg"))
        return tt

    def knock(self, t0: float) -> float:
        r, t = self.rng, self.t
        dur = r.uniform(0.01, 0.03)
        self.add_jolt(t0, r.uniform(2.0, 6.0), r.uniform(15, 40), dur)
        ring = r.uniform(0.0, 1.5)
        u = plateau(t, t0, 0.01, 0.0, 0.01)
        sl = self.window(t0, t0 + 3.0)
        resp = tip_mode(u[sl], self.fs, self.freq_hz, self.damping)
        self.down[sl] += resp * ring / max(float(np.abs(resp).max()), 1e-9) * r.choice([-1.0, 1.0])
        self.events.append(ScenarioEvent("knock", t0, t0 + dur, detail=f"ring {ring:.1f} deg"))
        return t0 + dur

    def wind(self, t0: float) -> float:
        r, t = self.rng, self.t
        dur, amp = r.uniform(5, 30), r.uniform(1.0, 5.0)
        sl = self.window(t0, t0 + dur)
        x = t[sl] - t0
        sway = sum(r.uniform(0.3, 1.0) * np.sin(2 * np.pi * r.uniform(0.5, 3.0) * x + r.uniform(0, 2 * np.pi))
                   for _ in range(3))  # fmt: skip
        g0 = r.uniform(0, max(dur - 3, 0.1))
        sway = sway + r.uniform(-1.5, 1.5) * plateau(x, g0, r.uniform(0.3, 1.0), r.uniform(0.5, 2.0), 0.8)
        env = plateau(x, 0.0, 1.0, max(dur - 2.0, 0.0), 1.0)
        pitch = env * sway
        pitch *= amp / max(float(np.abs(pitch).max()), 1e-9)
        yaw = env * sum(np.sin(2 * np.pi * r.uniform(0.5, 3.0) * x + r.uniform(0, 2 * np.pi)) for _ in range(3))
        self.direct[sl, 1] += pitch
        self.direct[sl, 2] += 2.0 * amp * yaw / max(float(np.abs(yaw).max()), 1e-9)
        self.events.append(ScenarioEvent("wind", t0, t0 + dur, detail=f"±{amp:.1f} deg"))
        return t0 + dur

    def handling(self, t0: float) -> float:
        r, t = self.rng, self.t
        dur = r.uniform(1.0, 3.0)
        yaw, roll, pitch = (r.uniform(10, 60) * r.choice([-1, 1]), r.uniform(5, 40) * r.choice([-1, 1]),
                            r.uniform(-2.4, 2.4))  # fmt: skip
        sl = self.window(t0, t0 + dur)
        env = plateau(t[sl], t0, 0.35 * dur, 0.3 * dur, 0.35 * dur)
        self.direct[sl] += env[:, None] * np.array([roll, pitch, yaw])
        self.events.append(ScenarioEvent("handling", t0, t0 + dur, detail=f"yaw {yaw:.0f}, roll {roll:.0f} deg"))
        return t0 + dur

    def drop_back(self, t0: float) -> float:
        r, t = self.rng, self.t
        rise, hold, fall = r.uniform(0.3, 1.5), r.uniform(2, 8), r.uniform(0.5, 2.0)
        up = r.uniform(8, 20)
        u = -up * plateau(t, t0, rise, hold, fall)
        t1 = t0 + rise + hold + fall
        self.pull(t0, t1, u)
        self.events.append(ScenarioEvent("drop_back", t0, t1, detail=f"up {up:.1f} deg, rise {rise:.2f} s"))
        return t1


def make_scenario(seed: int, settings: ScenarioSettings | None = None) -> Scenario:
    """One randomised rod recording (see the module docstring); the same seed gives the same recording."""
    s = settings or ScenarioSettings()
    rng = np.random.default_rng(seed)
    b = _Builder(s, rng)
    t = s.quiet_start_s
    makers = {"bite": b.bite, "run": b.run, "nibble": b.nibble, "knock": b.knock, "wind": b.wind,
              "handling": b.handling, "drop_back": b.drop_back}  # fmt: skip
    while True:
        family = FAMILIES[int(rng.integers(len(FAMILIES)))]
        if t + 45.0 > s.duration_s:  # room for the longest event and its ring-out
            break
        t = makers[family](t) + rng.uniform(*s.gap_s)
    rest_pitch, rest_yaw, rest_roll = rng.uniform(15, 40), rng.uniform(-180, 180), rng.uniform(-3, 3)
    ripple = rng.uniform(0.1, 0.3) * np.sin(2 * np.pi * rng.uniform(0.15, 0.3) * b.t + rng.uniform(0, 2 * np.pi))
    euler = np.radians(np.column_stack([rest_roll + b.direct[:, 0], rest_pitch - b.down + b.direct[:, 1] + ripple,
                                        rest_yaw + b.direct[:, 2]]))  # fmt: skip
    dt = 1.0 / b.fs
    rate = np.gradient(euler, dt, axis=0)
    acc = np.gradient(rate, dt, axis=0)
    for k, axis in ((1, 0), (2, 1)):  # jolts: pitch and yaw, exact derivatives
        euler[:, k] += b.jolt[0, :, axis]
        rate[:, k] += b.jolt[1, :, axis]
        acc[:, k] += b.jolt[2, :, axis]
    q_fast, gyr_fast, acc_fast = tip_kinematics(euler, rate, acc, s.lever_m)
    m = s.substeps
    n = b.t.size // m
    end = np.arange(n) * m + m - 1  # a sample is the state at the end of its 10 ms and the mean over it
    gyr_true = gyr_fast[: n * m].reshape(n, m, 3).mean(axis=1)
    acc_true = acc_fast[: n * m].reshape(n, m, 3).mean(axis=1)
    acc_max_g = np.linalg.norm(acc_fast[: n * m], axis=1).reshape(n, m).max(axis=1) / G_M_S2
    quat = q_fast[end]
    sensor = SensorModel(s.error_model(), 1, np.random.default_rng(seed + 10**6))
    gyr, acc_meas, mag = sensor.measure(gyr_true, acc_true, field_body(quat, EARTH_FIELD_ENU_UT), 1.0 / s.rate_hz)
    assert mag is not None
    t_s = b.t[end]
    dev_deg = np.degrees(euler[end, 1]) - rest_pitch
    events = tuple(_label(e, t_s, dev_deg, s.theta1_deg) for e in b.events)
    return Scenario(seed, t_s, math.radians(rest_pitch), euler[end], quat, gyr, acc_meas, mag, acc_max_g, events)


def _label(e: ScenarioEvent, t_s: FloatArray, dev_deg: FloatArray, theta1_deg: float) -> ScenarioEvent:
    """Fill in the true theta1 crossing (bites, runs) and the peak excursion within the event and 2 s after."""
    win = (t_s >= e.t_start_s) & (t_s <= e.t_end_s + 2.0)
    d = dev_deg[win]
    peak = float(d[np.argmax(np.abs(d))]) if d.size else 0.0
    cross = math.nan
    if e.family in ALARMING:
        hit = np.flatnonzero(win & (dev_deg <= -theta1_deg))
        cross = float(t_s[hit[0]]) if hit.size else math.nan
    return dataclasses.replace(e, cross_s=cross, peak_deg=peak)
