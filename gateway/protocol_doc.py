"""docs/protocol.md's generated parts: the key table, the field tables and the example payloads.

    python -m gateway.protocol_doc --write-doc docs/protocol.md     (or: python -m gateway.schemas --write-doc ...)

Everything here is derived from `gateway.schemas` (its `TOPICS` table and models); the gateway never imports it at
run time. `examples()` are exact, valid payloads of every topic, used by the doc and by tests.
"""

from __future__ import annotations

import inspect
import json
import math
import typing
from pathlib import Path
from typing import Any, Final

from gateway.schemas import (
    DEVICE_ID_PATTERN,
    DIAG_INGEST_KEY,
    DIAG_REJECTED_KEY,
    DIRECTION_TEXT,
    ENCODING_GW,
    ENCODING_IMU_BINARY,
    KINDS,
    SEL_DEVICE_DATA,
    SEL_DEVICE_TOKENS,
    SEL_TRUTH,
    SPOTS_KEY,
    T_ATTITUDES,
    TOPICS,
    AlarmEvent,
    Attitude,
    AttitudeBatch,
    AttitudeBlock,
    BallCommand,
    BallTruth,
    CraneMotion,
    DeviceConfig,
    DeviceIngestCounters,
    EnvPacket,
    GnssFix,
    Height,
    HookTruth,
    ImuPacket,
    IngestStats,
    ProfilePoint,
    ReelCommand,
    ReelStatus,
    RejectedPacket,
    RodTruth,
    SpotRanking,
    SpotScore,
    Swing,
    Topic,
    TruthEvent,
    WireModel,
    alarm_key,
    attitude_block_key,
    attitude_key,
    ball_cmd_key,
    config_key,
    crane_key,
    encoding_of,
    env_key,
    height_key,
    imu_key,
    imu_to_binary,
    reel_cmd_key,
    reel_key,
    swing_key,
    truth_key,
)

# ---------------------------------------------------------------------------------------------------------------
# Examples (exact payloads for docs/protocol.md and tests)
# ---------------------------------------------------------------------------------------------------------------


