"""`gw/attitudes` (schemas.AttitudeBatch): one message per ingest batch holding the newest attitude of every device,
entry for entry what the per-device keys carry, split at `ATTITUDES_PER_MESSAGE`, DROP, published only while someone
subscribes; and through real zenoh, a subscriber in another process sees every device of a running gateway in it."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from gateway import schemas
from gateway.hub import Hub
from gateway.ingest.bus import MemoryBus
from gateway.pipeline import Output

REPO = Path(__file__).resolve().parents[2]
_finite = st.floats(-6.0, 6.0, allow_nan=False)
_unit = st.floats(-1.0, 1.0, allow_nan=False)


def attitude(device_id: str, seq: int, pitch_rad: float = 0.1, wall: int | None = 10**15) -> schemas.Attitude:
    return schemas.Attitude(device_id=device_id, kind="hook" if device_id.startswith("hook") else "rod", seq=seq,
                            t_us=1000 * seq, wall_t_us=None if wall is None else wall + seq,
                            quat_wxyz=(1.0, 0.0, 0.0, 0.0), roll_rad=0.0, pitch_rad=pitch_rad, yaw_rad=0.0,
                            yaw_unwrapped_rad=0.0, filter="default")  # fmt: skip


class _Bus(MemoryBus):
    """A memory bus whose subscribers are only the keys in `taken` (zenoh's matching status)."""

    def __init__(self, taken: set[str]) -> None:
        super().__init__()
        self.taken = taken

    def subscribed(self, key: str, *, encoding: str, block: bool = False, express: bool = False) -> bool:
        return key in self.taken


def sent(bus: MemoryBus, key: str) -> list[bytes]:
    return [payload for k, payload, _ in bus.sent if k == key]


def test_one_message_per_batch_holds_what_each_device_key_got() -> None:
    """rod-1 twice in the batch: its newest only, as on its own key; DROP, as the per-device attitude (a slow fleet
    app must not hold up the alarms' BLOCK puts); the bytes are pydantic's dump."""
    bus = MemoryBus()
    hub = Hub(bus, writer=None, clock=lambda: 1_700_000_000.25)  # type: ignore[arg-type]  # no alarms: no writer
    atts = [attitude("rod-1", 1), attitude("hook-2", 1, wall=None), attitude("rod-1", 2, 0.3)]
    hub.emit(Output(attitudes=atts))
    (payload,) = sent(bus, "gw/attitudes")
    batch = schemas.AttitudeBatch.model_validate_json(payload)
    assert batch.wall_t_us == 1_700_000_000_250_000
    assert [a.device_id for a in batch.attitudes] == ["hook-2", "rod-1"]
    per_device = sent(bus, "gw/rod/rod-1/attitude") + sent(bus, "gw/hook/hook-2/attitude")
    assert sorted(a.to_json() for a in batch.attitudes) == sorted(per_device)
    assert payload == batch.model_dump_json(exclude_none=True).encode()
    assert not any(block for k, _, block in bus.sent if k == "gw/attitudes")
    hub.emit(Output())  # no attitudes: no batch message
    assert len(sent(bus, "gw/attitudes")) == 1


def test_a_large_batch_is_split_and_nothing_is_published_without_a_subscriber() -> None:
    n = 2 * schemas.ATTITUDES_PER_MESSAGE + 7
    atts = [attitude(f"rod-{i}", 5) for i in range(n)]
    bus = _Bus({"gw/attitudes"})
    Hub(bus, writer=None).emit(Output(attitudes=atts))  # type: ignore[arg-type]
    parts = [schemas.AttitudeBatch.model_validate_json(p) for p in sent(bus, "gw/attitudes")]
    assert [len(p.attitudes) for p in parts] == [schemas.ATTITUDES_PER_MESSAGE] * 2 + [7]
    assert [a.device_id for p in parts for a in p.attitudes] == [a.device_id for a in atts]
    assert not any(k.endswith("/attitude") for k, _, _ in bus.sent), "per-device keys have no subscriber here"
    quiet = _Bus({"gw/rod/rod-1/attitude"})
    Hub(quiet, writer=None).emit(Output(attitudes=atts))  # type: ignore[arg-type]
    assert sent(quiet, "gw/attitudes") == [] and len(sent(quiet, "gw/rod/rod-1/attitude")) == 1


@settings(max_examples=60, deadline=None)
@given(st.lists(st.tuples(st.integers(0, 2**32 - 1), st.integers(0, 2**62), _finite, st.floats(-1e18, 1e18),
                          st.lists(_unit, min_size=4, max_size=4), st.booleans()), min_size=1, max_size=5),
       st.integers(0, 2**62))  # fmt: skip
def test_batch_bytes_equal_pydantic_for_any_values(rows: list[tuple], wall_t_us: int) -> None:
    """Exponents, missing wall time, large unwrapped yaw: `attitude_batch_json` writes what pydantic writes."""
    atts = [schemas.Attitude(device_id=f"rod-{i}", kind="rod", seq=seq, t_us=t, wall_t_us=t if has_wall else None,
                             quat_wxyz=tuple(q), roll_rad=a, pitch_rad=-a, yaw_rad=a / 2, yaw_unwrapped_rad=yu)
            for i, (seq, t, a, yu, q, has_wall) in enumerate(rows)]  # fmt: skip
    got = schemas.attitude_batch_json(wall_t_us, atts)
    want = schemas.AttitudeBatch(wall_t_us=wall_t_us, attitudes=atts).model_dump_json(exclude_none=True).encode()
    assert got == want
    assert json.loads(got)["attitudes"][0]["device_id"] == "rod-0"


@pytest.mark.timeout(240)
def test_a_subscriber_in_another_process_gets_every_device_in_gw_attitudes(tmp_path: Path) -> None:
    """`bench.fleet --observe batch` on 30 devices (6 hooks) through a real gateway and zenoh router: the observer
    (another process than the gateway) sees all 30 devices in gw/attitudes, and at least half the attitudes the
    per-device keys would carry (one per packet end)."""
    out = tmp_path / "rows.json"
    cmd = [sys.executable, "-m", "bench.fleet", "--counts", "30", "--duration", "4", "--warmup", "3", "--procs", "1",
           "--pool", "2", "--pool-seconds", "6", "--samples-per-packet", "10", "--observe", "batch", "--json", str(out)]
    res = subprocess.run(cmd, cwd=REPO, capture_output=True, text=True, timeout=220)
    assert res.returncode == 0, res.stderr[-2000:]
    (row,) = json.loads(out.read_text())
    assert row["observe"] == "batch" and row["batch_devices"] == 30, (row, res.stdout[-1500:])
    assert row["processed"] >= 0.99 * row["sent"] > 0, row  # a loaded CI machine may lose a packet at the edges
    assert row["attitudes"] >= 0.5 * row["attitudes_expected"], row
