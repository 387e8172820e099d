"""The eighth round's held tip tracking (`HELD_TRACKING`, the default since the thirteenth round) and
bench.hook_suite's wrongly told rope length (`length_factor`, `--length-factor`)."""

from __future__ import annotations

import numpy as np

from bench.hook_suite import hook_estimate, main, run_seed, simulate_seed
from gateway.fusion import hook
from gateway.fusion.hook_filter import HELD_TRACKING, HOIST_ROUND, LEVER_ROUND, ROPE_ROUND, SLEW_ROUND, TIP_ROUND


def test_held_tracking_sees_a_slews_stop_with_its_own_jump_gate() -> None:
    """Windy suite seed 8 (2.9 m, a slew that stops at 27.7 s): held past its 10 s, the tip tracking follows the
    stop, which the jump test (gate 13.8) then misses (Θ 28-40 s: 0.49° measured); the held gate (χ² 5 for a tip
    estimate shrinking below its mean) sees it (0.28° measured; 0.37° with the tracking not held). On the filter of
    its round (`ROPE_ROUND`, the rope settings before the hoist round): with the hoist round's defaults both read
    0.35° there, the held gate changes nothing on this seed; the tenth round's tight tip state is undone too
    (`HOIST_ROUND`), and the eleventh round's onset re-run (`TIP_ROUND`): it re-runs this slew from its onset, after
    which held and not held both read 0.171°; the thirteenth round's length hold (`SLEW_ROUND`, whose
    held tracking `HELD_TRACKING` puts back); and the thirtieth session's lever arm in the tension row
    (`LEVER_ROUND`; with it this filter reads 0.40° / 0.60° here, the default 0.19°, 0.12° without it)."""
    case, truth, gyr, acc, mag = simulate_seed(8, 120.0, "calibrated", True, "windy")
    after_stop = (truth.t_s > 28.0) & (truth.t_s < 40.0)
    rmse = {}
    base = ROPE_ROUND | HOIST_ROUND | TIP_ROUND | SLEW_ROUND | HELD_TRACKING | LEVER_ROUND
    for name, over in (("held", base), ("no gate", base | {"move_track_hold_gate": 0.0})):
        q, _ = hook_estimate(gyr, acc, mag, case.physics.rope_length_m, overrides=over)
        rmse[name] = float(np.sqrt(np.mean(np.degrees(hook.swing_angle(q) - truth.swing_rad)[after_stop] ** 2)))
    assert rmse["held"] < 0.33, rmse
    assert rmse["no gate"] > 1.5 * rmse["held"], rmse


def test_the_suite_tells_the_filter_a_wrong_rope_length_when_asked(capsys) -> None:
    """`length_factor` 2: the filter starts from twice the true length (its rope error over the first 3 s is
    about 100 %, against a few % when told right); the command line takes `--length-factor` and says so."""
    right = run_seed(3, 3.0, "ideal", True, True)["hook"]["all"]["rope_rel"]
    wrong = run_seed(3, 3.0, "ideal", True, True, length_factor=2.0)["hook"]["all"]["rope_rel"]
    assert right < 0.1 and wrong > 0.5, (right, wrong)
    assert main(["--seeds", "3", "--duration", "2", "--imu", "ideal", "--length-factor", "1.3"]) == 0
    assert "1.3x told at t = 0" in capsys.readouterr().out