def examples() -> dict[str, tuple[str, WireModel]]:
    """name -> (key, model): one valid, deterministic example of every payload."""
    wall = 1_767_225_600_000_000  # 2026-01-01T00:00:00Z in unix µs
    q = (0.9537, -0.0, 0.1624, 0.2532)
    qn = math.sqrt(sum(c * c for c in q))
    quat = (round(q[0] / qn, 6), 0.0, round(q[2] / qn, 6), round(q[3] / qn, 6))
    imu = ImuPacket(
        v=1, device_id="rod-1", kind="rod", boot_id=2_882_400_001, seq=1042, t0_us=10_420_000, rate_hz=100.0,
        gyr_rad_s=[(0.0012, -0.0031, 0.0004), (0.0015, -0.0029, 0.0002)],
        acc_m_s2=[(5.312, 0.021, 8.247), (5.309, 0.018, 8.251)],
        mag_uT=[(-14.3, 18.1, -39.2), (-14.2, 18.0, -39.3)],
        temp_c=24.5, battery_v=4.08, rssi_dbm=-61.0, wall_t0_us=wall + 10_420_000,
        gnss=GnssFix(lat_deg=30.2741, lon_deg=120.1551, alt_m=7.5, speed_m_s=0.0, fix_quality=1),
    )
    hook_imu = ImuPacket(
        v=1, device_id="hook-1", kind="hook", boot_id=99, seq=7, t0_us=70_000, rate_hz=100.0,
        gyr_rad_s=[(0.0, 0.0, 0.0)], acc_m_s2=[(0.0, 0.0, 9.81)],
    )
    plain_imu = ImuPacket(
        v=1, device_id="imu-1", kind="imu", boot_id=3, seq=41, t0_us=5_000_000, rate_hz=200.0,
        gyr_rad_s=[(0.012, -0.004, 0.35), (0.011, -0.003, 0.36)], acc_m_s2=[(0.21, -0.05, 9.79), (0.2, -0.06, 9.8)],
        mag_uT=[(22.1, 1.3, -40.2), (22.0, 1.4, -40.1)], wall_t0_us=wall + 5_000_000,
    )
    env = EnvPacket(
        v=1, device_id="ball-1", boot_id=5, seq=12, t_us=12_000_000, wall_t_us=wall + 12_000_000, spot="deep_hole",
        air_temp_c=14.2, humidity_pct=81.5, light_lux=1520.0, water_temp_c=17.8, oxygen_mg_l=7.95,
        probe_depth_m=6.0, bottom_depth_m=12.0,
        profile=[ProfilePoint(depth_m=0.0, water_temp_c=19.9, oxygen_mg_l=8.9),
                 ProfilePoint(depth_m=6.0, water_temp_c=10.1, oxygen_mg_l=1.2)],
        battery_v=3.9, rssi_dbm=-70.0, gnss=GnssFix(lat_deg=30.2746, lon_deg=120.1559, fix_quality=1),
    )
    reel = ReelStatus(
        v=1, device_id="rod-1", boot_id=2_882_400_001, seq=208, t_us=10_420_000, wall_t_us=wall + 10_420_000,
        line_out_m=27.4, line_in_speed_m_s=0.48, motor="reeling_in", mode="in", cmd_speed_m_s=0.5, drag_n=25.0,
        tension_n=6.2, last_cmd_id=17,
    )
    crane = CraneMotion(
        v=1, device_id="hook-1", boot_id=7, seq=311, wall_t0_us=wall + 31_100_000, rate_hz=10.0,
        tip_acc_m_s2=[(0.212, -0.105), (0.208, -0.111)],
    )
    rod_truth = RodTruth(
        v=1, device_id="rod-1", boot_id=2_882_400_001, seq=1042, t0_us=10_420_000, rate_hz=100.0,
        wall_t0_us=wall + 10_420_000,
        events=[TruthEvent(label="bite", phase="start", t_us=10_415_000, value=0.349066)],
        quat_wxyz=[quat, quat], tension_n=[1.2, 1.6], breaking_strength_n=40.0, line_out_m=30.0,
        fish_state="nibbling", rest_pitch_rad=0.541,
    )
    hook_truth = HookTruth(
        v=1, device_id="hook-1", boot_id=99, seq=7, t0_us=70_000, rate_hz=100.0,
        quat_wxyz=[(1.0, 0.0, 0.0, 0.0)], swing_angle_rad=[0.0], swing_direction_rad=[0.0], torsion_rad=[0.0],
        rope_length_m=8.0, load_kg=1200.0,
    )
    ball_truth = BallTruth(
        v=1, device_id="ball-1", boot_id=5, seq=12, t_us=12_000_000, wall_t_us=wall + 12_000_000,
        spot="deep_hole", air_temp_c=14.25, water_temp_c=17.81, oxygen_mg_l=7.91, light_lux=1500.0,
        humidity_pct=81.0, sim_hour_of_day=6.2,
        events=[TruthEvent(label="rethrow", phase="instant", t_us=11_000_000)],
    )
    reel_cmd = ReelCommand(v=1, cmd_id=17, action="in", speed_m_s=0.5, sent_wall_us=wall + 10_300_000,
                           sender="gateway")
    ball_cmd = BallCommand(v=1, cmd_id=3, action="rethrow", spot="inlet", sent_wall_us=wall + 11_900_000)
    att = Attitude(
        device_id="rod-1", kind="rod", seq=1042, t_us=10_430_000, wall_t_us=wall + 10_436_000, quat_wxyz=quat,
        roll_rad=0.0012, pitch_rad=0.3316, yaw_rad=0.5236, yaw_unwrapped_rad=6.8068, filter="default",
    )
    att_block = AttitudeBlock(
        device_id="rod-1", kind="rod", boot_id=2_882_400_001, seq=1042, t0_us=10_420_000, rate_hz=100.0,
        wall_t0_us=wall + 10_420_000, quat_wxyz=[quat, quat], filter="default",
    )
    height = Height(device_id="hook-1", kind="hook", seq=7, t_us=80_000, wall_t_us=wall + 86_000, vz_m_s=-0.12,
                    height_m=1.84, at_rest=False, aided="rest")
    swing = Swing(device_id="hook-1", seq=7, t_us=80_000, wall_t_us=wall + 86_000, swing_angle_rad=0.087,
                  swing_direction_rad=1.2, torsion_rad=0.15, swing_phi_rad=0.6764, rest_heading_rad=0.5236,
                  rope_length_m=9.87, torsion_std_rad=0.0157)  # the worked example of section 3.5
    alarm = AlarmEvent(
        alarm_id="3f2b9c0d5e8a4b7c9d1e2f3a4b5c6d7e", device_id="rod-1", kind="rod", alarm="bite", state="raised",
        severity="major", t_us=10_425_000, wall_t_us=wall + 10_436_000, source_wall_us=wall + 10_425_000, value=-12.0,
        threshold=-10.0, message="bite: pitch 12.0° below rest ≥ θ1 10.0°",
    )
    spots = SpotRanking(wall_t_us=wall + 12_100_000, spots=[
        SpotScore(spot="inlet", rank=1, score=0.82, device_id="ball-2", last_seen_wall_us=wall + 12_000_000,
                  reasons=["oxygen 9.1 mg/L", "water 16 °C"], lat_deg=30.2751, lon_deg=120.1548),
        SpotScore(spot="deep_hole", rank=2, score=0.41, device_id="ball-1", last_seen_wall_us=wall + 12_000_000,
                  reasons=["low oxygen at probe depth"]),
    ])
    ingest = IngestStats(
        wall_t_us=wall + 12_000_000, received=125_000, queue_drops=0, rejected={"schema": 2, "unknown_key": 1},
        devices=[DeviceIngestCounters(device_id="rod-1", kind="rod", ok=24_990, lost=8, duplicates=1,
                                      reordered=2, reboots=0, rejected={"schema": 2})],
    )
    rejected = RejectedPacket(wall_t_us=wall + 12_000_000, key="rig/rod/rod-1/imu", reason="schema",
                              detail="acc_m_s2: acc_m_s2 has 9 samples, expected 10", size_bytes=612)
    config = DeviceConfig(device_id="rod-1", kind="rod", thresholds={"bite_deviation_deg": 10.0, "sensitivity": 3.0,
                                                                   "line_switch_deg": 20.0})
    return {
        "imu_rod": (imu_key("rod", "rod-1"), imu),
        "imu_hook_minimal": (imu_key("hook", "hook-1"), hook_imu),
        "imu_plain": (imu_key("imu", "imu-1"), plain_imu),
        "env": (env_key("ball-1"), env),
        "reel_status": (reel_key("rod-1"), reel),
        "crane": (crane_key("hook-1"), crane),
        "rod_truth": (truth_key("rod", "rod-1"), rod_truth),
        "hook_truth": (truth_key("hook", "hook-1"), hook_truth),
        "ball_truth": (truth_key("ball", "ball-1"), ball_truth),
        "reel_cmd": (reel_cmd_key("rod-1"), reel_cmd),
        "ball_cmd": (ball_cmd_key("ball-1"), ball_cmd),
        "attitude": (attitude_key("rod", "rod-1"), att),
        "attitudes": (T_ATTITUDES.key(), AttitudeBatch(wall_t_us=wall + 10_437_000, attitudes=[
            att, Attitude(device_id="hook-1", kind="hook", seq=7, t_us=80_000, wall_t_us=wall + 86_000,
                          quat_wxyz=(0.998, 0.0436, 0.0, 0.0436), roll_rad=0.0873, pitch_rad=-0.0038, yaw_rad=0.0873,
                          yaw_unwrapped_rad=0.0873, filter="hook")])),
        "attitude_block": (attitude_block_key("rod", "rod-1"), att_block),
        "height": (height_key("hook", "hook-1"), height),
        "swing": (swing_key("hook-1"), swing),
        "alarm": (alarm_key("rod", "rod-1"), alarm),
        "spots": (SPOTS_KEY, spots),
        "diag_ingest": (DIAG_INGEST_KEY, ingest),
        "diag_rejected": (DIAG_REJECTED_KEY, rejected),
        "config": (config_key("rod", "rod-1"), config),
    }


