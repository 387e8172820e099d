"""The evaluate command on a folder of unseen, shortened BROAD files (no trials.json: groups from names)."""

from __future__ import annotations

import json

import numpy as np
import pytest
import scipy.io

from gateway.fusion import broad, evaluate, registry, tuning
from gateway.fusion.mahony import MahonyFilter, MahonySettings
from tests.fusion.conftest import trial_slice


class NineDOnly(MahonyFilter):
    """A filter that refuses 6D, to check that evaluate skips that mode."""

    def __init__(self, *, use_mag: bool = True) -> None:
        if not use_mag:
            raise NotImplementedError("9D only")
        super().__init__(use_mag=use_mag)


@pytest.fixture(scope="module")
def short_dir(broad_dir, tmp_path_factory):
    out = tmp_path_factory.mktemp("broad_short")
    pairs = (("06_undisturbed_fast_rotation_A", "a_undisturbed_rot"), ("24_disturbed_tapping_A", "b_disturbed_tap"))
    for src, dst in pairs:
        t = trial_slice(broad_dir, src, 60.0)
        scipy.io.savemat(out / f"{dst}.mat", {
            "imu_gyr": t.gyr_rad_s, "imu_acc": t.acc_m_s2, "imu_mag": t.mag_uT, "opt_quat": t.quat_ref,
            "opt_pos": t.pos_m, "movement": t.movement.astype(np.uint8)[:, None],
            "sampling_rate": np.array([[t.rate_hz]]), "info": np.array([f"shortened {src}"]),
        })
    return out


def test_help_exits_cleanly(capsys):
    with pytest.raises(SystemExit) as e:
        evaluate.main(["--help"])
    assert e.value.code == 0
    assert "--filter" in capsys.readouterr().out


def test_json_output_matches_direct_scoring(short_dir, capsys, monkeypatch):
    monkeypatch.setitem(registry.FILTERS, "nine_only", "tests.fusion.test_evaluate:NineDOnly")
    args = [str(short_dir), "--filter", "mahony", "--filter", "nine_only", "--json", "--no-progress"]
    assert evaluate.main(args) == 0
    out = json.loads(capsys.readouterr().out)
    fig = out["filters"]["mahony"]
    assert set(fig) == {"9D", "6D"}
    assert set(fig["9D"]) == {"all", "undisturbed", "disturbed"}
    assert set(out["filters"]["nine_only"]) == {"9D"}  # 6D skipped
    # the figures are the scorer's, and "all" is the plain mean of the two trials
    trials = [broad.load_trial(p) for p in broad.find_trials(short_dir)]
    direct = [broad.score(broad.run_filter(MahonyFilter(), t, "9D"), t, "9D") for t in trials]
    per_trial = out["trials"]["mahony"]["9D"]
    for t, s in zip(trials, direct, strict=True):
        assert per_trial[t.name]["total"] == pytest.approx(s.total_deg, abs=1e-9)
    assert fig["9D"]["all"]["total"] == pytest.approx(np.mean([s.total_deg for s in direct]), abs=1e-9)
    assert fig["9D"]["undisturbed"]["inclination"] == pytest.approx(direct[0].inclination_deg, abs=1e-9)
    assert fig["9D"]["all"]["samples_per_s"] > 0
    # the same filter's 6D score differs (heading offset removed, no magnetometer)
    assert fig["6D"]["all"]["total"] != pytest.approx(fig["9D"]["all"]["total"], abs=1e-6)


def test_table_is_aligned_and_filters_by_glob(short_dir, capsys):
    assert evaluate.main([str(short_dir), "--filter", "mahony", "--mode", "9D", "--trials", "b_*",
                          "--no-progress"]) == 0
    lines = capsys.readouterr().out.strip().splitlines()
    assert lines[0].split()[:3] == ["filter", "mode", "trial"]
    assert any("b_disturbed_tap" in ln for ln in lines)
    assert not any("a_undisturbed_rot" in ln for ln in lines)
    assert not any(" 6D " in ln for ln in lines)
    assert len({len(ln) for ln in lines[1:]}) == 1  # every row padded to the same width


def test_unknown_filter_and_empty_folder_fail_cleanly(tmp_path, capsys):
    assert evaluate.main([str(tmp_path)]) == 2
    assert evaluate.main([str(tmp_path), "--filter", "nope"]) == 2


def test_cv_scores_each_trial_with_gains_chosen_on_the_others(short_dir, capsys, monkeypatch, tmp_path):
    """--cv on two trials: each trial is scored with the candidate that is best on the *other* trial (checked by
    running both candidates directly), and the in-sample row is the best mean over both."""
    spec = tuning.TuningSpec("gateway.fusion.mahony:MahonyFilter", "gateway.fusion.mahony:MahonySettings",
                             tuning.product(kp=(0.05, 1.0)))
    monkeypatch.setattr(tuning, "SPECS", {"mahony": spec})
    cache = tmp_path / "cv.json"
    args = [str(short_dir), "--cv", "--mode", "9D", "--json", "--no-progress", "--cache", str(cache)]
    assert evaluate.main(args) == 0
    out = json.loads(capsys.readouterr().out)
    trials = [broad.load_trial(p) for p in broad.find_trials(short_dir)]
    direct = np.array([[broad.score(broad.run_filter(MahonyFilter(MahonySettings(kp=kp)), t, "9D"), t, "9D").total_deg
                        for t in trials] for kp in (0.05, 1.0)])  # (candidate, trial)
    assert direct[0, 0] != pytest.approx(direct[1, 0], abs=1e-3)  # the candidates differ, so the choice matters
    loo = out["loo"]["mahony"]["9D"]
    for j, t in enumerate(trials):
        chosen = int(np.argmin(direct[:, 1 - j]))  # best on the other trial
        assert loo["trials"][t.name]["total"] == pytest.approx(direct[chosen, j], abs=1e-9)
        assert out["choices"]["mahony"]["9D"]["per_fold"][j] == {"kp": (0.05, 1.0)[chosen]}
    assert out["in_sample"]["mahony"]["9D"]["all"]["total"] == pytest.approx(direct.mean(axis=1).min(), abs=1e-9)
    # the cache is used: a planted score comes back instead of a new run
    data = json.loads(cache.read_text())
    data = {k: [42.0, 42.0, 42.0] for k in data}
    cache.write_text(json.dumps(data))
    assert evaluate.main(args) == 0
    assert json.loads(capsys.readouterr().out)["loo"]["mahony"]["9D"]["all"]["total"] == 42.0


def test_cv_table_names_filters_and_rejects_untuned(short_dir, capsys, monkeypatch):
    spec = tuning.TuningSpec("gateway.fusion.mahony:MahonyFilter", "gateway.fusion.mahony:MahonySettings",
                             tuning.product(kp=(0.2,)))
    monkeypatch.setattr(tuning, "SPECS", {"mahony": spec})
    assert evaluate.main([str(short_dir), "--cv", "--mode", "6D", "--no-progress"]) == 0
    text = capsys.readouterr().out
    assert "leave-one-trial-out" in text and "in-sample" in text
    assert any(ln.split()[:2] == ["mahony", "6D"] for ln in text.splitlines())
    assert evaluate.main([str(short_dir), "--cv", "--filter", "hook", "--no-progress"]) == 2
