"""Pure physics of a fishing rod in a holder with a motorised reel, a line and (sometimes) a fish. No I/O.

Model (all rods of a bank advance together, vectorised with numpy; time is passed in):

- Tip attitude: pitch = holder pitch - bend, where the bend follows a second-order tip mode
  δ̈ = ωn² (δ* - δ) - 2 ζ ωn δ̇ + wind, δ* = bend_max · tanh(T / tension_ref) (stiff at first, saturating as
  the rod loads up). Sideways, the same mode is driven by the line angle of a fighting fish. Roll and yaw follow
  the angler's hands (handling) through a slower, well-damped second-order response.
- Tension T at the tip = sinker/current baseline + bite pull + fish line tension + waves. A drop-back makes the
  line slack (baseline → 0), so the tip rises by bend(baseline), a few degrees.
- Line and fish: the fish at distance d pulls with F_fish (bursts scaled by stamina); line stretch gives
  T_line = k (d - L) + c ḋ when taut, L = line out. m ḋ̇ = F_fish - T_line - c_w ḋ|ḋ|. Stamina drains with effort.
  T above `breaking_strength_n` breaks the line (fish escapes); L below `land_line_m` lands the fish.
- Reel: motor line-in speed follows the command with first-order lag `motor_tau_s`, limited to
  ±`max_reel_speed_m_s`; when the locked-spool tension would exceed the drag, the spool slips just enough to
  hold T at the drag (an ideal drag).
- The IMU sits at the tip on a lever `tip_lever_m` about the bend point: its specific force includes the tip's
  translational acceleration.

API for closed-loop use without zenoh (e.g. reel-control benches over many seeded fights):

    sim = RodSim(RodSettings(), seed=3)            # one rod; RodBank(settings, n_rods, seed) for many at once
    sim.inject(Fight(t_s=1.0, mass_kg=2.5, stamina=0.8))
    for _ in range(6000):
        state = sim.step(0.01, reel_speed_cmd_m_s=0.5)   # > 0 reels in, < 0 pays out; returns RodState (floats)
        if state.fish_state in ("landed", "escaped"):
            break

`RodBank.step(dt_s, cmd)` advances all rods one step; `RodBank.run_block(n, dt_s, cmd)` advances n steps and
returns per-sample arrays (attitude, true IMU signals, tension) for the simulator. Events: `Bite`, `DropBack`,
`Fight`, `Handling`, `Wind`, `Waves` (times in seconds of simulation time); `parse_script()` builds them from
JSON-like dicts; `RandomEventRates` makes them at random.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import cached_property
from typing import Any

import numpy as np
from numpy.typing import NDArray

from devices import _quat
from devices.common import EARTH_FIELD_ENU_UT, G_M_S2, field_body

FloatArray = NDArray[np.float64]
BoolArray = NDArray[np.bool_]

FISH_STATES: tuple[str, ...] = ("none", "nibbling", "hooked", "fighting", "tired", "landed", "escaped")
_NONE, _NIBBLING, _HOOKED, _FIGHTING, _TIRED, _LANDED, _ESCAPED = range(7)


@dataclass(frozen=True)
class RodSettings:
    """Rod, line, reel and tip-dynamics parameters (defaults: 3 m surf rod, 0.3 mm mono, small DC reel)."""

    holder_pitch_rad: float = math.radians(35.0)
    holder_yaw_rad: float = math.radians(30.0)
    holder_spread_rad: float = math.radians(5.0)  # per-rod random spread of holder pitch/yaw in a bank
    tip_lever_m: float = 0.8
    bend_max_rad: float = math.radians(60.0)
    tension_ref_n: float = 15.0
    tip_freq_hz: float = 2.5
    tip_damping: float = 0.35
    hand_freq_hz: float = 1.2
    hand_damping: float = 0.9
    baseline_tension_n: float = 1.0  # sinker + current: the resting bend
    line_stiffness_n_m: float = 300.0
    line_damping_n_s_m: float = 20.0
    breaking_strength_n: float = 40.0
    initial_line_out_m: float = 30.0
    spool_capacity_m: float = 150.0
    land_line_m: float = 2.0
    max_reel_speed_m_s: float = 1.5
    default_reel_speed_m_s: float = 0.6
    motor_tau_s: float = 0.15
    drag_n: float = 25.0
    water_drag_n_s2_m2: float = 8.0
    wind_bend_rad: float = math.radians(1.5)  # rms tip bend at wind strength 1
    max_substep_s: float = 0.005

    def bend_rad(self, tension_n: FloatArray | float) -> FloatArray:
        """Static tip bend for a line tension (rad): bend_max · tanh(T / tension_ref)."""
        return np.asarray(self.bend_max_rad * np.tanh(np.asarray(tension_n) / self.tension_ref_n))

    def tension_for_bend_n(self, bend_rad: float) -> float:
        """Inverse of `bend_rad` (N); bends at or above bend_max are clipped just below it."""
        x = min(bend_rad / self.bend_max_rad, 0.999)
        return float(self.tension_ref_n * math.atanh(x))

    @property
    def rest_pitch_rad(self) -> float:
        """Tip pitch at rest with the baseline tension, for the default holder pitch."""
        return float(self.holder_pitch_rad - self.bend_rad(self.baseline_tension_n))


# ---------------------------------------------------------------------------------------------------------------
# Events
# ---------------------------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class Bite:
    """A fish takes the bait without being hooked: the tip drops by `depth_rad` (static) for `duration_s`."""

    t_s: float
    duration_s: float = 1.5
    depth_rad: float = math.radians(20.0)
    tremble: float = 0.1  # relative tension flicker while biting


@dataclass(frozen=True)
class DropBack:
    """The fish swims towards the rod: the line goes slack and the tip rises by bend(baseline)."""

    t_s: float
    duration_s: float = 2.0


@dataclass(frozen=True)
class Fight:
    """A fish is hooked at `t_s` and fights: `pull_n` is its top pull (default 9 N/kg · mass); stamina 0..1."""

    t_s: float
    mass_kg: float = 2.0
    stamina: float = 1.0
    pull_n: float | None = None
    endurance_s: float = 90.0  # seconds of full-strength pulling that exhaust a stamina-1 fish


@dataclass(frozen=True)
class Handling:
    """The angler picks the rod up and turns it: roll and yaw change, pitch barely (≤ `pitch_rad`)."""

    t_s: float
    duration_s: float = 3.0
    roll_rad: float = math.radians(25.0)
    yaw_rad: float = math.radians(15.0)
    pitch_rad: float = math.radians(0.5)


@dataclass(frozen=True)
class Wind:
    """Gusty wind shakes the tip (band-limited noise through the tip mode), strength 0..3."""

    t_s: float
    duration_s: float = 10.0
    strength: float = 1.0


@dataclass(frozen=True)
class Waves:
    """Waves modulate the line tension sinusoidally."""

    t_s: float
    duration_s: float = 20.0
    amplitude_n: float = 0.4
    period_s: float = 4.0


Event = Bite | DropBack | Fight | Handling | Wind | Waves
EVENT_TYPES: dict[str, type[Any]] = {
    "bite": Bite, "drop_back": DropBack, "fight": Fight, "handling": Handling, "wind": Wind, "waves": Waves,
}


def parse_script(items: list[dict[str, Any]]) -> list[Event]:
    """Events from dicts like `{"type": "bite", "t_s": 5, "duration_s": 1.5, "depth_deg": 20}`.

    Angles may be given in degrees with a `_deg` suffix instead of `_rad`. Raises ValueError on unknown types or
    fields.
    """
    events: list[Event] = []
    for item in items:
        kw = dict(item)
        kind = kw.pop("type", None)
        cls = EVENT_TYPES.get(str(kind))
        if cls is None:
            raise ValueError(f"unknown event type {kind!r}; known: {', '.join(EVENT_TYPES)}")
        for key in [k for k in kw if k.endswith("_deg")]:
            kw[key[:-4] + "_rad"] = math.radians(float(kw.pop(key)))
        try:
            events.append(cls(**kw))
        except TypeError as exc:
            raise ValueError(f"bad {kind} event {item}: {exc}") from exc
    return sorted(events, key=lambda e: e.t_s)


@dataclass(frozen=True)
class RandomEventRates:
    """Poisson rates of random events per rod, per hour of simulated time; `hook_prob`: a bite becomes a fight."""

    bite_per_h: float = 0.0
    drop_back_per_h: float = 0.0
    handling_per_h: float = 0.0
    wind_per_h: float = 0.0
    waves_per_h: float = 0.0
    hook_prob: float = 0.3

    @staticmethod
    def lively() -> RandomEventRates:
        """Something happens every minute or so: good for demos."""
        return RandomEventRates(60.0, 20.0, 20.0, 20.0, 10.0, 0.3)


@dataclass(frozen=True)
class TruthLabel:
    """An event label in simulation time."""

    rod: int
    label: str
    phase: str  # start | end | instant
    t_s: float
    value: float | None = None


# ---------------------------------------------------------------------------------------------------------------
# Outputs
# ---------------------------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class RodState:
    """One rod after a step (floats); angles in rad, ENU, quaternion wxyz body -> earth.

    `quat_wxyz`, `gyr_rad_s` (true body rate) and `acc_m_s2` (true specific force) are computed on first access,
    so a controller reading only pitch, tension and line pays nothing for them.
    """

    t_s: float
    roll_rad: float
    pitch_rad: float
    yaw_rad: float
    tension_n: float
    line_out_m: float
    line_in_speed_m_s: float
    motor_speed_m_s: float
    drag_n: float
    fish_state: str
    fish_stamina: float
    fish_distance_m: float
    breaking_strength_n: float
    line_broken: bool
    euler_rate_rad_s: FloatArray
    euler_acc_rad_s2: FloatArray
    tip_lever_m: float

    @cached_property
    def _kinematics(self) -> tuple[FloatArray, FloatArray, FloatArray]:
        e = np.array([self.roll_rad, self.pitch_rad, self.yaw_rad])
        return tip_kinematics(e, self.euler_rate_rad_s, self.euler_acc_rad_s2, self.tip_lever_m)

    @property
    def quat_wxyz(self) -> FloatArray:
        """True tip attitude, shape (4,)."""
        return self._kinematics[0]

    @property
    def gyr_rad_s(self) -> FloatArray:
        """True body angular rate, rad/s, shape (3,)."""
        return self._kinematics[1]

    @property
    def acc_m_s2(self) -> FloatArray:
        """True specific force in the body frame, m/s², shape (3,)."""
        return self._kinematics[2]


@dataclass(frozen=True)
class RodBlock:
    """n consecutive samples of D rods: arrays shaped (D, n, ...); sample j is the state after step j."""

    t_s: FloatArray  # (n,)
    quat_wxyz: FloatArray  # (D, n, 4)
    euler_rad: FloatArray  # (D, n, 3) roll, pitch, yaw
    gyr_rad_s: FloatArray  # (D, n, 3) true body rate
    acc_m_s2: FloatArray  # (D, n, 3) true specific force, body
    mag_uT: FloatArray  # (D, n, 3) true field, body
    tension_n: FloatArray  # (D, n)


# ---------------------------------------------------------------------------------------------------------------
# The bank
# ---------------------------------------------------------------------------------------------------------------


def _second_order(x: FloatArray, v: FloatArray, target: FloatArray, wn: float, zeta: float, force: FloatArray | float,
                  dt: float) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Semi-implicit Euler step of ẍ = ωn²(x* - x) - 2ζωn ẋ + f; returns (x, ẋ, ẍ)."""
    a = wn * wn * (target - x) - 2.0 * zeta * wn * v + force
    v = v + a * dt
    return x + v * dt, v, a