FIELD_NOTES: Final[dict[str, str]] = {
    "v": "protocol version, always 1 in this version",
    "device_id": "must equal the `{id}` chunk of the key; " + DEVICE_ID_PATTERN,
    "kind": "must equal the `{kind}` chunk of the key",
    "boot_id": "random at each device start; a new value restarts sequence tracking",
    "seq": "+1 per packet on this key, wraps 4294967295 -> 0",
    "t0_us": "device monotonic clock (µs) of sample 0; sample i at t0_us + i·1e6/rate_hz",
    "t_us": "device monotonic clock, µs",
    "rate_hz": "sample rate of the arrays",
    "gyr_rad_s": "angular rate, body frame, rad/s: n rows of [x, y, z]",
    "acc_m_s2": "specific force, body frame, m/s² (reads +9.81 on z when level): n rows of [x, y, z]",
    "mag_uT": "magnetic field, body frame, µT, n rows; absent = 6-axis IMU",
    "quat_wxyz": "unit quaternion body -> ENU, scalar first (|q| = 1 ± 1e-3)",
    "wall_t0_us": "device realtime clock (unix µs) of sample 0, if synchronised",
    "wall_t_us": "realtime clock, unix µs",
    "sent_wall_us": "sender's realtime clock when sent, unix µs",
    "events": "ground-truth labels: {label, phase start|end|instant, t_us (device clock), value?}",
    "profile": "water column measured while the probe sank (first packet after a throw)",
    "line_in_speed_m_s": "> 0 line coming in, < 0 going out",
    "cmd_speed_m_s": "motor line-in speed currently commanded",
    "speed_m_s": "in/out: magnitude (absent = reel default); speed: signed, > 0 reels in",
    "last_cmd_id": "cmd_id of the last ReelCommand applied (acknowledgement)",
    "source_wall_us": "device realtime clock (unix µs) of the sample that triggered the alarm; absent without one",
    "alarm_id": "the gateway's alarm id (REST `/api/alarms` `id`, ack with `POST /api/alarms/{alarm_id}/ack`)",
    "severity": "most severe first: critical, major, minor, warning, indeterminate (alarm engine levels)",
    "yaw_unwrapped_rad": "yaw without the ±π jumps",
    "filter_restarts": "fusion restarted from a fresh warm-up, by reason: the filter's exception class (e.g. "
                       "`LinAlgError`) or `non_finite` (it returned NaN/inf)",
    "swing_direction_rad": "bearing of the hook's horizontal displacement, counter-clockwise from East",
    "gnss": "GNSS fix at sample 0 (ImuPacket) or at the reading (EnvPacket: where the ball lies); absent without a "
            "receiver",
    "lat_deg": "WGS-84 latitude, degrees north",
    "lon_deg": "WGS-84 longitude, degrees east",
    "alt_m": "altitude above mean sea level, m",
    "fix_quality": "NMEA GGA fix quality: 0 invalid, 1 GNSS, 2 differential, 4 RTK fixed, 5 RTK float, 6 estimated",
    "depth_m": "pressure depth below the water surface at sample 0, m; absent without a depth sensor",
    "vz_m_s": "vertical velocity, ENU up, m/s",
    "height_m": "height above the device's first rest position (ENU up), m; minus the depth when depth-aided",
    "at_rest": "the rest detector holds the device still (velocity zeroed)",
    "aided": "what held the drift on this sample: rest detection, the depth sensor, the high-pass of a device free-"
             "running for 10 s (heave about the last rest height), or nothing yet (free integration)",
}

