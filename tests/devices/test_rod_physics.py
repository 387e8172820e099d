"""Rod physics: bites, drop-backs, handling, fights, line breaks, the reel, and tip kinematics."""

from __future__ import annotations

import math

import numpy as np
import pytest

from devices import _quat
from devices.rod_physics import (
    FISH_STATES,
    Bite,
    DropBack,
    Fight,
    Handling,
    RodBank,
    RodSettings,
    RodSim,
    Wind,
    parse_script,
    reel_speed_for,
    tip_kinematics,
)

DT = 0.01


def run(sim: RodSim, seconds: float, cmd: float = 0.0) -> list:
    return [sim.step(DT, cmd) for _ in range(int(round(seconds / DT)))]


def pitch_deg(states: list) -> np.ndarray:
    return np.degrees([s.pitch_rad for s in states])


@pytest.mark.parametrize("depth_deg", [10.0, 20.0, 30.0])
def test_bite_lowers_pitch_by_the_scripted_amount(depth_deg: float) -> None:
    sim = RodSim(seed=1)
    sim.inject(Bite(t_s=1.0, duration_s=3.0, depth_rad=math.radians(depth_deg), tremble=0.0))
    states = run(sim, 5.0)
    p = pitch_deg(states)
    rest = p[50:95].mean()
    assert rest == pytest.approx(math.degrees(sim.settings.rest_pitch_rad), abs=0.05)
    hold = p[250:390].mean()  # settled part of the bite
    assert rest - hold == pytest.approx(depth_deg, abs=0.5)
    assert p[-20:].mean() == pytest.approx(rest, abs=0.5)  # back to rest
    # the onset comes with a downward transient of the tip: specific force along body z dips below g
    acc_z = np.array([s.acc_m_s2[2] for s in states])
    assert acc_z[100:160].min() < acc_z[50:95].mean() - 1.0


def test_drop_back_raises_pitch_a_few_degrees() -> None:
    sim = RodSim(seed=2)
    sim.inject(DropBack(t_s=1.0, duration_s=3.0))
    p = pitch_deg(run(sim, 4.0))
    rise = p[250:390].mean() - p[50:95].mean()
    expected = math.degrees(float(sim.settings.bend_rad(sim.settings.baseline_tension_n)))
    assert rise == pytest.approx(expected, abs=0.3)
    assert 2.0 < rise < 8.0


def test_handling_changes_roll_and_yaw_but_not_pitch() -> None:
    sim = RodSim(seed=3)
    sim.inject(Handling(t_s=0.5, duration_s=4.0, roll_rad=math.radians(30), yaw_rad=math.radians(20),
                        pitch_rad=math.radians(0.5)))
    states = run(sim, 6.0)
    roll = np.degrees([s.roll_rad for s in states])
    yaw = np.degrees([s.yaw_rad for s in states])
    p = pitch_deg(states)
    assert roll.max() == pytest.approx(30.0, abs=2.0)
    assert yaw.max() - yaw[:40].mean() == pytest.approx(20.0, abs=2.0)
    assert np.abs(p - p[:40].mean()).max() < 1.0  # well under the 10° bite threshold


def test_line_breaks_above_breaking_strength_and_fish_escapes() -> None:
    sim = RodSim(RodSettings(breaking_strength_n=30.0, drag_n=200.0), seed=4)
    sim.inject(Fight(t_s=0.2, mass_kg=5.0, stamina=1.0, pull_n=60.0))
    states = run(sim, 5.0, cmd=0.0)
    broke = [s for s in states if s.line_broken]
    assert broke, "a 60 N fish against a locked 200 N drag must break a 30 N line"
    assert broke[0].fish_state == "escaped"
    before = [s.tension_n for s in states if not s.line_broken]
    assert max(before) <= 30.0 + 1e-9  # the break happens at the first sample above the strength
    assert states[-1].tension_n < 2.0  # no fish on the line any more
    labels = [lab.label for lab in sim.bank.drain_labels()]
    assert "line_break" in labels


def test_drag_below_breaking_strength_saves_the_line() -> None:
    sim = RodSim(RodSettings(breaking_strength_n=30.0, drag_n=15.0), seed=4)
    sim.inject(Fight(t_s=0.2, mass_kg=5.0, stamina=1.0, pull_n=60.0))
    states = run(sim, 5.0, cmd=0.0)
    assert not any(s.line_broken for s in states)
    assert states[-1].line_out_m > states[0].line_out_m + 1.0  # line slipped out through the drag
    assert max(s.tension_n for s in states) < 30.0


def test_a_tired_fish_is_landed_by_reeling_in() -> None:
    bank = RodBank(RodSettings(), 4, seed=5)  # four fights at once, physics only (no kinematics)
    bank.line_out[:] = 8.0
    bank.inject(Fight(t_s=0.1, mass_kg=1.0, stamina=0.2, endurance_s=10.0))
    for _ in range(3000):
        bank.step(0.02, 0.8)
        if (bank.fish == FISH_STATES.index("landed")).all():
            break
    assert [FISH_STATES[f] for f in bank.fish] == ["landed"] * 4
    assert (bank.line_out <= bank.s.land_line_m).all()
    assert sum(lab.label == "landed" for lab in bank.drain_labels()) == 4


