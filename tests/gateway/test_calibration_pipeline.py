"""Per-device IMU calibration applied by the gateway itself (docs/calibration.md, "Per-device calibration").

The raw simulated rod (`ImuErrorModel.uncalibrated()`: 15 µT hard iron, 30 mg offsets) is recorded while posed and
turned (tests/test_calibrate.py's dance), `python -m gateway.calibrate` fits it, and its JSON goes into the device's
`DeviceSettings.calibration`; the real `Pipeline` then corrects acc/mag after `_gather`, warm-up included.
"""

from __future__ import annotations

import functools
import json
import tempfile
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from pydantic import ValidationError

from devices.common import FleetSettings, ImuErrorModel
from devices.sim_rod import RodFleet
from gateway import calibrate, schemas
from gateway.calibrate import DeviceCalibration
from gateway.config import DeviceSettings
from gateway.fusion.quaternion import to_euler
from gateway.pipeline import Pipeline
from gateway.recording.format import write_recording
from gateway.recording.importers import ImuStream, imu_records
from tests.gateway.conftest import Running, rod_messages
from tests.test_calibrate import RATE_HZ, dance


@functools.cache
def _fitted_text(seed: int) -> str:
    """What `python -m gateway.calibrate dance.rigrec -o cal.json` writes for the raw rod board of `seed` (the same
    drawn board as RodFleet's with that seed), recorded while posed and turned (tests/test_calibrate.py's dance)."""
    fleet = RodFleet(FleetSettings(seed=seed, id_prefix="rod"), error_model=ImuErrorModel.uncalibrated())
    _, gyr_t, acc_t, mag_t = dance(np.random.default_rng(seed))
    g, a, m = fleet.sensor.measure(gyr_t, acc_t, mag_t, 1.0 / RATE_HZ)
    with tempfile.TemporaryDirectory() as tmp:
        rec, out = Path(tmp) / "dance.rigrec", Path(tmp) / "cal.json"
        write_recording(rec, [r for *_, r in imu_records(ImuStream(RATE_HZ, g, a, m), "rod-1")])
        assert calibrate.main([str(rec), "-o", str(out), "--no-progress"]) == 0
        return out.read_text()


def fitted_json(seed: int) -> dict[str, Any]:
    """The calibration JSON of the raw rod board of `seed`, from the command."""
    d: dict[str, Any] = json.loads(_fitted_text(seed))
    assert d["device_id"] == "rod-1"
    return d


def rest_error_deg(seed: int, calibration: dict[str, Any] | None, duration_s: float = 10.0) -> np.ndarray:
    """Fused minus true (roll, pitch, yaw), degrees, after `duration_s` at rest: raw packets of the uncalibrated
    rod into a Pipeline whose rod-1 settings carry `calibration`."""
    fl = FleetSettings(seed=seed, samples_per_packet=5, id_prefix="rod")
    fleet = RodFleet(fl, error_model=ImuErrorModel.uncalibrated())
    pipe = Pipeline(device_settings={"rod-1": ("rod", DeviceSettings(calibration=calibration))})
    extra: list[Any] = []
    for k in range(int(round(duration_s / fl.period_s))):
        data, extra = fleet.tick(k)
        pipe.process([schemas.decode(m.key, m.payload) for m in data[0] if m.key.endswith("/imu")],
                     now_wall_s=1.0e9 + k * fl.period_s)  # fmt: skip
    q_true = np.array(json.loads(extra[0].payload)["quat_wxyz"][-1])
    d = np.degrees(pipe.devices["rod-1"].euler - to_euler(q_true))
    d[2] = (d[2] + 180.0) % 360.0 - 180.0
    return d


@pytest.mark.parametrize("seed", [7, 1])
def test_raw_rod_with_calibration_in_its_settings_reads_heading_within_2_deg(seed: int) -> None:
    """Calibration via DeviceSettings: yaw within 2° and roll/pitch within 1° at rest (measured roll/pitch/yaw
    0.18/0.62/0.76° and 0.38/0.00/-0.62° on seeds 7/1; packets corrected before the pipeline, tests/devices/
    test_heading.py: yaw 0.78/-0.70°); without it yaw is > 20° off (measured 51/-60°)."""
    d_cal = rest_error_deg(seed, fitted_json(seed))
    assert abs(d_cal[2]) < 2.0 and np.all(np.abs(d_cal[:2]) < 1.0), d_cal
    d_raw = rest_error_deg(seed, None, duration_s=3.0)
    assert abs(d_raw[2]) > 20.0, d_raw


def test_changed_calibration_restarts_fusion_and_the_same_one_does_not() -> None:
    """A new calibration drops the live device (its reference field came from differently corrected data); the same
    settings again, or another threshold with the same calibration, keep it running."""
    cal = fitted_json(7)
    pipe = Pipeline(device_settings={"rod-1": ("rod", DeviceSettings(calibration=cal))})
    fleet = RodFleet(FleetSettings(seed=7, samples_per_packet=5, id_prefix="rod"))
    for k in range(12):  # 0.6 s: past the 0.5 s warm-up
        data, _ = fleet.tick(k)
        pipe.process([schemas.decode(m.key, m.payload) for m in data[0] if m.key.endswith("/imu")], now_wall_s=k)
    assert "rod-1" in pipe.devices
    pipe.set_device_settings("rod-1", "rod", DeviceSettings(calibration=cal, thresholds={"sensitivity": 4}))
    assert "rod-1" in pipe.devices
    other = {**cal, "mag_offset_uT": [v + 1.0 for v in cal["mag_offset_uT"]]}
    pipe.set_device_settings("rod-1", "rod", DeviceSettings(calibration=other))
    assert "rod-1" not in pipe.devices
    np.testing.assert_allclose(pipe.bank.cal["rod-1"].mag_offset_uT, other["mag_offset_uT"])
    pipe.set_device_settings("rod-1", "rod", DeviceSettings())
    assert "rod-1" not in pipe.bank.cal


