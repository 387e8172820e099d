"""Wire protocol: round trips, rejection reasons, decode fuzzing, sequence tracking, and the protocol doc."""

from __future__ import annotations

import json
import math
import re
import types
import typing
from pathlib import Path

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from pydantic import ValidationError

from gateway import protocol_doc, schemas
from gateway.ingest.sequence import SequenceTracker
from gateway.schemas import DecodeError, decode

DOC = Path(__file__).resolve().parent.parent / "docs" / "protocol.md"


def imu_dict(n: int = 10, **over: object) -> dict[str, object]:
    d: dict[str, object] = {
        "v": 1, "device_id": "rod-1", "kind": "rod", "boot_id": 7, "seq": 41, "t0_us": 123_456, "rate_hz": 100.0,
        "gyr_rad_s": [[0.01 * i, -0.02, 0.03] for i in range(n)],
        "acc_m_s2": [[0.1, 0.2, 9.81] for _ in range(n)],
        "mag_uT": [[1.0, 20.0, -44.0] for _ in range(n)],
        "wall_t0_us": 1_700_000_000_000_000,
    }
    d.update(over)
    return d


def enc(d: dict[str, object]) -> bytes:
    return json.dumps(d).encode()


IMU_KEY = "rig/rod/rod-1/imu"


def test_imu_round_trip_preserves_every_value() -> None:
    d = imu_dict()
    p = decode(IMU_KEY, enc(d))
    assert isinstance(p, schemas.ImuPacket)
    assert p.n == 10 and p.seq == 41 and p.boot_id == 7
    assert [list(r) for r in p.gyr_rad_s] == d["gyr_rad_s"]
    again = decode(IMU_KEY, p.to_json())
    assert again == p
    gyr, acc, mag = p.arrays()
    assert gyr.shape == (10, 3) and acc[3, 2] == 9.81 and mag is not None and mag[0, 2] == -44.0
    assert p.sample_times_us()[-1] == 123_456 + 9 * 10_000


def test_examples_round_trip_through_their_keys() -> None:
    examples = protocol_doc.examples()
    assert {type(m) for _, m in examples.values()} >= {
        schemas.ImuPacket, schemas.EnvPacket, schemas.ReelStatus, schemas.RodTruth, schemas.HookTruth,
        schemas.BallTruth, schemas.ReelCommand, schemas.BallCommand,
    }
    for key, model in examples.values():
        if key.startswith("rig/"):
            assert decode(key, model.to_json()) == model
        else:  # gateway outputs: validate against their own model
            assert type(model).model_validate_json(model.to_json()) == model


@pytest.mark.parametrize(
    ("key", "payload", "reason"),
    [
        (IMU_KEY, b"{not json", "bad_json"),
        (IMU_KEY, b"", "bad_json"),
        (IMU_KEY, b"[1, 2]", "schema"),
        (IMU_KEY, enc(imu_dict(v=2)), "version"),
        (IMU_KEY, enc(imu_dict(v="1")), "version"),
        (IMU_KEY, enc({k: v for k, v in imu_dict().items() if k != "seq"}), "schema"),
        (IMU_KEY, enc(imu_dict(extra_field=1)), "schema"),
        (IMU_KEY, enc(imu_dict(acc_m_s2=[[0, 0, 9.8]] * 9)), "schema"),  # length mismatch
        (IMU_KEY, enc(imu_dict(n=0)), "schema"),
        (IMU_KEY, enc(imu_dict(n=1001)), "schema"),
        (IMU_KEY, enc(imu_dict(gyr_rad_s=[[0, 0, 51.0]] + [[0, 0, 0]] * 9)), "out_of_range"),
        (IMU_KEY, enc(imu_dict(acc_m_s2=[[-401.0, 0, 0]] * 10)), "out_of_range"),
        (IMU_KEY, enc(imu_dict(mag_uT=[[0, 5001.0, 0]] * 10)), "out_of_range"),
        (IMU_KEY, enc(imu_dict(rate_hz=2500.0)), "out_of_range"),
        (IMU_KEY, enc(imu_dict(rate_hz=0.5)), "out_of_range"),
        (IMU_KEY, enc(imu_dict(seq=2**32)), "out_of_range"),
        (IMU_KEY, enc(imu_dict(seq=-1)), "out_of_range"),
        (IMU_KEY, json.dumps(imu_dict(gyr_rad_s=[[math.nan, 0, 0]] * 10)).encode(), "non_finite"),
        (IMU_KEY, json.dumps(imu_dict(rate_hz=math.inf)).encode(), "non_finite"),
        (IMU_KEY, enc(imu_dict(device_id="rod-2")), "key_mismatch"),
        ("rig/hook/rod-1/imu", enc(imu_dict()), "key_mismatch"),
        ("rig/rod/rod-1/imu/x", enc(imu_dict()), "unknown_key"),
        ("rig/ball/rod-1/imu", enc(imu_dict()), "unknown_key"),
        ("fish/rod/rod-1/imu", enc(imu_dict()), "unknown_key"),
        ("rig/rod/rod 1/imu", enc(imu_dict()), "unknown_key"),
        (IMU_KEY, b" " * (schemas.MAX_PAYLOAD_BYTES + 1), "too_large"),
    ],
)
def test_malformed_packets_are_rejected_with_their_reason(key: str, payload: bytes, reason: str) -> None:
    with pytest.raises(DecodeError) as info:
        decode(key, payload)
    assert info.value.reason == reason, info.value.detail
    assert reason in schemas.REASONS


