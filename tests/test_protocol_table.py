"""The protocol table (`schemas.TOPICS`) and the IMU fast decode path.

The fast path must be invisible: for any payload, `decode(key, b)` and the pydantic reference
`decode(key, b, fast=False)` both raise with the same reason or both return equal packets (same values, same float
types, same fields set, same JSON).
"""

from __future__ import annotations

import json
import math
import pickle
from typing import Any

import msgspec
import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from gateway import protocol_doc, schemas
from gateway.ingest.bus import key_matches
from tests.test_schemas import DOC, imu_dict, json_values

IMU_KEY = "rig/rod/rod-1/imu"


# ---- the table -----------------------------------------------------------------------------------------------


def test_every_device_topic_key_parses_back_to_its_row_and_matches_its_selector() -> None:
    seen = 0
    for t in schemas.TOPICS:
        for kind in t.kinds:
            key = t.key(kind, "dev-1")
            assert key_matches(schemas.selector(t), key), (t.name, key)
            if key.startswith("rig/") and t.suffix:
                parsed = schemas.parse_key(key)
                assert (parsed.kind, parsed.device_id, parsed.topic) == (kind, "dev-1", t.suffix)
                seen += 1
        for kind in set(schemas.KINDS) - set(t.kinds) if t.kinds else ():
            with pytest.raises(ValueError):
                t.key(kind, "dev-1")
    assert seen == 11  # imu x3 (rod, hook, imu), env, reel, crane, truth x3, reel/cmd, cmd


def test_named_builders_and_selectors_are_the_tables() -> None:
    assert schemas.imu_key("hook", "h-2") == schemas.T_IMU.key("hook", "h-2") == "rig/hook/h-2/imu"
    assert schemas.truth_key("ball", "b-1") == "rig/ball/b-1/truth"
    assert schemas.alarm_key("ball", "b-1") == "gw/ball/b-1/alarm"
    assert schemas.SEL_DEVICE_DATA == ("rig/*/*/imu", "rig/ball/*/env", "rig/rod/*/reel", "rig/hook/*/crane")
    assert schemas.crane_key("h-2") == "rig/hook/h-2/crane"
    assert schemas.SEL_TRUTH == "rig/*/*/truth" and schemas.SEL_DEVICE_TOKENS == "rig/*/*"
    assert (schemas.SEL_REEL_CMD, schemas.SEL_BALL_CMD) == ("rig/rod/*/reel/cmd", "rig/ball/*/cmd")
    with pytest.raises(ValueError):
        schemas.truth_key("buoy", "b-1")
    with pytest.raises(ValueError):
        schemas.swing_key("bad/id")


def test_each_kind_has_a_token_alarm_and_config_row_and_imu_kinds_get_imu_outputs() -> None:
    for t in (schemas.T_DEVICE_TOKEN, schemas.T_ALARM, schemas.T_CONFIG):
        assert t.kinds == schemas.KINDS
    for t in (schemas.T_IMU, schemas.T_ATTITUDE, schemas.T_HEIGHT):
        assert t.kinds == schemas.IMU_KINDS
    blocking = ["reel_cmd", "ball_cmd", "attitude_block", "swing", "alarm", "diag_rejected"]
    assert [t.name for t in schemas.TOPICS if t.block] == blocking
    assert len({t.name for t in schemas.TOPICS}) == len(schemas.TOPICS)


def test_decode_dispatches_every_device_example_to_its_rows_model() -> None:
    for key, model in protocol_doc.examples().values():
        if key.startswith("rig/"):
            parsed = schemas.parse_key(key)
            row = next(t for t in schemas.TOPICS if t.suffix == parsed.topic and parsed.kind in t.kinds)
            assert type(schemas.decode(key, model.to_json())) is row.model
            assert schemas.encoding_of(type(model)) == row.encoding


def test_protocol_doc_generated_sections_are_in_step() -> None:
    """Regenerate with `python -m gateway.schemas --write-doc docs/protocol.md`."""
    text = DOC.read_text()
    assert protocol_doc.keys_markdown() in text
    assert protocol_doc.all_fields_markdown() in text
    assert protocol_doc.examples_markdown() in text