_vec = st.lists(st.floats(-50, 50), min_size=3, max_size=3)


@settings(max_examples=40, deadline=None)
@given(acc_off=_vec, acc_scale=st.lists(st.floats(0.8, 1.2), min_size=3, max_size=3), mag_off=_vec,
       soft=st.lists(st.floats(-0.1, 0.1), min_size=9, max_size=9))  # fmt: skip
def test_json_round_trip_applies_the_same_correction(
    acc_off: list[float], acc_scale: list[float], mag_off: list[float], soft: list[float]
) -> None:
    """to_json -> DeviceSettings -> from_json corrects a reading as the original does, to the JSON's rounding
    (offsets 1e-6 m/s² / 1e-4 µT, matrix 1e-6): 1e-3 of the units on readings of ~10-50."""
    cal = DeviceCalibration(np.array(acc_off), np.array(acc_scale), np.array(mag_off),
                            np.eye(3) + np.array(soft).reshape(3, 3))  # fmt: skip
    back = DeviceCalibration.from_json(DeviceSettings(calibration=cal.to_json()).calibration or {})
    acc, mag = np.array([[0.3, -9.6, 1.2]]), np.array([[12.0, -30.0, 44.0]])
    a0, m0 = cal.apply(acc, mag)
    a1, m1 = back.apply(acc, mag)
    assert m0 is not None and m1 is not None
    np.testing.assert_allclose(a1, a0, atol=1e-3)
    np.testing.assert_allclose(m1, m0, atol=1e-3)


def _good() -> dict[str, Any]:
    return DeviceCalibration.identity().to_json()


@pytest.mark.parametrize(
    ("change", "message"),
    [
        ({"acc_scale": [1.0, 1.0]}, "acc_scale: shape (2,), need (3,)"),
        ({"acc_scale": [1.0, 0.0, 1.0]}, "acc_scale: [1.0, 0.0, 1.0] outside (0.5, 2)"),
        ({"mag_soft_iron": [[1, 0, 0], [0, 1, 0], [0, 0, 0]]}, "mag_soft_iron: singular"),
        ({"mag_offset_uT": [1.0, "x", 2.0]}, "mag_offset_uT: not numbers"),
        ({"acc_offset_m_s2": [0.0, float("nan"), 0.0]}, "acc_offset_m_s2: not finite"),
        ({"acc_offset_m_s2": None}, "acc_offset_m_s2"),
    ],
)
def test_malformed_calibration_is_rejected_with_the_field_named(change: dict[str, Any], message: str) -> None:
    with pytest.raises(ValidationError, match=message.replace("(", r"\(").replace(")", r"\)").replace("[", r"\[")):
        DeviceSettings(calibration={**_good(), **change})
    bad = _good()
    del bad["mag_soft_iron"]
    with pytest.raises(ValidationError, match="mag_soft_iron: missing"):
        DeviceSettings(calibration=bad)


# -- REST -------------------------------------------------------------------------------------------------------


def test_calibration_over_rest_is_stored_applied_and_survives_a_restart(running: Callable[[], Running]) -> None:
    """PUT a calibration, GET it back; a thresholds-only PUT and a DELETE keep it, a restart keeps it (the store
    persists DeviceSettings) and the restarted pipeline applies it; null removes it; a malformed one is a 422."""
    cal = fitted_json(7)
    app = running()
    r = app.client.put("/api/devices/rod-1/settings", json={"kind": "rod", "calibration": cal}, headers=app.auth)
    assert r.status_code == 200, r.text
    assert r.json()["settings"]["calibration"] == cal
    r = app.client.put("/api/devices/rod-1/settings", json={"thresholds": {"sensitivity": 4}}, headers=app.auth)
    assert r.json()["settings"]["calibration"] == cal  # left out: kept
    assert app.client.delete("/api/devices/rod-1/settings", headers=app.auth).json()["settings"]["calibration"] == cal

    app = running()  # restart on the same data dir
    assert app.client.get("/api/devices/rod-1/settings").json()["settings"]["calibration"] == cal
    app.feed(rod_messages(0.2))
    pipe = app.client.app.state.service.pipeline  # type: ignore[attr-defined]
    np.testing.assert_allclose(pipe.bank.cal["rod-1"].mag_offset_uT, cal["mag_offset_uT"])

    bad = {**cal, "mag_soft_iron": [[1.0, 0.0], [0.0, 1.0]]}
    r = app.client.put("/api/devices/rod-1/settings", json={"calibration": bad}, headers=app.auth)
    assert r.status_code == 422 and "mag_soft_iron: shape (2, 2), need (3, 3)" in r.text, r.text
    assert app.client.get("/api/devices/rod-1/settings").json()["settings"]["calibration"] == cal  # unchanged

    r = app.client.put("/api/devices/rod-1/settings", json={"calibration": None}, headers=app.auth)
    assert r.status_code == 200 and r.json()["settings"]["calibration"] is None
    assert "rod-1" not in pipe.bank.cal