def test_truth_quaternion_must_be_unit() -> None:
    key, truth = protocol_doc.examples()["rod_truth"]
    d = json.loads(truth.to_json())
    d["quat_wxyz"][0] = [0.5, 0.0, 0.0, 0.0]
    with pytest.raises(DecodeError) as info:
        decode(key, enc(d))
    assert info.value.reason == "out_of_range"


def test_key_builders_and_parser_agree() -> None:
    assert schemas.imu_key("hook", "h-9") == "rig/hook/h-9/imu"
    assert schemas.reel_cmd_key("rod-3") == "rig/rod/rod-3/reel/cmd"
    assert schemas.attitude_key("rod", "rod-3") == "gw/rod/rod-3/attitude"
    parsed = schemas.parse_key(schemas.reel_cmd_key("rod-3"))
    assert (parsed.kind, parsed.device_id, parsed.topic) == ("rod", "rod-3", "reel/cmd")
    with pytest.raises(ValueError):
        schemas.imu_key("rod", "bad/id")
    with pytest.raises(ValueError):
        schemas.env_key("*")


# ---- fuzzing: decode never raises anything but DecodeError ---------------------------------------------------

json_values = st.recursive(
    st.none() | st.booleans() | st.integers(-(2**70), 2**70) | st.floats(allow_nan=True) | st.text(max_size=20),
    lambda children: st.lists(children, max_size=5) | st.dictionaries(st.text(max_size=12), children, max_size=6),
    max_leaves=30,
)
keys = st.sampled_from([
    IMU_KEY, "rig/hook/h-1/imu", "rig/ball/b-1/env", "rig/rod/rod-1/reel", "rig/rod/rod-1/truth",
    "rig/hook/h-1/truth", "rig/ball/b-1/truth", "rig/rod/rod-1/reel/cmd", "rig/ball/b-1/cmd", "rig/x/y/z", "",
]) | st.text(max_size=40)


def _decode_or_reason(key: str, payload: bytes) -> str:
    try:
        decode(key, payload)
    except DecodeError as exc:
        assert exc.reason in schemas.REASONS
        return exc.reason
    return "ok"


@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(keys, st.binary(max_size=300))
def test_fuzz_arbitrary_bytes(key: str, payload: bytes) -> None:
    _decode_or_reason(key, payload)


@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(keys, json_values)
def test_fuzz_arbitrary_json(key: str, value: object) -> None:
    _decode_or_reason(key, json.dumps(value).encode())


@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.sampled_from(sorted(k for k in protocol_doc.examples() if protocol_doc.examples()[k][0].startswith("rig/"))),
       st.data())
def test_fuzz_mutated_valid_packets(name: str, data: st.DataObject) -> None:
    """Replace one top-level field of a valid packet with an arbitrary JSON value."""
    key, model = protocol_doc.examples()[name]
    d = json.loads(model.to_json())
    field = data.draw(st.sampled_from(sorted(d)))
    d[field] = data.draw(json_values)
    reason = _decode_or_reason(key, json.dumps(d).encode())
    assert reason in (*schemas.REASONS, "ok")


# ---- sequence tracker ----------------------------------------------------------------------------------------


