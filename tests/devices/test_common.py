"""IMU error model statistics, quantisation, saturation, link loss, payloads and zenoh options."""

from __future__ import annotations

import argparse
import json
import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from devices import _quat, common
from devices.common import G_M_S2, ImuErrorModel, LinkModel, LinkSim, SensorModel
from gateway import schemas

RATE_HZ = 100.0
DT = 1.0 / RATE_HZ


def still(n_dev: int, n: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    gyr = np.zeros((n_dev, n, 3))
    acc = np.zeros((n_dev, n, 3))
    acc[..., 2] = G_M_S2
    mag = np.broadcast_to(np.array(common.EARTH_FIELD_ENU_UT), (n_dev, n, 3)).copy()
    return gyr, acc, mag


def test_white_noise_std_matches_the_datasheet_density_within_5pct() -> None:
    """Bias, scale and walk off: the residual std must be density·√rate (MPU-6050: 0.05 °/s rms at 100 Hz)."""
    err = ImuErrorModel(gyro_bias_rw_rad_s_rts=0.0, acc_bias_rw_m_s2_rts=0.0, gyro_scale_std=0.0, acc_scale_std=0.0,
                        misalignment_std_rad=0.0)
    sm = SensorModel(err, 4, np.random.default_rng(1))
    g, a, m = still(4, 20_000)
    gm, am, mm = sm.measure(g, a, m, DT)
    gyr_std = (gm - sm.gyro_bias_rad_s[:, None, :]).std()
    acc_std = (am - a - sm.acc_bias_m_s2[:, None, :]).std()
    expect_g = err.gyro_noise_density_rad_s_rthz * math.sqrt(RATE_HZ)
    expect_a = err.acc_noise_density_m_s2_rthz * math.sqrt(RATE_HZ)
    assert math.degrees(expect_g) == pytest.approx(0.05, rel=1e-9)  # the datasheet's own figure
    assert gyr_std == pytest.approx(expect_g, rel=0.05)
    assert acc_std == pytest.approx(expect_a, rel=0.05)
    mag_resid = mm - np.einsum("dij,dnj->dni", sm.mag_soft_iron, m) - sm.mag_hard_iron_uT[:, None, :]
    # HMC5883L: 0.2 µT noise plus uniform quantisation of the 0.092 µT LSB
    assert mag_resid.std() == pytest.approx(math.hypot(0.2, err.mag_lsb_uT / math.sqrt(12)), rel=0.05)


def test_biases_are_drawn_with_the_configured_std_and_seen_in_the_mean() -> None:
    err = ImuErrorModel(gyro_bias_rw_rad_s_rts=0.0, acc_bias_rw_m_s2_rts=0.0)
    sm = SensorModel(err, 2000, np.random.default_rng(2))
    assert sm.gyro_bias_rad_s.std() == pytest.approx(err.gyro_bias_std_rad_s, rel=0.05)
    assert sm.acc_bias_m_s2.std() == pytest.approx(err.acc_bias_std_m_s2, rel=0.05)
    assert sm.mag_hard_iron_uT.std() == pytest.approx(err.mag_hard_iron_std_uT, rel=0.05)
    g, a, m = still(2000, 100)
    gm, _, _ = sm.measure(g, a, m, DT)
    # mean of 100 samples: noise 8.7e-4/10 = 8.7e-5 rad/s, far below the 1.7e-2 rad/s bias spread
    np.testing.assert_allclose(gm.mean(axis=1), sm.gyro_bias_rad_s, atol=5e-4)  # 5.7 sigma


def test_bias_random_walk_grows_like_sqrt_time() -> None:
    rw = 1e-3
    err = ImuErrorModel.ideal()
    err = ImuErrorModel(**{**err.__dict__, "gyro_bias_rw_rad_s_rts": rw})
    sm = SensorModel(err, 2000, np.random.default_rng(3))
    g, a, m = still(2000, 400)  # 4 s
    gm, _, _ = sm.measure(g, a, None, DT)
    assert gm[:, -1, :].std() == pytest.approx(rw * math.sqrt(4.0), rel=0.05)


def test_quantisation_to_lsb_and_saturation_at_full_scale() -> None:
    err = ImuErrorModel(gyro_noise_density_rad_s_rthz=0.0, gyro_bias_std_rad_s=0.0, gyro_bias_rw_rad_s_rts=0.0,
                        gyro_scale_std=0.0, misalignment_std_rad=0.0, acc_bias_std_m_s2=0.0, acc_scale_std=0.0,
                        acc_noise_density_m_s2_rthz=0.0, acc_bias_rw_m_s2_rts=0.0)
    sm = SensorModel(err, 1, np.random.default_rng(4))
    true = np.linspace(-12.0, 12.0, 1001)[:, None] * np.ones(3)
    acc_true = np.linspace(-100.0, 100.0, 1001)[:, None] * np.ones(3)
    g, a, _ = sm.measure(true, acc_true, None, DT)
    lsb_g = err.gyro_fs_rad_s / 32768
    lsb_a = err.acc_fs_m_s2 / 32768
    np.testing.assert_allclose(g / lsb_g, np.rint(g / lsb_g), atol=1e-6)
    np.testing.assert_allclose(a / lsb_a, np.rint(a / lsb_a), atol=1e-6)
    inside = np.abs(true) < err.gyro_fs_rad_s * 0.99
    assert np.abs(g - true)[inside].max() <= lsb_g / 2 + 1e-12
    assert g.max() == pytest.approx(32767 * lsb_g) and g.min() == pytest.approx(-32768 * lsb_g)
    assert a.max() == pytest.approx(32767 * lsb_a) and a.min() == pytest.approx(-32768 * lsb_a)
    # magnetometer: 12-bit ADC saturates at 2047 counts of 100/1090 µT
    mm = common.quantise(np.array([500.0, -500.0, 10.0]), err.mag_lsb_uT, err.mag_bits)
    np.testing.assert_allclose(mm[:2], [2047 * err.mag_lsb_uT, -2048 * err.mag_lsb_uT])


@settings(max_examples=50, deadline=None)
@given(st.floats(-1.5, 1.5), st.floats(-1.4, 1.4), st.floats(-3.1, 3.1))
def test_specific_force_and_field_at_rest_have_earth_magnitudes(roll: float, pitch: float, yaw: float) -> None:
    q = _quat.from_euler(roll, pitch, yaw)
    f = common.specific_force_body(q, np.zeros(3))
    b = common.field_body(q)
    assert np.linalg.norm(f) == pytest.approx(G_M_S2, rel=1e-12)
    assert np.linalg.norm(b) == pytest.approx(np.linalg.norm(common.EARTH_FIELD_ENU_UT), rel=1e-12)
    # pitch up -> accelerometer x reads +g sin(pitch) (design.md: at rest level it reads [0, 0, +g])
    assert f[0] == pytest.approx(G_M_S2 * math.sin(pitch), abs=1e-9)


def test_bursty_link_loss_has_the_configured_rate_and_burst_length() -> None:
    link = LinkSim(LinkModel(loss_prob=0.1, burst_len=4.0), 1000, np.random.default_rng(5))
    lost = np.array([link.lost() for _ in range(2000)])  # (time, device)
    assert lost.mean() == pytest.approx(0.1, rel=0.05)
    starts = (lost[1:] & ~lost[:-1]).sum()
    assert lost[1:].sum() / starts == pytest.approx(4.0, rel=0.05)
    assert not LinkSim(LinkModel(), 3, np.random.default_rng(0)).lost().any()


def test_imu_payload_is_a_valid_packet_with_rounded_values() -> None:
    rng = np.random.default_rng(6)
    gyr, acc, mag = rng.normal(size=(5, 3)), rng.normal(size=(5, 3)), rng.normal(size=(5, 3)) * 40
    b = common.imu_payload(device_id="rod-7", kind="rod", boot_id=3, seq=2**32 + 4, t0_us=100, rate_hz=200.0,
                           gyr_rad_s=gyr, acc_m_s2=acc, mag_uT=mag, wall_t0_us=5, temp_c=20.5)
    p = schemas.decode("rig/rod/rod-7/imu", b)
    assert isinstance(p, schemas.ImuPacket)
    assert p.seq == 4 and p.temp_c == 20.5 and p.n == 5
    np.testing.assert_allclose(np.array(p.gyr_rad_s), gyr, atol=5e-7)
    np.testing.assert_allclose(np.array(p.mag_uT), mag, atol=5e-4)
    assert json.loads(b) == json.loads(common.encode_json(json.loads(b)))


def test_zenoh_options_default_to_peer_connecting_to_the_gateway_without_multicast() -> None:
    parser = argparse.ArgumentParser()
    common.add_zenoh_args(parser)
    args = parser.parse_args([])
    conf = common.zenoh_config_from_args(args)
    assert json.loads(conf.get_json("mode")) == "peer"
    assert json.loads(conf.get_json("connect/endpoints")) == [common.DEFAULT_GATEWAY_ENDPOINT]
    assert json.loads(conf.get_json("scouting/multicast/enabled")) is False
    assert json.loads(conf.get_json("connect/exit_on_failure")) is False
    args = parser.parse_args(["--connect", "none", "--listen", "tcp/127.0.0.1:9000", "--mode", "client"])
    conf = common.zenoh_config_from_args(args)
    assert json.loads(conf.get_json("listen/endpoints")) == ["tcp/127.0.0.1:9000"]
    assert json.loads(conf.get_json("mode")) == "client"


def test_zenoh_config_file_is_the_base_and_explicit_endpoints_override_it(tmp_path) -> None:
    """`--zenoh-config` (a secure device config: mTLS client to the gateway) keeps the file's mode and endpoints;
    only --connect/--listen given on the command line replace them. Without the file: the usual peer defaults."""
    p = argparse.ArgumentParser()
    common.add_zenoh_args(p)
    f = tmp_path / "device.json5"
    f.write_text('{mode: "client", connect: {endpoints: ["tls/127.0.0.1:7448"]}, '
                 'scouting: {multicast: {enabled: false}}}')
    conf = common.zenoh_config_from_args(p.parse_args(["--zenoh-config", str(f)]))
    assert json.loads(conf.get_json("mode")) == "client"
    assert json.loads(conf.get_json("connect/endpoints")) == ["tls/127.0.0.1:7448"]
    conf = common.zenoh_config_from_args(p.parse_args(["--zenoh-config", str(f), "--connect", "tcp/127.0.0.1:9"]))
    assert json.loads(conf.get_json("connect/endpoints")) == ["tcp/127.0.0.1:9"]
    plain = common.zenoh_config_from_args(p.parse_args([]))
    assert json.loads(plain.get_json("mode")) == "peer"
    assert json.loads(plain.get_json("connect/endpoints")) == [common.DEFAULT_GATEWAY_ENDPOINT]


def test_launcher_passes_the_zenoh_config_file_to_every_device(tmp_path) -> None:
    from devices.__main__ import build_parser, child_commands

    f = tmp_path / "device.json5"
    args = build_parser().parse_args(["--zenoh-config", str(f)])
    cmds = child_commands(args)
    assert cmds and all(c[c.index("--zenoh-config") + 1] == str(f) for c in cmds.values())