class RodBank:
    """D rods simulated together (vectorised). See the module docstring for the model and API.

    Stable state for controllers and benches, arrays of shape (D,) after each `step`: `t_s` (float), `tension`
    (N at the tip), `line_tension` (N, fish line only), `line_out` (m), `line_rate` (m/s, d line_out / dt),
    `motor` (line-in speed m/s), `drag` (N), `breaking` (N), `broken` (bool), `fish` (index into
    FISH_STATES), `fish_stamina` (0..1), `fish_d` (fish distance, m); `euler()` gives the tip angles.
    """

    def __init__(self, settings: RodSettings, n_rods: int = 1, seed: int | None = None,
                 rates: RandomEventRates | None = None):
        self.s, self.n = settings, n_rods
        self.rng = np.random.default_rng(seed)
        self.rates = rates or RandomEventRates()
        s, d, r = settings, n_rods, self.rng
        spread = s.holder_spread_rad if n_rods > 1 else 0.0
        self.holder_pitch = s.holder_pitch_rad + r.uniform(-spread, spread, d)
        self.holder_yaw = s.holder_yaw_rad + r.uniform(-spread, spread, d)
        self.t_s = 0.0
        z = np.zeros(d)
        self.bend, self.bend_v, self.bend_a = z.copy(), z.copy(), z.copy()
        self.side, self.side_v, self.side_a = z.copy(), z.copy(), z.copy()
        self.roll, self.roll_v, self.roll_a = z.copy(), z.copy(), z.copy()
        self.yaw, self.yaw_v, self.yaw_a = z.copy(), z.copy(), z.copy()
        self.pitch_h, self.pitch_h_v, self.pitch_h_a = z.copy(), z.copy(), z.copy()
        self.hand_target = np.zeros((d, 3))  # roll, yaw, pitch offsets while handled
        self.hand_until = np.full(d, -np.inf)
        self.bite_tension = z.copy()
        self.bite_tremble = z.copy()
        self.bite_from, self.bite_until = np.full(d, np.inf), np.full(d, -np.inf)
        self.slack_until = np.full(d, -np.inf)
        self.wind_strength, self.wind_until = z.copy(), np.full(d, -np.inf)
        self.wind_f = np.zeros((d, 2))
        self.wave_amp, self.wave_period, self.wave_until = z.copy(), np.ones(d), np.full(d, -np.inf)
        self.line_out = np.full(d, s.initial_line_out_m)
        self.line_rate = z.copy()  # d(line_out)/dt
        self.motor = z.copy()  # line-in speed of the motor, m/s
        self.drag = np.full(d, s.drag_n)
        self.breaking = np.full(d, s.breaking_strength_n)
        self.broken = np.zeros(d, dtype=bool)
        self.fish = np.zeros(d, dtype=np.int64)  # index into FISH_STATES
        self.fish_d, self.fish_v = z.copy(), z.copy()
        self.fish_mass, self.fish_pull, self.fish_stamina = z.copy(), z.copy(), z.copy()
        self.fish_endurance = np.ones(d)
        self.fish_stamina0 = z.copy()
        self.fish_burst = np.zeros(d, dtype=bool)
        self.fish_burst_until = z.copy()
        self.fish_bearing = z.copy()
        self.fish_since = z.copy()
        self.line_tension = z.copy()
        self.tension = np.full(d, s.baseline_tension_n)
        self.pending: list[list[Event]] = [[] for _ in range(d)]
        self.labels: list[TruthLabel] = []
        self._open: list[tuple[int, str, float]] = []  # (rod, label, end time) for labels with an end
        # start at rest: bend already at the baseline
        self.bend[:] = s.bend_rad(s.baseline_tension_n)

    # ---- events ------------------------------------------------------------------------------------------------

    def inject(self, event: Event, rods: int | list[int] | None = None) -> None:
        """Schedule an event (at `event.t_s`, or now if that is past) on one rod, a list, or all (None)."""
        targets = range(self.n) if rods is None else [rods] if isinstance(rods, int) else rods
        for i in targets:
            self.pending[i].append(event)
            self.pending[i].sort(key=lambda e: e.t_s)

    def set_drag(self, drag_n: float | FloatArray, rods: int | list[int] | None = None) -> None:
        """Set the reel's drag (N) on some rods."""
        idx = slice(None) if rods is None else rods
        self.drag[idx] = drag_n

    def drain_labels(self) -> list[TruthLabel]:
        """Labels produced since the last call (events with device times, for truth packets)."""
        out, self.labels = self.labels, []
        return out

    def _label(self, rod: int, label: str, phase: str, value: float | None = None, end_s: float | None = None) -> None:
        self.labels.append(TruthLabel(rod, label, phase, self.t_s, value))
        if end_s is not None:
            self._open.append((rod, label, end_s))

    def _start(self, i: int, e: Event) -> None:
        s, t = self.s, self.t_s
        if isinstance(e, Bite):
            self.bite_tension[i] = s.tension_for_bend_n(s.bend_rad(s.baseline_tension_n).item() + e.depth_rad) - (
                s.baseline_tension_n)
            self.bite_tremble[i] = e.tremble
            self.bite_from[i], self.bite_until[i] = t, t + e.duration_s
            if self.fish[i] in (_NONE, _LANDED, _ESCAPED):
                self.fish[i] = _NIBBLING
            self._label(i, "bite", "start", e.depth_rad, t + e.duration_s)
        elif isinstance(e, DropBack):
            self.slack_until[i] = t + e.duration_s
            self._label(i, "drop_back", "start", None, t + e.duration_s)
        elif isinstance(e, Fight):
            self.fish[i] = _HOOKED
            self.fish_since[i] = t
            self.fish_mass[i] = e.mass_kg
            self.fish_pull[i] = e.pull_n if e.pull_n is not None else 9.0 * e.mass_kg
            self.fish_stamina[i] = self.fish_stamina0[i] = e.stamina
            self.fish_endurance[i] = e.endurance_s
            self.fish_d[i], self.fish_v[i] = self.line_out[i], 0.0
            self.fish_burst[i], self.fish_burst_until[i] = True, t + self.rng.uniform(1.0, 4.0)
            self.fish_bearing[i] = self.rng.uniform(-0.3, 0.3)
            self.broken[i] = False
            self._label(i, "fight", "start", e.mass_kg)
        elif isinstance(e, Handling):
            self.hand_target[i] = (e.roll_rad, e.yaw_rad, e.pitch_rad)
            self.hand_until[i] = t + e.duration_s
            self._label(i, "handling", "start", None, t + e.duration_s)
        elif isinstance(e, Wind):
            self.wind_strength[i], self.wind_until[i] = e.strength, t + e.duration_s
            self._label(i, "wind", "start", e.strength, t + e.duration_s)
        elif isinstance(e, Waves):
            self.wave_amp[i], self.wave_period[i], self.wave_until[i] = e.amplitude_n, e.period_s, t + e.duration_s
            self._label(i, "waves", "start", e.amplitude_n, t + e.duration_s)

    def _due_events(self) -> None:
        for i, queue in enumerate(self.pending):
            while queue and queue[0].t_s <= self.t_s + 1e-12:
                self._start(i, queue.pop(0))
        if self._open:
            still = []
            for rod, label, end in self._open:
                if end <= self.t_s + 1e-12:
                    self.labels.append(TruthLabel(rod, label, "end", self.t_s))
                else:
                    still.append((rod, label, end))
            self._open = still

    def _random_events(self, dt: float) -> None:
        r = self.rates
        for rate, make in (
            (r.bite_per_h, lambda: Bite(self.t_s, self.rng.uniform(0.5, 3.0), math.radians(self.rng.uniform(10, 30)))),
            (r.drop_back_per_h, lambda: DropBack(self.t_s, self.rng.uniform(1.0, 4.0))),
            (r.handling_per_h, lambda: Handling(self.t_s, self.rng.uniform(2.0, 6.0),
                                                math.radians(self.rng.uniform(-40, 40)),
                                                math.radians(self.rng.uniform(-25, 25)))),
            (r.wind_per_h, lambda: Wind(self.t_s, self.rng.uniform(5.0, 30.0), self.rng.uniform(0.5, 2.0))),
            (r.waves_per_h, lambda: Waves(self.t_s, self.rng.uniform(10.0, 60.0), self.rng.uniform(0.2, 0.6),
                                          self.rng.uniform(3.0, 8.0))),
        ):
            if rate <= 0:
                continue
            hits = np.flatnonzero(self.rng.random(self.n) < rate / 3600.0 * dt)
            for i in hits:
                if self.fish[i] in (_HOOKED, _FIGHTING, _TIRED):
                    continue
                e = make()
                self._start(int(i), e)
                if isinstance(e, Bite) and self.rng.random() < r.hook_prob:
                    self.inject(Fight(self.t_s + e.duration_s, float(self.rng.uniform(0.5, 6.0)),
                                      float(self.rng.uniform(0.3, 1.0))), int(i))

    # ---- dynamics ----------------------------------------------------------------------------------------------

    def step(self, dt_s: float, reel_speed_cmd_m_s: float | FloatArray = 0.0) -> None:
        """Advance every rod by `dt_s` with the reel motor commanded to `reel_speed_cmd_m_s` (> 0 reels in)."""
        n_sub = max(1, math.ceil(dt_s / self.s.max_substep_s - 1e-9))
        h = dt_s / n_sub
        cmd = np.clip(np.broadcast_to(np.asarray(reel_speed_cmd_m_s, dtype=np.float64), (self.n,)),
                      -self.s.max_reel_speed_m_s, self.s.max_reel_speed_m_s)
        for _ in range(n_sub):
            self._due_events()
            self._random_events(h)
            self._substep(h, cmd)

    def _substep(self, h: float, cmd: FloatArray) -> None:
        s, t = self.s, self.t_s + h
        # reel motor with lag
        self.motor += (cmd - self.motor) * min(1.0, h / s.motor_tau_s)
        # fish and line; the spool pays out at the motor's rate unless the drag slips
        hooked = (self.fish == _HOOKED) | (self.fish == _FIGHTING) | (self.fish == _TIRED)
        rate = -self.motor
        line_tension = np.zeros(self.n)
        if hooked.any():
            line_tension, rate = self._fish_step(h, t, hooked, rate)
        new_out = np.clip(self.line_out + rate * h, 0.0, s.spool_capacity_m)
        self.line_rate = (new_out - self.line_out) / h
        self.line_out = new_out
        # tension at the tip
        slack = t < self.slack_until
        base = np.where(slack | hooked, 0.0, s.baseline_tension_n)
        biting = (t >= self.bite_from) & (t < self.bite_until)
        bite = np.zeros(self.n)
        if biting.any():
            # smooth 0.3 s cosine ramps at both ends, flicker on top
            up = np.clip((t - self.bite_from) / 0.3, 0.0, 1.0)
            down = np.clip((self.bite_until - t) / 0.3, 0.0, 1.0)
            env = 0.5 - 0.5 * np.cos(np.pi * np.minimum(up, down))
            flick = 1.0 + self.bite_tremble * np.sin(2 * np.pi * 3.0 * np.where(biting, t - self.bite_from, 0.0))
            bite = np.where(biting, self.bite_tension * env * flick, 0.0)
        ended = (~biting) & (self.fish == _NIBBLING) & (t >= self.bite_until)
        self.fish[ended] = _NONE
        waves = np.where(t < self.wave_until, self.wave_amp * np.sin(2 * np.pi * t / self.wave_period), 0.0)
        self.line_tension = line_tension
        self.tension = np.maximum(0.0, base + bite + line_tension + waves)
        # wind: Ornstein-Uhlenbeck force (1 s correlation) on both tip modes
        windy = t < self.wind_until
        wn = 2 * np.pi * s.tip_freq_hz
        if windy.any() or self.wind_f.any():
            sigma = np.where(windy, self.wind_strength, 0.0) * s.wind_bend_rad * wn * wn
            theta = 1.0
            noise = self.rng.normal(size=(self.n, 2))
            self.wind_f += -theta * self.wind_f * h + (sigma * math.sqrt(2 * theta * h))[:, None] * noise
        # tip modes
        target = s.bend_rad(self.tension)
        self.bend, self.bend_v, self.bend_a = _second_order(
            self.bend, self.bend_v, target, wn, s.tip_damping, self.wind_f[:, 0], h)
        side_target = s.bend_rad(line_tension) * np.sin(self.fish_bearing)
        self.side, self.side_v, self.side_a = _second_order(
            self.side, self.side_v, side_target, wn, s.tip_damping, self.wind_f[:, 1], h)
        # hands
        handled = t < self.hand_until
        hand = np.where(handled[:, None], self.hand_target, 0.0)
        hw = 2 * np.pi * s.hand_freq_hz
        hz = s.hand_damping
        self.roll, self.roll_v, self.roll_a = _second_order(self.roll, self.roll_v, hand[:, 0], hw, hz, 0, h)
        self.yaw, self.yaw_v, self.yaw_a = _second_order(self.yaw, self.yaw_v, hand[:, 1], hw, hz, 0, h)
        self.pitch_h, self.pitch_h_v, self.pitch_h_a = _second_order(
            self.pitch_h, self.pitch_h_v, hand[:, 2], hw, s.hand_damping, 0, h)
        self.t_s = t

    def _fish_step(self, h: float, t: float, hooked: BoolArray, motor_rate: FloatArray,
                   ) -> tuple[FloatArray, FloatArray]:
        """Advance hooked fish; returns (line tension N, line-out rate m/s) with the drag as a tension cap."""
        s, r = self.s, self.rng
        # bursts: runs of 1-5 s alternate with rests of 1-3 s
        switch = hooked & (t >= self.fish_burst_until)
        if switch.any():
            idx = np.flatnonzero(switch)
            self.fish_burst[idx] = ~self.fish_burst[idx]
            self.fish_burst_until[idx] = t + np.where(self.fish_burst[idx], r.uniform(1.0, 5.0, idx.size),
                                                      r.uniform(1.0, 3.0, idx.size))
            self.fish_bearing[idx] = np.clip(self.fish_bearing[idx] + r.normal(0.0, 0.2, idx.size), -0.8, 0.8)
        tired = self.fish_stamina < 0.1
        effort = np.where(self.fish_burst & ~tired, 1.0, 0.15) * np.where(hooked, 1.0, 0.0)
        pull = self.fish_pull * np.maximum(self.fish_stamina, 0.05) * effort
        stretch = self.fish_d - self.line_out
        k, c = s.line_stiffness_n_m, s.line_damping_n_s_m
        locked = np.where(hooked & (stretch > 0), np.maximum(0.0, k * stretch + c * (self.fish_v - motor_rate)), 0.0)
        # drag: the spool slips just enough to hold the tension at the drag setting
        slipping = locked > self.drag
        rate = np.where(slipping, np.maximum(motor_rate, self.fish_v - (self.drag - k * stretch) / c), motor_rate)
        line_t = np.where(slipping, self.drag, locked)
        m = np.maximum(self.fish_mass, 0.1) * 1.5  # added mass of water
        acc = (pull - line_t - s.water_drag_n_s2_m2 * self.fish_v * np.abs(self.fish_v)) / m
        self.fish_v = np.where(hooked, self.fish_v + acc * h, 0.0)
        self.fish_d = np.where(hooked, np.maximum(0.0, self.fish_d + self.fish_v * h), self.fish_d)
        drain = (effort * (1.0 + line_t / np.maximum(self.fish_pull, 1e-6))) / np.maximum(self.fish_endurance, 1e-6)
        self.fish_stamina = np.where(hooked, np.maximum(0.0, self.fish_stamina - drain * h), self.fish_stamina)
        self.fish = np.where(hooked & (self.fish == _HOOKED) & (t - self.fish_since > 1.0), _FIGHTING, self.fish)
        newly_tired = hooked & tired & (self.fish == _FIGHTING)
        self.fish = np.where(newly_tired, _TIRED, self.fish)
        for i in np.flatnonzero(newly_tired):
            self.labels.append(TruthLabel(int(i), "fish_tired", "instant", t))
        broke = hooked & (line_t > self.breaking)
        landed = hooked & ~broke & (self.line_out <= s.land_line_m) & (self.fish_d <= self.line_out + 0.5)
        for i in np.flatnonzero(broke):
            self.labels.append(TruthLabel(int(i), "line_break", "instant", t, float(line_t[i])))
            self.labels.append(TruthLabel(int(i), "fight", "end", t))
        for i in np.flatnonzero(landed):
            self.labels.append(TruthLabel(int(i), "landed", "instant", t))
            self.labels.append(TruthLabel(int(i), "fight", "end", t))
        self.broken |= broke
        self.fish = np.where(broke, _ESCAPED, np.where(landed, _LANDED, self.fish))
        line_t = np.where(broke | landed, 0.0, line_t)
        return np.asarray(line_t, dtype=np.float64), np.asarray(rate, dtype=np.float64)

    # ---- kinematics --------------------------------------------------------------------------------------------

    def euler(self) -> tuple[FloatArray, FloatArray, FloatArray]:
        """Current (roll, pitch, yaw), their rates and accelerations, each (D, 3)."""
        e = np.stack([self.roll, self.holder_pitch - self.bend + self.pitch_h, self.holder_yaw + self.yaw + self.side],
                     axis=-1)
        de = np.stack([self.roll_v, -self.bend_v + self.pitch_h_v, self.yaw_v + self.side_v], axis=-1)
        dde = np.stack([self.roll_a, -self.bend_a + self.pitch_h_a, self.yaw_a + self.side_a], axis=-1)
        return e, de, dde

    def run_block(self, n: int, dt_s: float, reel_speed_cmd_m_s: float | FloatArray = 0.0) -> RodBlock:
        """Advance n steps; return per-sample attitude and true IMU signals (sample j = state after step j)."""
        e = np.empty((n, self.n, 3))
        de, dde, ten, ts = np.empty_like(e), np.empty_like(e), np.empty((n, self.n)), np.empty(n)
        for j in range(n):
            self.step(dt_s, reel_speed_cmd_m_s)
            e[j], de[j], dde[j] = self.euler()
            ten[j], ts[j] = self.tension, self.t_s
        e, de, dde = (np.swapaxes(a, 0, 1) for a in (e, de, dde))
        q, gyr, acc = tip_kinematics(e, de, dde, self.s.tip_lever_m)
        return RodBlock(ts, q, e, gyr, acc, field_body(q, EARTH_FIELD_ENU_UT), ten.T.copy())


