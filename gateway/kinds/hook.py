"""The crane hook: swing angle Θ, displacement bearing and torsion φ (`gateway.fusion.hook`), the hook rules, and
`Swing` messages at packet ends (decimated to `swing_interval_s`); the crane's feed of its boom tip's motion
(`schemas.CraneMotion`), which the hook filter takes as a known input (`gateway.fusion.crane_feed`).

Θ and φ of every hook in a batch are computed in one call each over the concatenated blocks (φ against each
hook's own rest heading, repeated over its rows); rules and messages are per hook.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, ClassVar

import numpy as np

from gateway import schemas
from gateway.alarm.engine import Condition
from gateway.alarm.hook import HookAlarms, hook_rules
from gateway.config import HookThresholds
from gateway.fusion import hook as hook_geo
from gateway.fusion.crane_feed import MAX_HOLD_S, CraneFeed
from gateway.fusion.gaps import gap_tol_s
from gateway.kinds.base import (
    TWO_PI,
    Fused,
    FusedDevice,
    KindBase,
    KindBatch,
    KindContext,
    Output,
    Timed,
    headers_valid,
    timed,
)

if TYPE_CHECKING:
    from pydantic import BaseModel

    from gateway.pipeline import PipelineSettings


_SWING_SET = frozenset(schemas.Swing.model_fields) - {"v"}  # the fields `HookKind.post` sets
# A hook with no configured rest heading takes its torsion reference from its heading at the first fused sample, when
# the heading is least known (an uncalibrated compass's hard iron is learnt in the first twists). After this many
# seconds of samples without a gap, the reference is read again: the heading then, carried back to the first sample by
# the gyroscope's twist with the bias and scale the filter has learnt by then (fresh cranes 3072-3083 through the
# pipeline, MPU-6050-class board: torsion RMSE from 1 s 0.86 -> 0.68°; crane 2863 1.73 -> 0.71°).
REFERENCE_SETTLE_S = 10.0


def _swings_valid(picks: list[tuple[int, int, int, int]], kb: KindBatch, angle: np.ndarray, bearing: list[float],
                  phi: list[float], twist: np.ndarray) -> bool:  # fmt: skip
    """Whether the batch's Swing floats and ints (all but each hook's heading and rope) pass the model's checks."""
    angles = np.concatenate((angle, np.asarray(bearing, dtype=np.float64), np.asarray(phi, dtype=np.float64)))
    if not ((np.abs(angles) <= TWO_PI).all() and np.isfinite(twist).all()):
        return False
    devs = [kb.items[i].dev for i, _, _, _ in picks]
    return (headers_valid(devs, [s for _, _, s, _ in picks], [t for _, _, _, t in picks])
            and all(type(d.device_id) is str and schemas.valid_device_id(d.device_id)
                    for d in {id(d): d for d in devs}.values()))


@dataclass
class HookState:
    """A hook's rules, torsion reference and last Swing."""

    rules: HookAlarms
    rest_heading_rad: float | None = None  # heading at the first fused sample (torsion reference)
    rest_heading_redone: bool = False  # the reference retaken from the filter's redone start (`start_redone_q0`)
    rest_heading_set_rad: float | None = None  # configured rest heading (HookThresholds), wins when set
    settle_from_s: float | None = None  # device time of the first fused sample while the reference settles, else None
    settle_last_s: float = math.nan  # device time of the last sample integrated
    settle_rate_sum_rad: float = 0.0  # Σ ω_z·dt of the samples since the first (raw z gyro)
    settle_time_s: float = 0.0  # Σ dt of the same samples
    last_swing_t_s: float = -math.inf  # device time of the last Swing published
    swing: schemas.Swing | None = None


