"""Leave-one-trial-out selection: known answers on a small score table, and the honesty property (a trial's own scores
never influence the candidate it is scored with)."""

from __future__ import annotations

import numpy as np
from hypothesis import given
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from gateway.fusion import tuning


def test_product_and_star_grids():
    assert tuning.product(a=(1, 2), b=(3,)) == ({"a": 1, "b": 3}, {"a": 2, "b": 3})
    s = tuning.star({"a": 1.0, "b": 2.0}, a=(0.5, 1.0, 2.0), b=(4.0,))
    assert s == ({"a": 1.0, "b": 2.0}, {"a": 0.5, "b": 2.0}, {"a": 2.0, "b": 2.0}, {"a": 1.0, "b": 4.0})


def test_6d_drops_magnetometer_parameters():
    spec = tuning.TuningSpec("m:F", "m:S", tuning.product(k=(1.0, 2.0), k_mag=(0.1, 0.2)), frozenset({"k_mag"}))
    assert len(spec.for_mode("9D")) == 4
    assert spec.for_mode("6D") == ({"k": 1.0}, {"k": 2.0})


def test_every_spec_holds_the_documented_defaults():
    """Each candidate table contains the filter's shipped settings, so LOO judges the defaults among neighbours."""
    for name, spec in tuning.SPECS.items():
        defaults = tuning._load(spec.settings_path)()
        assert any(all(getattr(defaults, k) == v for k, v in c.items()) for c in spec.candidates), name


def test_leave_one_out_known_answer():
    # candidate 0 is best on trials 0-2 and bad on trial 3; candidate 1 is the reverse, a little worse on average
    total = np.array([[1.0, 1.0, 1.0, 9.0],
                      [2.0, 2.0, 2.0, 1.0]])
    scores = np.stack([total, total, total], axis=-1)
    choice, held_out = tuning.leave_one_out(scores)
    # without trial 3, candidate 0 wins (mean 1 vs 2) and is scored 9 there; without one of trials 0-2, candidate 1
    # wins (mean (2 + 2 + 1) / 3 = 1.67 vs (1 + 1 + 9) / 3 = 3.67)
    np.testing.assert_array_equal(choice, [1, 1, 1, 0])
    np.testing.assert_allclose(held_out[:, 0], [2.0, 2.0, 2.0, 9.0])
    # in-sample (one choice on all four) would report candidate 1's mean 1.75; LOO reports 3.75
    assert held_out[:, 0].mean() > total[1].mean()


@given(arrays(np.float64, (4, 6), elements=st.floats(0.1, 10.0)), st.integers(0, 5),
       arrays(np.float64, 4, elements=st.floats(0.1, 10.0)))
def test_held_out_scores_never_influence_their_own_choice(total, j, replacement):
    scores = np.stack([total, total, total], axis=-1)
    choice, _ = tuning.leave_one_out(scores)
    changed = scores.copy()
    changed[:, j, 0] = replacement
    choice2, held = tuning.leave_one_out(changed)
    assert choice2[j] == choice[j]
    assert held[j, 0] == replacement[choice[j]]