def tip_kinematics(euler_rad: FloatArray, euler_rate: FloatArray, euler_acc: FloatArray, lever_m: float,
                   ) -> tuple[FloatArray, FloatArray, FloatArray]:
    """Quaternion, body rate (rad/s) and specific force (m/s², body) of an IMU on a lever swinging in pitch/yaw.

    Tip position p = lever · u(pitch, yaw), u = (cos p cos y, cos p sin y, sin p); its acceleration
    follows from the chain rule with the pitch/yaw rates and accelerations; specific force = Rᵀ(p̈ + g ẑ).
    """
    q = _quat.from_euler(euler_rad[..., 0], euler_rad[..., 1], euler_rad[..., 2])
    gyr = _quat.body_rates_from_euler(euler_rad, euler_rate)
    p, y = euler_rad[..., 1], euler_rad[..., 2]
    dp, dy, ddp, ddy = euler_rate[..., 1], euler_rate[..., 2], euler_acc[..., 1], euler_acc[..., 2]
    sp, cp, sy, cy = np.sin(p), np.cos(p), np.sin(y), np.cos(y)
    zero = np.zeros_like(p)
    u_p = np.stack([-sp * cy, -sp * sy, cp], axis=-1)
    u_y = np.stack([-cp * sy, cp * cy, zero], axis=-1)
    u_pp = np.stack([-cp * cy, -cp * sy, -sp], axis=-1)
    u_py = np.stack([sp * sy, -sp * cy, zero], axis=-1)
    u_yy = np.stack([-cp * cy, -cp * sy, zero], axis=-1)
    acc = lever_m * (u_p * ddp[..., None] + u_y * ddy[..., None] + u_pp * (dp * dp)[..., None]
                     + 2 * u_py * (dp * dy)[..., None] + u_yy * (dy * dy)[..., None])
    acc[..., 2] += G_M_S2
    return q, gyr, _quat.rotate_inverse(q, acc)