# Notes that differ from FIELD_NOTES for one model: (model name, field) -> note.
MODEL_FIELD_NOTES: Final[dict[tuple[str, str], str]] = {
    ("AttitudeBlock", "wall_t0_us"): "sample 0 on the realtime clock (unix µs): the packet's `wall_t0_us`, else "
                                     "mapped from the gateway's arrival time (as `Attitude.wall_t_us`)",
    ("AttitudeBlock", "quat_wxyz"): "n unit quaternions body -> ENU, scalar first, one per sample of the packet",
    ("AlarmEvent", "t_us"): "device monotonic clock (µs) of the sample that raised, updated or cleared the alarm",
    ("AlarmEvent", "wall_t_us"): "gateway realtime clock (unix µs) when the event was published",
    ("GnssFix", "speed_m_s"): "ground speed, m/s",
    ("SpotScore", "lat_deg"): "where the spot's ball last reported its GNSS fix (WGS-84), absent without one",
    ("SpotScore", "lon_deg"): "as `lat_deg`",
    ("Height", "t_us"): "device monotonic clock (µs) of the sample",
    ("Swing", "swing_angle_rad"): "Θ ∈ [0, π/2): angle between the rope and the vertical (section 3.5)",
    ("Swing", "swing_direction_rad"): "displacement bearing ∈ (-π, π]: direction of the hook's horizontal "
                                      "displacement from below the boom tip, CCW from East in the heading frame; "
                                      "0 when Θ = 0 (section 3.5)",
    ("Swing", "torsion_rad"): "φ ∈ (-π, π]: twist about the rope from the rest heading, right-handed about the rope "
                              "(CCW seen from above); 0 = body x at the rest heading (section 3.5)",
    ("Swing", "swing_phi_rad"): "paper 001 eq. 7 Φ ∈ [-π/2, π/2] relative to the rest heading ψ: sin Φ = sin θy / "
                                "sin Θ; the bearing is ψ + Φ or ψ + π - Φ (section 3.5); absent from old gateways",
    ("Swing", "rest_heading_rad"): "ψ: the rest heading torsion and Φ are taken from, CCW from East in the heading "
                                   "frame (configured `rest_heading_deg`, else the first fused heading)",
    ("Swing", "rope_length_m"): "the hook filter's estimate of the pendulum length (boom tip to the hook and load's "
                                "centre), m; absent with other filters",
    ("Swing", "provisional"): "true while the hook filter may still start again told the rope length it finds (a "
                              "hook not told its rope, swinging at start: its first 2-15 s, section 3.5): the angles "
                              "can be several degrees off and the hook's alarms wait; absent otherwise",
    ("Swing", "torsion_std_rad"): "1σ of `torsion_rad` as the hook filter holds it at the end of the packets it fused "
                                  "with this one (its covariance and a 0.5° floor; tens of degrees while an "
                                  "uncalibrated compass's hard iron is still being learnt), sent with a configured "
                                  "rest heading only: torsion from the first fused heading is a twist since then, "
                                  "which that covariance does not hold (section 3.5)",
    ("HookTruth", "swing_direction_rad"): "bearing of the hook's horizontal displacement, CCW from East (ENU)",
}