# ---- the fast path mirrors ImuPacket ---------------------------------------------------------------------------


def _bounds(schema: dict[str, Any], defs: dict[str, Any], path: str, out: dict[str, tuple[Any, ...]]) -> None:
    """Leaf constraints by path, integer exclusive bounds turned inclusive, nulls and refs flattened."""
    if "$ref" in schema:
        _bounds(defs[schema["$ref"].split("/")[-1]], defs, path, out)
        return
    for alt in schema.get("anyOf", []):
        if alt.get("type") != "null":
            _bounds(alt, defs, path, out)
    if "properties" in schema:
        for name, sub in schema["properties"].items():
            _bounds(sub, defs, f"{path}.{name}", out)
        out[path + ".required"] = tuple(sorted(schema.get("required", [])))
    if isinstance(schema.get("items"), dict):
        _bounds(schema["items"], defs, f"{path}[]", out)
    for i, sub in enumerate(schema.get("prefixItems", [])):
        _bounds(sub, defs, f"{path}[{i}]", out)
    if schema.get("type") == "array":
        out[path + ".len"] = (schema.get("minItems", 0), schema.get("maxItems"))
    if "const" in schema or "enum" in schema:
        out[path] = ("enum", *schema.get("enum", [schema.get("const")]))
    elif schema.get("type") in ("number", "integer"):
        lo, hi = schema.get("minimum"), schema.get("maximum")
        if "exclusiveMaximum" in schema:
            hi = schema["exclusiveMaximum"] - 1
        out[path] = (schema["type"], lo, hi)


def test_imu_wire_mirror_has_the_models_fields_and_constraints() -> None:
    """A limit changed in ImuPacket but not in `_ImuWire` (or the reverse) would let the fast path accept what
    pydantic rejects; the hypothesis test below may miss a narrow band, this comparison does not."""
    pyd = schemas.ImuPacket.model_json_schema()
    (wire_ref,), wire_defs = msgspec.json.schema_components([schemas._ImuWire])
    wire = wire_defs["_ImuWire"]
    got: dict[str, tuple[Any, ...]] = {}
    want: dict[str, tuple[Any, ...]] = {}
    _bounds(wire, wire_defs, "", got)
    _bounds(pyd, pyd.get("$defs", {}), "", want)
    for path in list(want):  # the mirror leaves these to the key check (the key's id matched the same pattern)
        if path in (".device_id", ".kind"):
            want.pop(path)
    assert got == want


@st.composite
def imu_payloads(draw: st.DrawFn) -> bytes:
    """IMU packets near and across every limit: valid ones, one-field mutations, dropped/extra fields, ints for
    floats, booleans, nulls, NaN, huge ints, duplicate keys."""
    n = draw(st.integers(1, 4))
    limit = draw(st.sampled_from([schemas.GYR_LIMIT_RAD_S, schemas.ACC_LIMIT_M_S2, schemas.MAG_LIMIT_UT]))
    edge = st.sampled_from([0, 1, -1, limit, -limit, math.nextafter(limit, math.inf), 1.05 * limit, -1.05 * limit,
                            50, 400, 5000, 5001, 2**53 + 1, 2**64, -0.0, 1e-320, True, None, "1", math.nan, math.inf])
    num = st.floats(-6000, 6000, allow_nan=False) | st.integers(-6000, 6000) | edge
    row = st.lists(num, min_size=2, max_size=4) | st.tuples(num, num, num).map(list)
    d: dict[str, Any] = imu_dict(n)
    d["gyr_rad_s"] = draw(st.lists(row, min_size=n, max_size=n))
    if draw(st.booleans()):
        d["acc_m_s2"] = draw(st.lists(row, min_size=max(0, n - 1), max_size=n + 1))
    for name in ("temp_c", "battery_v", "rssi_dbm", "depth_m", "wall_t0_us", "rate_hz", "seq", "boot_id", "t0_us"):
        if draw(st.integers(0, 3)) == 0:
            d[name] = draw(num | st.integers(-(2**65), 2**65))
    if draw(st.booleans()):
        d["gnss"] = {"lat_deg": draw(num), "lon_deg": draw(num)}
        if draw(st.booleans()):
            d["gnss"]["fix_quality"] = draw(num)
    if draw(st.integers(0, 4)) == 0:
        d[draw(st.sampled_from(sorted(d) + ["extra", "mag_uT"]))] = draw(json_values)
    if draw(st.integers(0, 6)) == 0:
        d.pop(draw(st.sampled_from(sorted(d))))
    if draw(st.booleans()):
        d["mag_uT"] = None
    text = json.dumps(d)
    if draw(st.integers(0, 6)) == 0:  # a duplicate key: the last one counts for both parsers
        text = text[:-1] + f', "seq": {draw(num | st.integers(-5, 5))}' + "}"
    return text.encode()