class RodSim:
    """One rod with a float-valued API for closed-loop control: `step(dt_s, reel_speed_cmd_m_s) -> RodState`."""

    def __init__(self, settings: RodSettings | None = None, seed: int | None = None,
                 rates: RandomEventRates | None = None):
        self.bank = RodBank(settings or RodSettings(), 1, seed, rates)

    @property
    def settings(self) -> RodSettings:
        """The rod's settings."""
        return self.bank.s

    def inject(self, event: Event) -> None:
        """Schedule an event (simulation time `event.t_s`)."""
        self.bank.inject(event)

    def set_drag(self, drag_n: float) -> None:
        """Set the reel drag, N."""
        self.bank.set_drag(drag_n)

    def step(self, dt_s: float, reel_speed_cmd_m_s: float = 0.0) -> RodState:
        """Advance `dt_s`; the motor is commanded to `reel_speed_cmd_m_s` line-in speed (> 0 in, < 0 out)."""
        b = self.bank
        b.step(dt_s, reel_speed_cmd_m_s)
        e, de, dde = b.euler()
        return RodState(
            t_s=b.t_s, roll_rad=float(e[0, 0]), pitch_rad=float(e[0, 1]), yaw_rad=float(e[0, 2]),
            tension_n=float(b.tension[0]), line_out_m=float(b.line_out[0]),
            line_in_speed_m_s=float(-b.line_rate[0]), motor_speed_m_s=float(b.motor[0]), drag_n=float(b.drag[0]),
            fish_state=FISH_STATES[int(b.fish[0])], fish_stamina=float(b.fish_stamina[0]),
            fish_distance_m=float(b.fish_d[0]), breaking_strength_n=float(b.breaking[0]),
            line_broken=bool(b.broken[0]), euler_rate_rad_s=de[0], euler_acc_rad_s2=dde[0],
            tip_lever_m=b.s.tip_lever_m,
        )


def reel_speed_for(action: str, speed_m_s: float | None, settings: RodSettings) -> float:
    """Motor line-in speed (m/s, > 0 in) for a ReelCommand action: in/out use |speed| or the default, stop = 0,
    speed = signed value; clipped to the reel's limit."""
    mag = abs(speed_m_s) if speed_m_s else settings.default_reel_speed_m_s
    v = {"in": mag, "out": -mag, "stop": 0.0, "speed": float(speed_m_s or 0.0)}[action]
    return float(np.clip(v, -settings.max_reel_speed_m_s, settings.max_reel_speed_m_s))