def _type_of(prop: dict[str, Any], defs: dict[str, Any]) -> str:
    if "$ref" in prop:
        return str(prop["$ref"]).split("/")[-1]
    if "anyOf" in prop:
        return " or ".join(_type_of(p, defs) for p in prop["anyOf"] if p.get("type") != "null")
    if "const" in prop:
        return json.dumps(prop["const"])
    if "enum" in prop:
        return " \\| ".join(json.dumps(e) for e in prop["enum"])
    t = str(prop.get("type", "any"))
    if t == "array":
        if "prefixItems" in prop:
            inner = _type_of(prop["prefixItems"][0], defs)
            return f"[{inner} ×{len(prop['prefixItems'])}]"
        n = f"{prop.get('minItems', 0)}..{prop.get('maxItems', '∞')}"
        return f"array({n}) of {_type_of(prop.get('items', {}), defs)}"
    if t == "object":
        return f"object of {_type_of(prop.get('additionalProperties', {}), defs)}"
    rng = []
    if "minimum" in prop or "exclusiveMinimum" in prop:
        rng.append(f"≥ {prop['minimum']}" if "minimum" in prop else f"> {prop['exclusiveMinimum']}")
    if "maximum" in prop or "exclusiveMaximum" in prop:
        rng.append(f"≤ {prop['maximum']}" if "maximum" in prop else f"< {prop['exclusiveMaximum']}")
    if "maxLength" in prop:
        rng.append(f"len {prop.get('minLength', 0)}..{prop['maxLength']}")
    return t + (f" ({', '.join(rng)})" if rng else "")


def fields_markdown(model: type[WireModel]) -> str:
    """A markdown table of the model's fields: name, JSON type with ranges, required, notes."""
    schema = model.model_json_schema()
    defs = schema.get("$defs", {})
    required = set(schema.get("required", []))
    rows = ["| field | JSON type (range) | required | notes |", "|---|---|---|---|"]
    for name, prop in schema["properties"].items():
        req = "yes" if name in required else f"no (default {json.dumps(prop.get('default'))})"
        note = MODEL_FIELD_NOTES.get((model.__name__, name), FIELD_NOTES.get(name, ""))
        rows.append(f"| `{name}` | {_type_of(prop, defs)} | {req} | {note} |")
    return "\n".join(rows)


_FIELDS_BEGIN = "<!-- fields:begin (generated) -->"
_FIELDS_END = "<!-- fields:end -->"


def _doc_models() -> tuple[type[WireModel], ...]:
    """Every payload model in `TOPICS` order, each followed by the models nested in it (GnssFix after ImuPacket)."""
    out: list[type[WireModel]] = []

    def add(model: type[WireModel]) -> None:
        if model in out:
            return
        out.append(model)
        for info in model.model_fields.values():
            for arg in _flat_args(info.annotation):
                if isinstance(arg, type) and issubclass(arg, WireModel):
                    add(arg)

    for t in TOPICS:
        if t.model is not None:
            add(t.model)
    return tuple(out)


def _flat_args(tp: Any) -> list[Any]:
    args = typing.get_args(tp)
    return [tp] if not args else [a for x in args for a in _flat_args(x)]


DOC_MODELS: Final[tuple[type[WireModel], ...]] = _doc_models()