def test_tracker_classifies_loss_duplicates_reorder_wrap_and_reboot() -> None:
    tr = SequenceTracker()
    seqs = [2**32 - 2, 2**32 - 1, 0, 3, 3, 2, 1, 1, 4]
    got = [tr.update(9, s) for s in seqs]
    assert [r.status for r in got] == [
        "first", "ok", "ok", "lost", "duplicate", "reordered", "reordered", "duplicate", "ok"
    ]
    assert got[3].lost == 2
    assert (tr.ok, tr.lost, tr.duplicates, tr.reordered) == (7, 0, 2, 2)
    r = tr.update(10, 500)
    assert r.status == "reboot" and tr.reboots == 1
    assert tr.update(10, 501).status == "ok"
    assert tr.update(9, 5).status == "duplicate"  # straggler from the old boot
    assert tr.update(10, 502).status == "ok" and tr.reboots == 1


@settings(max_examples=200, deadline=None)
@given(start=st.integers(0, 2**32 - 1), fate=st.lists(st.integers(0, 19), min_size=1, max_size=200))
def test_tracker_counts_match_a_lossy_reordering_link(start: int, fate: list[int]) -> None:
    """Sent seqs start..start+n (mod 2**32); per packet the link drops (0-3), duplicates (4) or swaps it with the
    next arrival (5-6); the first packet always arrives first."""
    sent = [(start + i) % 2**32 for i in range(len(fate))]
    arrivals: list[int] = []
    for i, (s, f) in enumerate(zip(sent, fate, strict=True)):
        if f <= 3 and i > 0:
            continue
        arrivals.append(s)
        if f == 4:
            arrivals.append(s)
    for i in range(1, len(arrivals) - 1):
        if fate[i % len(fate)] in (5, 6):
            arrivals[i], arrivals[i + 1] = arrivals[i + 1], arrivals[i]
    tr = SequenceTracker()
    results = [tr.update(1, s) for s in arrivals]
    unique = set(arrivals)
    assert tr.ok == len(unique)
    assert tr.duplicates == len(arrivals) - len(unique)
    newest = max(i for i, s in enumerate(sent) if s in unique)
    assert tr.lost == (newest + 1) - len(unique)  # gaps up to the newest packet received
    assert sum(r.accept for r in results) == len(unique)


# ---- protocol document ---------------------------------------------------------------------------------------


def doc_examples() -> list[tuple[str, str]]:
    """(key, json) pairs: each ```json block in the doc preceded by a line 'Key: `...`'."""
    text = DOC.read_text()
    return re.findall(r"Key: `([^`]+)`[^\n]*\n+```json\n(.*?)\n```", text, flags=re.S)


def test_protocol_doc_examples_validate() -> None:
    pairs = doc_examples()
    assert len(pairs) >= len(protocol_doc.examples())
    models = {
        "attitude": schemas.Attitude, "swing": schemas.Swing, "alarm": schemas.AlarmEvent, "height": schemas.Height,
        "attitude/block": schemas.AttitudeBlock, "gw/attitudes": schemas.AttitudeBatch,
        "gw/spots": schemas.SpotRanking, "gw/diag/ingest": schemas.IngestStats,
        "gw/diag/rejected": schemas.RejectedPacket, "gw/config": schemas.DeviceConfig,
    }
    for key, body in pairs:
        if key.startswith("rig/"):
            decode(key, body.encode())
        else:
            model = next(m for k, m in models.items() if key.endswith(k) or key.startswith(k))
            model.model_validate_json(body)


def test_protocol_doc_is_current() -> None:
    """The doc's examples are generated from the models; regenerate: `python -m gateway.schemas --write-doc ...`."""
    text = DOC.read_text()
    for key, model in protocol_doc.examples().values():
        assert f"Key: `{key}`" in text
        assert protocol_doc.example_json(model) in text, key


def test_alarm_event_carries_the_engines_severities_and_string_ids() -> None:
    from gateway.alarm.engine import Severity

    assert schemas.SEVERITIES == tuple(s.value for s in Severity)  # same levels, most severe first
    assert set(typing.get_args(schemas.Severity)) == set(schemas.SEVERITIES)
    _, alarm = protocol_doc.examples()["alarm"]
    assert isinstance(alarm, schemas.AlarmEvent)
    for sev in schemas.SEVERITIES:
        assert schemas.AlarmEvent.model_validate({**alarm.model_dump(), "severity": sev}).severity == sev
    for bad in ({"severity": "info"}, {"alarm_id": 58}, {"alarm_id": "a/b"}, {"alarm_id": ""}):
        with pytest.raises(ValidationError):
            schemas.AlarmEvent.model_validate({**alarm.model_dump(), **bad})
    uuid_hex = "0123456789abcdef0123456789abcdef"
    assert schemas.AlarmEvent.model_validate({**alarm.model_dump(), "alarm_id": uuid_hex}).alarm_id == uuid_hex