class HookKind(KindBase):
    """Hook handler."""

    name: ClassVar[str] = "hook"
    fused: ClassVar[bool] = True
    bridge_lost_samples: ClassVar[bool] = True  # the pendulum's phase must cross a gap (Θ 0.58° -> 0.22° at 2 % loss)
    packet_types: ClassVar[tuple[type[Any], ...]] = (schemas.CraneMotion,)

    def __init__(self) -> None:
        self.feeds: dict[str, CraneFeed] = {}  # device id -> its crane's feed (kept across filter restarts)

    def on_packet(self, ctx: KindContext, packet: Any, now_s: float) -> None:
        if isinstance(packet, schemas.CraneMotion):
            feed = self.feeds.get(packet.device_id)
            if feed is None:
                feed = self.feeds[packet.device_id] = CraneFeed()
            feed.add(packet.wall_t0_us * 1e-6, packet.rate_hz, np.asarray(packet.tip_acc_m_s2, dtype=np.float64))

    def feed_view(self, device_id: str, now_wall_s: float) -> dict[str, Any] | None:
        """REST's view of the hook's crane feed: packets taken, the newest sample's age by the gateway's clock (s),
        and whether the filter is taking it now (`in_use`: the newest within `MAX_HOLD_S`); None when its crane has
        sent none."""
        feed = self.feeds.get(device_id)
        if feed is None or not feed.t_s.size:
            return None
        age_s = now_wall_s - float(feed.t_s[-1])
        return {"packets": feed.packets, "newest_age_s": age_s, "in_use": age_s <= MAX_HOLD_S}

    def filter_inputs(self, device_id: str, wall_end_s: float, n: int, dt_s: float) -> dict[str, Any]:
        feed = self.feeds.get(device_id)
        tip = None if feed is None else feed.at(wall_end_s, n, dt_s)
        return {} if tip is None else {"tip_enu": tip}

    def thresholds_model(self) -> type[BaseModel]:
        return HookThresholds

    def default_filter(self, settings: PipelineSettings) -> str:
        return settings.hook_filter  # the rope-aware EKF unless configured otherwise

    def filter_options(self, th: Any) -> dict[str, Any]:
        if not isinstance(th, HookThresholds):
            return {}
        return {"rope_length_m": th.rope_length_m, "imu_offset_m": th.imu_offset_m, "imu_tilt_deg": th.imu_tilt_deg,
                "acc_bias_xy_m_s2": th.acc_bias_xy_m_s2}

    def new_state(self, ctx: KindContext, dev: FusedDevice, th: Any) -> HookState:
        st = HookState(HookAlarms(dev.device_id, th if isinstance(th, HookThresholds) else None))
        if isinstance(th, HookThresholds) and th.rest_heading_deg is not None:
            st.rest_heading_set_rad = math.radians(th.rest_heading_deg)
        return st

    def apply(self, ctx: KindContext, dev: FusedDevice, th: Any) -> bool:
        if not isinstance(th, HookThresholds):
            return True
        fs: Any = getattr(dev.filt, "settings", None)
        if hasattr(fs, "rope_length_known"):  # the hook filter: the length it was told (None: finds it itself)
            told = fs.rope_length_m if fs.rope_length_known else None
            if told != th.rope_length_m:  # the pendulum model changed: restart fusion
                return False
            if getattr(fs, "imu_offset_told", None) != th.imu_offset_m:  # ... or the IMU's lever arm
                return False
            if getattr(fs, "imu_tilt_told", None) != th.imu_tilt_deg:  # ... or its tilt on the hook
                return False
            if getattr(fs, "acc_bias_xy_told", None) != th.acc_bias_xy_m_s2:  # ... or its accelerometer's offset
                return False
        st: HookState = dev.state
        st.rules.set_thresholds(th)
        st.rest_heading_set_rad = None if th.rest_heading_deg is None else math.radians(th.rest_heading_deg)
        return True

    def post(self, ctx: KindContext, kb: KindBatch, now_s: float, out: Output) -> list[Timed]:
        refs = np.empty(len(kb.items))
        for i, f in enumerate(kb.items):
            st: HookState = f.dev.state
            if st.rest_heading_rad is None:
                st.rest_heading_rad = float(hook_geo.twist_heading(f.q[0]))
                st.settle_from_s = float(f.t_s[0])
            if not st.rest_heading_redone and (q0 := getattr(f.dev.filt, "start_redone_q0", None)) is not None:
                # the filter started again told the rope length it found: its better estimate of the same sample
                st.rest_heading_rad, st.rest_heading_redone = float(hook_geo.twist_heading(q0)), True
            if st.settle_from_s is not None:
                _settle_reference(st, f)
            if st.rest_heading_set_rad is None:  # read at the start (β = 0 then): it follows the output's North
                refs[i] = st.rest_heading_rad + float(getattr(f.dev.filt, "north_turn_rad", 0.0))
            else:
                refs[i] = st.rest_heading_set_rad
        swing = hook_geo.swing_angle(kb.q)
        tors = hook_geo.torsion(kb.q, np.repeat(refs, kb.stop - kb.start))
        interval_s = ctx.settings.swing_interval_s
        ran: list[tuple[int, list[Condition], int, int]] = []  # (device index, its new conditions, its picks [a, b))
        picks: list[tuple[int, int, int, int]] = []  # (device index, row in kb, seq, t_us) of each Swing to send
        # a hook whose start may still be redone (not told its rope, swinging at start) is not judged until it is:
        # its first seconds can read several degrees off (issue 11: false swing warnings on 5 of 33 such hooks)
        held = [bool(getattr(f.dev.filt, "start_pending", False)) for f in kb.items]
        rules = hook_rules([f.dev.state.rules for f in kb.items], kb.t_s, swing, tors, kb.start, kb.stop, held)
        for i, (f, new) in enumerate(zip(kb.items, rules, strict=True)):
            dev, rows, st = f.dev, kb.rows(i), f.dev.state
            if isinstance(new, Exception):  # only this hook restarts
                ctx.fail(dev, new, out)
                continue
            first = len(picks)
            for j, seq, t_us in f.ends:
                if f.t_s[j] - st.last_swing_t_s < interval_s - 1e-9:
                    continue
                st.last_swing_t_s = float(f.t_s[j])
                picks.append((i, rows.start + j, seq, t_us))
            ran.append((i, new, first, len(picks)))
        # bearing and Φ of every Swing of the batch in one call each (they were one call per message)
        k_rows = np.fromiter((k for _, k, _, _ in picks), dtype=np.int64, count=len(picks))
        q_picked = kb.q[k_rows]
        bearing = hook_geo.displacement_bearing(q_picked).tolist()
        phi = hook_geo.swing_direction_paper(q_picked, refs[[i for i, _, _, _ in picks]]).tolist()
        angle, twist = swing[k_rows].tolist(), tors[k_rows].tolist()
        # pydantic's range checks of the batch's floats and ints at once; a message outside them (or a device whose
        # heading or rope is) is built through pydantic, which raises as it always did
        trusted = bool(picks) and _swings_valid(picks, kb, swing[k_rows], bearing, phi, tors[k_rows])
        conds: list[Timed] = []
        for i, new, first, stop in ran:
            dev, st = kb.items[i].dev, kb.items[i].dev.state
            try:
                if stop > first:
                    rope = getattr(dev.filt, "rope_length_m", None)  # the hook filter's estimate at the batch's end
                    rope = None if rope is None else float(rope)
                    heading = math.remainder(float(refs[i]), 2.0 * math.pi)
                    # the torsion's 1σ: from a configured rest heading only (the covariance holds the heading, not
                    # the twist since the first fused one); at the batch's end, as the rope
                    std = getattr(dev.filt, "torsion_std_rad", None) if st.rest_heading_set_rad is not None else None
                    std = None if std is None else float(std)
                    fast = (trusted and abs(heading) <= TWO_PI and (rope is None or 0.0 < rope <= 1000.0)
                            and (std is None or 0.0 <= std < math.inf))  # fmt: skip
                for m in range(first, stop):
                    _, _, seq, t_us = picks[m]
                    fields = {"device_id": dev.device_id, "seq": seq, "t_us": t_us,
                              "wall_t_us": t_us + dev.wall_offset_us, "swing_angle_rad": angle[m],
                              "swing_direction_rad": bearing[m], "torsion_rad": twist[m], "swing_phi_rad": phi[m],
                              "rest_heading_rad": heading, "rope_length_m": rope,
                              "provisional": True if held[i] else None, "torsion_std_rad": std}  # fmt: skip
                    st.swing = (schemas.prevalidated(schemas.Swing, {"v": 1, **fields}, _SWING_SET) if fast
                                else schemas.Swing(**fields))  # fmt: skip
                    out.swings.append(st.swing)
                conds += timed(dev, new)
            except Exception as exc:  # only this hook restarts
                ctx.fail(dev, exc, out)
        return conds