def all_fields_markdown() -> str:
    """Field tables of every wire model."""
    return "\n\n".join(f"#### {m.__name__}\n\n{inspect.cleandoc(m.__doc__ or '')}\n\n{fields_markdown(m)}"
                         for m in DOC_MODELS)


_EXAMPLES_BEGIN = "<!-- examples:begin (generated by `python -m gateway.schemas --write-doc docs/protocol.md`) -->"
_EXAMPLES_END = "<!-- examples:end -->"


def example_json(model: WireModel) -> str:
    """The model's wire JSON laid out one top-level field per line (what docs/protocol.md shows)."""
    d = json.loads(model.to_json())
    lines = [f"  {json.dumps(k)}: {json.dumps(v, ensure_ascii=False)}" for k, v in d.items()]
    return "{\n" + ",\n".join(lines) + "\n}"


def examples_markdown() -> str:
    """Markdown blocks 'Key: `...`' + JSON for every example (keys in model order)."""
    parts = []
    for name, (key, model) in examples().items():
        body = example_json(model)
        enc = encoding_of(type(model))
        parts.append(f"#### {name}\n\nKey: `{key}` — encoding `{enc}`\n\n```json\n{body}\n```\n")
    key, imu = examples()["imu_rod"]
    assert isinstance(imu, ImuPacket)
    b = imu_to_binary(imu.model_copy(update={"gnss": None}))
    rows = [b[i:i + 16].hex(" ") for i in range(0, len(b), 16)]
    parts.append(f"#### imu_rod_binary\n\nThe `imu_rod` packet without its `gnss` fix in the binary encoding "
                 f"(section 3.6), {len(b)} bytes, hex — encoding `{ENCODING_IMU_BINARY}`\n\n```text\n"
                 + "\n".join(rows) + "\n```\n")
    return "\n".join(parts)


_KEYS_BEGIN = "<!-- keys:begin (generated from gateway.schemas.TOPICS) -->"
_KEYS_END = "<!-- keys:end -->"


def _key_text(t: Topic) -> str:
    if "{kind}" not in t.pattern or set(t.kinds) == set(KINDS):
        return f"`{t.pattern}`"
    return ", ".join(f"`{t.pattern.replace('{kind}', k)}`" for k in t.kinds)


def keys_markdown() -> str:
    """The key table of docs/protocol.md section 2, one row per `TOPICS` entry."""
    rows = ["| key | payload | from → to | QoS |", "|---|---|---|---|"]
    for t in TOPICS:
        if t.model is None:
            payload = t.note
        else:
            enc = t.encoding.rsplit("schema=", 1)[-1]
            extra = "; ".join(x for x in (f"`{enc}`" if t.encoding != ENCODING_GW else "", t.note) if x)
            payload = t.model.__name__ + (f" ({extra})" if extra else "")
        if t.direction == "queryable":
            payload = f"**queryable**: replies {payload}"
        qos = "—" if t.direction in ("token", "queryable") else "**BLOCK**" if t.block else "DROP"
        rows.append(f"| {_key_text(t)} | {payload} | {DIRECTION_TEXT[t.direction]} | {qos} |")
    sel = ", ".join(f"`{s}`" for s in SEL_DEVICE_DATA)
    rows.append("")
    rows.append(f"Selectors for subscribers: all device data {sel}; truth `{SEL_TRUTH}`; presence "
                f"`{SEL_DEVICE_TOKENS}` on the liveliness API. Note that `rig/**` also matches the command keys.")
    return "\n".join(rows)


def write_doc(path: str) -> None:
    """Replace the generated examples section of the protocol document in place."""
    p = Path(path)
    text = p.read_text()
    for begin, end, body in ((_KEYS_BEGIN, _KEYS_END, keys_markdown()),
                             (_EXAMPLES_BEGIN, _EXAMPLES_END, examples_markdown()),
                             (_FIELDS_BEGIN, _FIELDS_END, all_fields_markdown())):
        i, j = text.index(begin), text.index(end)
        text = text[: i + len(begin)] + "\n\n" + body + "\n" + text[j:]
    p.write_text(text)


def main(argv: list[str] | None = None) -> int:
    import argparse

    parser = argparse.ArgumentParser(prog="python -m gateway.schemas", description="Wire protocol doc.")
    parser.add_argument("--write-doc", metavar="PATH",
                        help="regenerate the key table, field tables and examples of this markdown file")
    args = parser.parse_args(argv)
    if args.write_doc:
        write_doc(args.write_doc)
    else:
        print(examples_markdown())
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