def test_device_config_example_uses_real_threshold_names() -> None:
    from gateway.config import RodThresholds

    _, cfg = protocol_doc.examples()["config"]
    assert isinstance(cfg, schemas.DeviceConfig)
    assert set(cfg.thresholds) <= set(RodThresholds.model_fields)


def test_gnss_fix_is_optional_and_range_checked() -> None:
    """A packet without `gnss` decodes as before; with one it round-trips; a latitude beyond 90° is out of range."""
    fix = {"lat_deg": 30.27, "lon_deg": 120.15, "alt_m": 7.5, "speed_m_s": 1.2, "fix_quality": 4}
    assert decode(IMU_KEY, enc(imu_dict())).gnss is None  # type: ignore[union-attr]
    pkt = decode(IMU_KEY, enc(imu_dict(gnss=fix, depth_m=2.5)))
    assert pkt.gnss == schemas.GnssFix(**fix) and pkt.depth_m == 2.5  # type: ignore[union-attr]
    with pytest.raises(schemas.DecodeError) as err:
        decode(IMU_KEY, enc(imu_dict(gnss={**fix, "lat_deg": 91.0})))
    assert err.value.reason == "out_of_range"


def _values(annotation: object) -> st.SearchStrategy[object]:
    """Values of a wire field's type (its range limits ignored: the writer must match pydantic on any value)."""
    origin, args = typing.get_origin(annotation), typing.get_args(annotation)
    if origin is typing.Annotated:
        return _values(args[0])
    if origin is typing.Literal:
        return st.sampled_from(args)
    if origin in (typing.Union, types.UnionType):
        return st.one_of(*(_values(a) for a in args))
    if origin is tuple:
        return st.tuples(*(_values(a) for a in args))
    if origin is list:
        return st.lists(_values(args[0]), max_size=3)
    if origin is dict:
        return st.dictionaries(st.text(max_size=4), _values(args[1]), max_size=2)
    if annotation is type(None):
        return st.none()
    if annotation is float:
        return st.one_of(st.floats(allow_nan=False, allow_infinity=False),
                         st.sampled_from([0.0, -0.0, 1e16, -1e16, 9.999999999999998e15, 1e-7, 1.5e-5, 1e22, 1e40, 7e99,
                                          1e100, 1.7976931348623157e308, 5e-324]))
    if annotation is bool:
        return st.booleans()
    if annotation is int:
        return st.integers(-(2**63), 2**63 - 1)
    if annotation is str:
        return st.one_of(st.text(max_size=8), st.sampled_from(["rode1", "a1e2x", "hook-3"]))
    raise AssertionError(f"no strategy for {annotation!r}")


_FLAT = [m for m in vars(schemas).values() if isinstance(m, type) and issubclass(m, schemas.WireModel)
         and m is not schemas.WireModel and schemas._json_mirror(m)]  # fmt: skip


@settings(max_examples=300, deadline=None)
@given(st.data())
def test_to_json_writes_pydantics_bytes(data: st.DataObject) -> None:
    """`to_json` (msgspec for models without nested models) gives `model_dump_json(exclude_none=True)`'s bytes for
    any field values: floats of every magnitude (1e16 and up: pydantic writes 1e+16), any text, None left out."""
    model = data.draw(st.sampled_from(_FLAT))
    hints = typing.get_type_hints(model, include_extras=True)
    values = {name: data.draw(_values(hints[name])) for name in model.model_fields}
    m = model.model_construct(**values)
    assert m.to_json() == m.model_dump_json(exclude_none=True).encode()


def test_output_models_are_written_by_msgspec() -> None:
    """The frequent outputs take the fast writer (a model that gains a nested field would silently fall back)."""
    assert {schemas.Attitude, schemas.Height, schemas.Swing, schemas.AlarmEvent, schemas.AttitudeBlock} <= set(_FLAT)
