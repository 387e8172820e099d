"""Settings from the environment, zenoh inserts, threshold validation and default/override merging."""

from __future__ import annotations

from pathlib import Path

import pytest
import zenoh
from pydantic import ValidationError

from gateway.config import (
    SENSITIVITY_STEPS,
    DeviceSettings,
    HookThresholds,
    RodThresholds,
    Settings,
    SpotPreferences,
    effective_settings,
    merge_thresholds,
)
from gateway.pipeline import Pipeline


def test_defaults(monkeypatch, tmp_path):
    monkeypatch.chdir(tmp_path)
    s = Settings()
    assert s.data_dir == tmp_path / "var" and s.db_path == tmp_path / "var" / "gateway.sqlite3"
    assert (s.zenoh_mode, s.zenoh_listen, s.zenoh_connect, s.zenoh_multicast_scouting) == (
        "peer", ["tcp/127.0.0.1:7447"], [], False,
    )  # fmt: skip
    assert (s.http_host, s.http_port, s.viser_host, s.viser_port) == ("127.0.0.1", 8000, "127.0.0.1", 8080)
    assert s.default_filter == "default"


def test_env_prefix_overrides(monkeypatch):
    monkeypatch.setenv("RIG_DATA_DIR", "/tmp/rig-x")
    monkeypatch.setenv("RIG_ZENOH_MODE", "client")
    monkeypatch.setenv("RIG_ZENOH_CONNECT", '["tcp/10.0.0.2:7447"]')
    monkeypatch.setenv("RIG_HTTP_PORT", "9001")
    s = Settings()
    assert s.data_dir == Path("/tmp/rig-x") and s.zenoh_mode == "client"
    assert s.zenoh_connect == ["tcp/10.0.0.2:7447"] and s.http_port == 9001
    monkeypatch.setenv("RIG_ZENOH_MODE", "satellite")
    with pytest.raises(ValidationError, match="zenoh_mode"):
        Settings()


def test_zenoh_config_inserts_are_accepted_by_zenoh():
    s = Settings(zenoh_mode="client", zenoh_connect=["tcp/127.0.0.1:7999"], zenoh_multicast_scouting=True)
    conf = zenoh.Config()
    for key, value in s.zenoh_config().items():
        conf.insert_json5(key, value)
    assert conf.get_json("mode") == '"client"'
    assert "tcp/127.0.0.1:7999" in conf.get_json("connect/endpoints")
    assert conf.get_json("scouting/multicast/enabled") == "true"


def test_rod_theta_order_enforced_with_clear_message():
    with pytest.raises(ValidationError, match="theta1 < theta2 < theta3"):
        RodThresholds(line_switch_deg=40.0, line_limit_deg=35.0)
    with pytest.raises(ValidationError, match="sensitivity 1: 22.5 deg"):
        RodThresholds(bite_deviation_deg=15.0, sensitivity=1, line_switch_deg=20.0)  # 15 * 1.5 > theta2 = 20
    with pytest.raises(ValidationError, match="sensitivity"):
        RodThresholds(sensitivity=6)


@pytest.mark.parametrize("step", sorted(SENSITIVITY_STEPS))
def test_sensitivity_steps_get_more_sensitive(step):
    scale, confirm, _, _ = SENSITIVITY_STEPS[step]
    if step > 1:
        prev_scale, prev_confirm, _, _ = SENSITIVITY_STEPS[step - 1]
        assert scale < prev_scale and confirm < prev_confirm
    assert RodThresholds(sensitivity=step).effective_bite_deg == pytest.approx(10.0 * scale)


def test_hook_and_spot_validation():
    with pytest.raises(ValidationError, match="warn"):
        HookThresholds(swing_warn_deg=12.0, swing_critical_deg=10.0)
    with pytest.raises(ValidationError, match="hysteresis"):
        HookThresholds(hysteresis_deg=6.0)
    with pytest.raises(ValidationError, match="unknown species"):
        SpotPreferences(species=("shark",))
    assert SpotPreferences(species=("pike", "trout")).temp_ranges_c() == {"pike": (10.0, 20.0), "trout": (10.0, 16.0)}


def test_merge_and_effective_settings():
    base = RodThresholds(bite_deviation_deg=8.0)
    merged = merge_thresholds(base, {"sensitivity": 5})
    assert (merged.bite_deviation_deg, merged.sensitivity) == (8.0, 5)
    with pytest.raises(ValidationError):
        merge_thresholds(base, {"line_limit_deg": 10.0})
    with pytest.raises(ValidationError, match="extra"):
        merge_thresholds(base, {"no_such_field": 1})
    assert effective_settings("rod", None, "default") == ("default", RodThresholds())
    name, th = effective_settings("rod", DeviceSettings(filter_name="ekf", thresholds={"sensitivity": 1}), "default",
                                  base)
    assert name == "ekf" and th == RodThresholds(bite_deviation_deg=8.0, sensitivity=1)
    # the kind's default filter is the caller's (the pipeline gives hooks the hook filter), no second copy here
    assert effective_settings("hook", DeviceSettings(), "hook")[0] == "hook"
    assert Pipeline().effective("hook", "h-1") == effective_settings("hook", None, "hook")


def test_threshold_kinds_are_the_wire_kinds():
    from gateway import schemas
    from gateway.config import THRESHOLD_MODELS, default_thresholds

    assert tuple(THRESHOLD_MODELS) == schemas.KINDS  # `ball`, never a second name for the same device
    assert isinstance(default_thresholds("ball"), SpotPreferences)
    with pytest.raises(KeyError):
        default_thresholds("env")


def test_device_settings_carry_auto_reel():
    assert DeviceSettings().auto_reel is False
    assert DeviceSettings.model_validate_json('{"auto_reel": true}').auto_reel is True