def _outcome(key: str, payload: bytes, *, fast: bool) -> tuple[str, Any]:
    try:
        p = schemas.decode(key, payload, fast=fast)
    except schemas.DecodeError as e:
        return "reject", e.reason
    floats = [type(x).__name__ for row in getattr(p, "gyr_rad_s", []) for x in row]
    return "ok", (p, p.model_fields_set, p.to_json(), floats)


@settings(max_examples=400, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(imu_payloads(), st.sampled_from([IMU_KEY, "rig/hook/rod-1/imu", "rig/rod/rod-2/imu"]))
def test_fast_path_accepts_rejects_and_builds_exactly_like_pydantic(payload: bytes, key: str) -> None:
    assert _outcome(key, payload, fast=True) == _outcome(key, payload, fast=False)


@settings(max_examples=200, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.binary(max_size=200) | json_values.map(lambda v: json.dumps(v).encode()))
def test_fast_path_on_arbitrary_bytes_and_json(payload: bytes) -> None:
    assert _outcome(IMU_KEY, payload, fast=True) == _outcome(IMU_KEY, payload, fast=False)


def test_fast_path_takes_valid_packets_itself_and_leaves_the_rest_to_pydantic() -> None:
    """Without this the equivalence tests would also pass with a fast path that always gives up."""
    parsed = schemas.parse_key(IMU_KEY)
    fix = {"lat_deg": 30.27, "lon_deg": 120.15}
    for d in (imu_dict(), imu_dict(n=1, mag_uT=None), imu_dict(gnss=fix, depth_m=2.5, temp_c=20)):
        p = schemas._decode_imu_fast(parsed, json.dumps(d).encode())
        assert p is not None and p == schemas.decode(IMU_KEY, json.dumps(d).encode(), fast=False)
        assert p.arrays()[0].shape == (len(d["gyr_rad_s"]), 3)  # type: ignore[arg-type]
    assert schemas._decode_imu_fast(parsed, json.dumps(imu_dict(gnss=fix)).encode()).gnss == schemas.GnssFix(**fix)  # type: ignore[union-attr]
    for bad in (imu_dict(rate_hz=0.5), imu_dict(device_id="rod-2"), imu_dict(acc_m_s2=[[0, 0, 9.8]])):
        assert schemas._decode_imu_fast(parsed, json.dumps(bad).encode()) is None


# ---- binary IMU encoding (protocol v2) -------------------------------------------------------------------------

f32 = st.floats(width=32, allow_nan=True, allow_infinity=True)
near = st.sampled_from([0.0, 49.99, 50.0, 50.01, -400.0, 400.5, 4999.0, 5000.0, -5000.5, 9.81, math.nan, -math.inf])


@st.composite
def imu_contents(draw: st.DrawFn) -> dict[str, Any]:
    """Keyword arguments of `schemas.imu_binary`: valid float32 values, then maybe one sample value and one field
    moved near or across its limit (or to NaN/inf), maybe the key's kind or id changed."""
    n = draw(st.integers(1, 5))
    small = st.floats(-10, 10, width=32)

    def rows() -> list[list[float]]:
        return draw(st.lists(st.lists(small, min_size=3, max_size=3), min_size=n, max_size=n))

    def maybe(strategy: st.SearchStrategy[Any]) -> Any:
        return draw(st.none() | strategy)

    c: dict[str, Any] = {
        "device_id": "rod-1", "kind": "rod", "boot_id": draw(st.integers(0, 2**32 - 1)),
        "seq": draw(st.integers(0, 2**32 - 1)), "t0_us": draw(st.integers(0, 2**63 - 1)),
        "rate_hz": draw(st.sampled_from([100.0, 1.0, 2000.0, 50.5])), "gyr_rad_s": rows(), "acc_m_s2": rows(),
        "mag_uT": rows() if draw(st.booleans()) else None, "wall_t0_us": maybe(st.integers(0, 2**63 - 1)),
        "temp_c": maybe(st.floats(-60, 150, width=32)), "battery_v": maybe(st.floats(0, 60, width=32)),
        "rssi_dbm": maybe(st.floats(-150, 0, width=32)), "depth_m": maybe(st.floats(0, 1000, width=32)),
    }
    if draw(st.booleans()):
        arrays = [a for a in ("gyr_rad_s", "acc_m_s2", "mag_uT") if c[a] is not None]
        row = draw(st.sampled_from(c[draw(st.sampled_from(arrays))]))
        row[draw(st.integers(0, 2))] = draw(near | st.floats(width=32))
    if draw(st.integers(0, 3)) == 0:
        name = draw(st.sampled_from(["t0_us", "wall_t0_us", "rate_hz", "temp_c", "battery_v", "rssi_dbm", "depth_m"]))
        c[name] = draw(st.integers(-3, 0)) if name.endswith("_us") else draw(
            st.sampled_from([0.5, 2001.0, -61.0, 150.5, 60.5, 0.5, -150.5, 1000.5, -0.5, math.nan, math.inf])
            | st.floats(width=32))  # fmt: skip
    if draw(st.integers(0, 5)) == 0:
        c.update(draw(st.sampled_from([{"kind": "hook"}, {"device_id": "rod-2"}])))
    return c


def json_twin(c: dict[str, Any]) -> bytes:
    """The same packet as JSON, every float at its float32 value (what the binary encoding carries)."""
    d: dict[str, Any] = {"v": 1}
    for name, value in c.items():
        if value is None:
            continue
        if isinstance(value, list):
            value = [[float(np.float32(x)) for x in row] for row in value]
        elif isinstance(value, float) and name != "rate_hz":
            value = float(np.float32(value))
        d[name] = value
    return json.dumps(d).encode()  # NaN/Infinity tokens: pydantic's `non_finite`, like the binary check


@settings(max_examples=400, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(imu_contents())
def test_binary_decodes_like_its_json_twin(c: dict[str, Any]) -> None:
    """Same verdict, same reason, equal packets (values, fields set, JSON) as pydantic on the JSON twin."""
    binary = schemas.imu_binary(**c)
    assert binary[0] == schemas.IMU_BINARY_MAGIC
    assert _outcome(IMU_KEY, binary, fast=True) == _outcome(IMU_KEY, json_twin(c), fast=False)


_READS: dict[str, Any] = {
    "attribute": lambda p: (p.gyr_rad_s, p.acc_m_s2, p.mag_uT), "n": lambda p: p.n, "to_json": lambda p: p.to_json(),
    "model_dump": lambda p: p.model_dump(), "model_dump_json": lambda p: p.model_dump_json(exclude_none=True),
    "repr": repr, "dict": dict, "arrays": lambda p: [None if a is None else a.tolist() for a in p.arrays()],
    "pickle": lambda p: pickle.loads(pickle.dumps(p)).to_json(), "copy": lambda p: p.model_copy().model_dump(),
    "copy_rate": lambda p: p.model_copy(update={"rate_hz": 50.0}).model_dump(),
    "copy_samples": lambda p: p.model_copy(update={"gyr_rad_s": [(1.0, 2.0, 3.0)] * p.n}).model_dump(),
}


@settings(max_examples=100, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(imu_contents(), st.sampled_from(sorted(_READS)), st.booleans())
def test_a_binary_packet_reads_like_its_json_twin_before_its_samples_are_built(c: dict[str, Any], read: str,
                                                                               batch: bool) -> None:  # fmt: skip
    """A binary packet keeps its float32 rows and builds its sample tuples only when read: whatever reads it first
    (attribute, dumps, repr, dict(), equality, copies, pickle) sees what the JSON twin's packet gives."""
    binary = schemas.imu_binary(**c)
    try:
        twin = schemas.decode(IMU_KEY, json_twin(c), fast=False)
    except schemas.DecodeError:
        return  # rejected alike: test_binary_decodes_like_its_json_twin
    got = schemas.decode_many([(IMU_KEY, binary)])[0] if batch else schemas.decode(IMU_KEY, binary)
    assert isinstance(got, schemas.ImuPacket) and "gyr_rad_s" not in got.__dict__  # not built yet
    assert _READS[read](got) == _READS[read](twin)
    fresh = schemas.decode(IMU_KEY, binary)
    assert fresh == twin and twin == schemas.decode(IMU_KEY, binary)
    assert schemas.sample_rows(got) is not None and schemas.sample_rows(twin) is None
    if read == "copy_samples":
        assert schemas.sample_rows(got.model_copy(update={"gyr_rad_s": [(1.0, 2.0, 3.0)] * got.n})) is None


@settings(max_examples=300, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(imu_contents(), st.data())
def test_binary_hostile_bytes_only_raise_decode_error(c: dict[str, Any], data: st.DataObject) -> None:
    """Flip, cut or extend a valid binary packet anywhere: decode returns or raises DecodeError, nothing else."""
    b = bytearray(schemas.imu_binary(**c))
    i = data.draw(st.integers(0, len(b) - 1))
    how = data.draw(st.sampled_from(["flip", "cut", "extend"]))
    if how == "flip":
        b[i] ^= data.draw(st.integers(1, 255))
    elif how == "cut":
        del b[i:]
    else:
        b += data.draw(st.binary(min_size=1, max_size=8))
    if b[:1] != bytes([schemas.IMU_BINARY_MAGIC]):
        return
    try:
        p = schemas.decode(IMU_KEY, bytes(b))
    except schemas.DecodeError as e:
        assert e.reason in schemas.REASONS
    else:
        assert schemas.decode(IMU_KEY, p.to_json()) == p  # type: ignore[union-attr]


def test_binary_layout_is_the_documented_one() -> None:
    """docs/protocol.md section 3.6: a 56-byte little-endian header, the id, then float32 rows; 2.4x fewer bytes."""
    key, example = protocol_doc.examples()["imu_rod"]
    assert isinstance(example, schemas.ImuPacket)
    p = example.model_copy(update={"gnss": None})
    b = schemas.imu_to_binary(p)
    assert len(b) == 56 + len("rod-1") + 2 * 9 * 4
    assert b[:4] == bytes([0xB2, 0b011111, 0, 5]) and b[4:6] == (2).to_bytes(2, "little")
    assert int.from_bytes(b[12:16], "little") == 1042 and b[56:61] == b"rod-1"
    assert np.frombuffer(b, "<f4", offset=61)[3] == np.float32(5.312)  # acc x of sample 0
    assert schemas.decode(key, b) == schemas.decode(key, json_twin({
        k: getattr(p, k) for k in ("device_id", "kind", "boot_id", "seq", "t0_us", "rate_hz", "wall_t0_us",
                                   "temp_c", "battery_v", "rssi_dbm")} | {  # fmt: skip
        "gyr_rad_s": [list(r) for r in p.gyr_rad_s], "acc_m_s2": [list(r) for r in p.acc_m_s2],
        "mag_uT": [list(r) for r in p.mag_uT or []]}))
    with pytest.raises(ValueError):
        schemas.imu_to_binary(example)  # a GNSS fix goes as JSON


def test_every_topic_with_a_payload_has_an_example_in_the_doc() -> None:
    """A new kind's topic row without an example would reach docs/protocol.md without a payload to copy."""
    examples = protocol_doc.examples().values()
    for t in schemas.TOPICS:
        if t.model is not None:
            assert any(type(m) is t.model and key_matches(schemas.selector(t), key) for key, m in examples), t.name


@pytest.mark.parametrize(("field", "limit"), [
    ("gyr_rad_s", schemas.GYR_LIMIT_RAD_S), ("acc_m_s2", schemas.ACC_LIMIT_M_S2), ("mag_uT", schemas.MAG_LIMIT_UT)])
def test_binary_limits_are_the_models_to_the_last_float32(field: str, limit: float) -> None:
    """At the limit: accepted; one float32 step beyond, either sign: out_of_range; NaN: non_finite (as JSON)."""
    beyond = float(np.nextafter(np.float32(limit), np.float32(np.inf)))
    for value, want in ((limit, "ok"), (-limit, "ok"), (beyond, "out_of_range"), (-beyond, "out_of_range"),
                        (math.nan, "non_finite")):  # fmt: skip
        rows = [[0.0, 0.0, 1.0], [0.0, 0.0, 1.0]]
        rows[1][2] = value
        c: dict[str, Any] = {"device_id": "rod-1", "kind": "rod", "boot_id": 1, "seq": 2, "t0_us": 3, "rate_hz": 100.0,
                             "gyr_rad_s": [[0.0] * 3] * 2, "acc_m_s2": [[0.0] * 3] * 2, "mag_uT": [[0.0] * 3] * 2}
        c[field] = rows
        got, twin = _outcome(IMU_KEY, schemas.imu_binary(**c), fast=True), _outcome(IMU_KEY, json_twin(c), fast=False)
        assert got == twin and (got[0] == "ok" if want == "ok" else got[1] == want), (value, got)


def _verdict(p: object) -> tuple[str, Any]:
    if isinstance(p, schemas.DecodeError):
        return "reject", (p.reason, str(p))
    assert isinstance(p, schemas.ImuPacket | schemas.EnvPacket | schemas.ReelStatus)
    keys = tuple(p.__dict__)  # before a read builds the samples: the order the decoder left
    rows = schemas.sample_rows(p) if isinstance(p, schemas.ImuPacket) else None
    floats = [type(x).__name__ for row in getattr(p, "gyr_rad_s", []) for x in row]
    kept = None if rows is None else (rows.dtype.str, rows.shape, rows.tobytes())
    return "ok", (p, keys, p.model_fields_set, p.to_json(), floats, kept)


@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(st.lists(st.tuples(imu_contents(), st.sampled_from(["binary", "binary", "json", "flip", "flip_head", "cut"]),
                          st.sampled_from([IMU_KEY, IMU_KEY, "rig/hook/rod-1/imu", "rig/rod/rod-1/env", "x/y"]),
                          st.integers(0, 10**6)), min_size=1, max_size=30))  # fmt: skip
def test_decode_many_gives_what_decode_gives_each(items: list[tuple[dict[str, Any], str, str, int]]) -> None:
    """A batch of binary (valid, out of range, damaged anywhere or in the header), JSON and misaddressed packets:
    `decode_many` (headers and rows checked and converted for the whole batch, the rest decoded alone) returns, in
    order, the packet (values, field order, rows) or the error (reason and detail) that `decode` gives each one
    alone."""
    batch = []
    for c, how, key, pos in items:
        b = bytearray(schemas.imu_binary(**c)) if how != "json" else bytearray(json_twin(c))
        if how == "flip":
            b[pos % len(b)] ^= 0x5A
        elif how == "flip_head":  # flags, kind, id length, n, reserved, ..., the scalars; not the magic byte
            b[1 + pos % (schemas.IMU_BINARY_HEADER.size - 1)] ^= 1 << (pos % 8)
        elif how == "cut":
            del b[pos % len(b):]
        batch.append((key, bytes(b)))
    got = [_verdict(p) for p in schemas.decode_many(batch)]
    alone = []
    for key, payload in batch:
        try:
            alone.append(_verdict(schemas.decode(key, payload)))
        except schemas.DecodeError as e:
            alone.append(_verdict(e))
    assert got == alone