def test_reel_obeys_speed_commands_with_lag_and_limit() -> None:
    s = RodSettings()
    sim = RodSim(s, seed=6)
    start = sim.step(DT).line_out_m
    states = run(sim, 2.0, cmd=reel_speed_for("in", 0.5, s))
    assert states[-1].motor_speed_m_s == pytest.approx(0.5, abs=1e-3)
    # after the lag (5 τ) the line comes in at the commanded speed
    assert states[-1].line_in_speed_m_s == pytest.approx(0.5, abs=1e-3)
    assert start - states[-1].line_out_m == pytest.approx(0.5 * (2.0 - s.motor_tau_s), abs=0.05)
    assert states[10].motor_speed_m_s == pytest.approx(0.5 * (1 - math.exp(-0.11 / s.motor_tau_s)), abs=0.03)
    states = run(sim, 1.0, cmd=reel_speed_for("out", 0.3, s))
    assert states[-1].line_in_speed_m_s == pytest.approx(-0.3, abs=1e-3)
    held = run(sim, 1.0, cmd=reel_speed_for("stop", None, s))
    assert held[-1].line_in_speed_m_s == pytest.approx(0.0, abs=1e-3)
    assert reel_speed_for("speed", 9.0, s) == s.max_reel_speed_m_s
    assert reel_speed_for("speed", -0.4, s) == -0.4
    assert reel_speed_for("in", None, s) == s.default_reel_speed_m_s


def test_true_gyro_integrates_to_the_true_attitude() -> None:
    """Consistency of the truth: integrating the body rates reproduces the quaternions (wind + handling)."""
    bank = RodBank(RodSettings(), 1, seed=7)
    bank.inject(Wind(0.0, 10.0, 2.0))
    bank.inject(Handling(0.5, 2.0))
    bank.inject(Bite(1.0, 1.0))
    dt = 0.001
    blk = bank.run_block(3000, dt)
    q = blk.quat_wxyz[0, 0]
    for w0, w1 in zip(blk.gyr_rad_s[0, :-1], blk.gyr_rad_s[0, 1:], strict=True):
        w = 0.5 * (w0 + w1) * dt
        angle = np.linalg.norm(w)
        dq = np.concatenate([[math.cos(angle / 2)], np.sin(angle / 2) * w / max(angle, 1e-15)])
        q = _quat.multiply(q, dq)
    err = 2 * math.acos(min(1.0, abs(float(np.dot(q, blk.quat_wxyz[0, -1])))))
    assert math.degrees(err) < 0.2


def test_tip_kinematics_accelerometer_matches_finite_differences() -> None:
    t = np.linspace(0, 2, 2001)
    pitch, yaw = 0.5 + 0.2 * np.sin(3 * t), 0.3 * np.cos(2 * t)
    e = np.stack([np.zeros_like(t), pitch, yaw], -1)
    de = np.stack([np.zeros_like(t), 0.6 * np.cos(3 * t), -0.6 * np.sin(2 * t)], -1)
    dde = np.stack([np.zeros_like(t), -1.8 * np.sin(3 * t), -1.2 * np.cos(2 * t)], -1)
    q, _, f = tip_kinematics(e, de, dde, 0.8)
    pos = 0.8 * np.stack([np.cos(pitch) * np.cos(yaw), np.cos(pitch) * np.sin(yaw), np.sin(pitch)], -1)
    h = t[1] - t[0]
    acc = (pos[2:] - 2 * pos[1:-1] + pos[:-2]) / h**2 + [0, 0, 9.80665]
    np.testing.assert_allclose(_quat.rotate_inverse(q[1:-1], acc), f[1:-1], atol=1e-4)


def test_bank_of_rods_is_vectorised_and_per_rod_events_stay_local() -> None:
    bank = RodBank(RodSettings(), 3, seed=8)
    bank.inject(Bite(0.5, 2.0, math.radians(20), tremble=0.0), rods=1)
    blk = bank.run_block(200, DT)
    drop = np.degrees(blk.euler_rad[:, 20, 1] - blk.euler_rad[:, 199, 1])
    assert drop[1] > 15.0 and abs(drop[0]) < 0.1 and abs(drop[2]) < 0.1
    np.testing.assert_allclose(np.linalg.norm(blk.quat_wxyz, axis=-1), 1.0, atol=1e-12)


def test_parse_script_accepts_degrees_and_rejects_unknown_events() -> None:
    events = parse_script([{"type": "handling", "t_s": 2, "roll_deg": 10}, {"type": "bite", "t_s": 1}])
    assert isinstance(events[0], Bite) and isinstance(events[1], Handling)
    assert events[1].roll_rad == pytest.approx(math.radians(10))
    with pytest.raises(ValueError):
        parse_script([{"type": "shark", "t_s": 1}])
    with pytest.raises(ValueError):
        parse_script([{"type": "bite", "t_s": 1, "colour": "red"}])