def _settle_reference(st: HookState, f: Fused) -> None:
    """Integrate the z gyro over `f`'s samples; once `REFERENCE_SETTLE_S` of them followed on from the first fused
    sample (and no re-start of the filter is pending), take the reference again: the heading now, less the output's
    North turn and the twist since, with the filter's bias and z scale as learnt now. A gap as the fusion bank tells
    it (`gaps.gap_tol_s`: a lost packet, a `t0_us` off by more than the jitter tolerance) or a sample that far back
    in time leaves the first reading: the twist across it is not known."""
    t, dt = f.t_s, f.dev.dt_s
    if t.shape[0] == 0:
        return
    first = st.settle_time_s == 0.0 and float(t[0]) == st.settle_from_s  # the block holding the first sample
    # a step off the period by more than the fusion bank's gap tolerance, either way (a jittery t0_us between
    # packets that follow on is within it, as it is no gap to the filter)
    steps = np.diff(t) if first else np.diff(t, prepend=st.settle_last_s)
    tol = gap_tol_s(dt, all(f.dev.follows))
    if steps.shape[0] and float(np.max(np.abs(steps - dt))) > tol:
        st.settle_from_s = None
        return
    rates = f.gyr[1:, 2] if first else f.gyr[:, 2]  # the first sample's rate turns nothing before it
    st.settle_rate_sum_rad += float(np.sum(rates)) * dt
    st.settle_time_s += rates.shape[0] * dt
    st.settle_last_s = float(t[-1])
    filt = f.dev.filt
    if st.settle_time_s < REFERENCE_SETTLE_S or filt is None or getattr(filt, "start_pending", False):
        return
    bias_z = float(getattr(filt, "gyro_bias_rad_s", np.zeros(3))[2])
    scale = float(getattr(filt, "gyro_z_scale", 0.0))
    twist = (st.settle_rate_sum_rad - bias_z * st.settle_time_s) / (1.0 + scale)
    north = float(getattr(filt, "north_turn_rad", 0.0))
    st.rest_heading_rad = float(hook_geo.twist_heading(f.q[-1])) - north - twist
    st.rest_heading_redone, st.settle_from_s = True, None
