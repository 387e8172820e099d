"""Output messages built from a batch check (`schemas.prevalidated`) equal the ones pydantic validates one by one,
field for field and byte for byte, and values pydantic rejects still raise (random batches, hypothesis): Attitude
(`kinds.base.attitudes`), Height (`kinds.base.height_messages`) and Swing (`kinds.hook.HookKind.post`)."""

from __future__ import annotations

import math
from collections.abc import Callable
from typing import Any

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from pydantic import ValidationError

from gateway import schemas
from gateway.kinds import base, hook
from gateway.kinds.base import Fused, FusedDevice, KindBatch

BREAKS = ["", "", "", "", "q", "q1", "seq", "wall", "wall_neg", "id", "filter", "filter_long", "t_end",
          "rows", "rows_inf"]  # fmt: skip


@st.composite
def batches(draw: st.DrawFn, kind: str = "rod") -> list[dict[str, Any]]:
    """Devices of one kind: each a block of samples with packet ends, unit quaternions and valid header values,
    except that one device may carry one value at or beyond a model limit (most batches are valid)."""
    devices = []
    floats = st.floats(-1.0, 1.0, allow_subnormal=False)
    for d in range(draw(st.integers(1, 3))):
        n_packets = draw(st.integers(1, 3))
        n = 5 * n_packets
        broken = draw(st.sampled_from(BREAKS))
        q = np.array(draw(st.lists(floats, min_size=4 * n, max_size=4 * n))).reshape(n, 4) + 1e-3
        q /= np.linalg.norm(q, axis=1, keepdims=True)
        if broken in ("q", "q1"):  # a component just beyond 1, or nan
            q[-1] = [1.0 + 1e-9, 0.0, 0.0, 0.0] if broken == "q1" else [math.nan, 0.0, 0.0, 1.0]
        t0_us = 2**63 - 10**5 if broken == "t_end" else draw(st.sampled_from([0, 10**6]))
        seqs = [draw(st.integers(0, 2**32 - 1)) for _ in range(n_packets)]
        if broken == "seq":
            seqs[-1] = draw(st.sampled_from([-1, 2**32]))
        ends = [(5 * k + 4, seqs[k], t0_us + (5 * k + 4) * 10_000) for k in range(n_packets)]
        ident = draw(st.text(min_size=1, max_size=3)) if broken == "id" else f"{kind}-{d}"
        filt = {"filter": "", "filter_long": "f" * 65}.get(broken, draw(st.sampled_from([None, "vqf", "f" * 64])))
        dev = FusedDevice(kind=kind, device_id=ident, filter_name=filt, dt_s=0.01, use_mag=False, filt=None)
        dev.wall_offset_us = {"wall": 2**63, "wall_neg": -(10**7)}.get(broken, 1_800_000_000_000_000)
        dev.yaw_turns = draw(st.sampled_from([0, 3, -(10**15), 2**60]))  # finite, beyond 1e16 rad too
        rows = np.array(draw(st.lists(st.floats(-1e20, 1e20), min_size=4 * n, max_size=4 * n))).reshape(n, 4)
        if broken in ("rows", "rows_inf"):
            rows[-1, draw(st.integers(0, 1))] = math.nan if broken == "rows" else -math.inf
        devices.append({"dev": dev, "q": q, "t_s": t0_us * 1e-6 + np.arange(n) * 0.01, "ends": ends, "rows": rows})
    return devices


def kind_batch(devices: list[dict[str, Any]]) -> KindBatch:
    """A fresh KindBatch (fresh device records: building outputs moves their decimation clocks)."""
    items = []
    for d in devices:
        dev = FusedDevice(**{k: getattr(d["dev"], k) for k in ("kind", "device_id", "filter_name", "dt_s", "use_mag",
                                                                "filt")})  # fmt: skip
        dev.wall_offset_us, dev.yaw_turns = d["dev"].wall_offset_us, d["dev"].yaw_turns
        n = d["q"].shape[0]
        items.append(Fused(dev, d["q"], np.zeros((n, 3)), np.zeros((n, 3)), d["t_s"], d["ends"], []))
    return KindBatch(items)


def outcome(fn: Callable[[], list[schemas.WireModel]]) -> list[tuple[Any, ...]] | str:
    """Each message as (type, fields, fields set, JSON bytes), or `invalid` when pydantic rejects one."""
    try:
        msgs = fn()
    except ValidationError:
        return "invalid"
    return [(type(m), m.model_dump(), m.model_fields_set, m.to_json()) for m in msgs]


def both(monkeypatch: pytest.MonkeyPatch, module: Any, check: str, fn: Callable[[], list[Any]]) -> tuple[Any, Any]:
    """`fn` as it runs, and with the batch check refusing everything (every message through pydantic)."""
    fast = outcome(fn)
    with monkeypatch.context() as m:
        m.setattr(module, check, lambda *a, **k: False)
        slow = outcome(fn)
    return fast, slow


@settings(max_examples=150, deadline=None)
@given(batches())
def test_attitudes_equal_the_validated_ones(devices: list[dict[str, Any]]) -> None:
    with pytest.MonkeyPatch.context() as mp:
        fast, slow = both(mp, base, "_attitudes_valid", lambda: base.attitudes(kind_batch(devices), 0.0))
    assert fast == slow


@settings(max_examples=150, deadline=None)
@given(batches(), st.sampled_from([0.0, 0.02, 0.1]))
def test_heights_batch_equals_each_device_validated(devices: list[dict[str, Any]], interval_s: float) -> None:
    """`heights_batch` gives the messages (and device states) `height_messages` gives device by device, or None
    exactly when pydantic rejects a message of some device there."""
    def heave(d: dict[str, Any]) -> np.ndarray:
        rows = d["rows"].copy()
        rows[:, 2], rows[:, 3] = rows[:, 2] > 0, np.arange(rows.shape[0]) % 4  # at rest, aided index
        return rows

    kb, ref = kind_batch(devices), kind_batch(devices)
    batch = base.heights_batch(kb, range(len(devices)), np.concatenate([heave(d) for d in devices]), interval_s)
    alone: list[Any] = []
    for f, d in zip(ref.items, devices, strict=True):
        alone.append(outcome(lambda f=f, d=d: base.height_messages(f, heave(d), interval_s)))
    if batch is None:
        assert "invalid" in alone
        return
    assert outcome(lambda: batch) == [m for msgs in alone for m in msgs]
    for f, g in zip(kb.items, ref.items, strict=True):
        assert (f.dev.last_height_t_s, f.dev.height) == (g.dev.last_height_t_s, g.dev.height)


@settings(max_examples=100, deadline=None)
@given(batches(), st.sampled_from([0.0, 0.1]), st.integers(0, 7))
def test_heights_nobody_takes_are_not_made_but_read_the_same(devices: list[dict[str, Any]], interval_s: float,
                                                              mask: int) -> None:  # fmt: skip
    """With `takes` saying no for some devices, `heights_batch` makes no message for them, moves their decimation
    clock the same, and their `height` (made on demand for REST) equals the last message they would have had."""
    rows = np.concatenate([d["rows"] for d in devices])
    rows[:, 2], rows[:, 3] = rows[:, 2] > 0, np.arange(rows.shape[0]) % 4
    kb, ref = kind_batch(devices), kind_batch(devices)
    taken = {f.dev.device_id: bool(mask >> i & 1) for i, f in enumerate(kb.items)}
    got = base.heights_batch(kb, range(len(devices)), rows, interval_s, lambda d: taken[d.device_id])
    want = base.heights_batch(ref, range(len(devices)), rows, interval_s)
    if want is None:
        assert got is None
        return
    assert got == [m for m in want if taken[m.device_id]]
    for f, g in zip(kb.items, ref.items, strict=True):
        assert (f.dev.last_height_t_s, f.dev.height) == (g.dev.last_height_t_s, g.dev.height)
        assert f.dev.height is None or f.dev.height.to_json() == g.dev.height.to_json()  # type: ignore[union-attr]


class _Rules:
    def update_deg(self, *args: Any) -> list[Any]:
        return []


class _Ctx:
    class settings:  # noqa: N801 (a stand-in for PipelineSettings)
        swing_interval_s = 0.0

    @staticmethod
    def fail(dev: FusedDevice, exc: Exception, out: Any) -> None:
        raise exc


@settings(max_examples=150, deadline=None)
@given(batches("hook"), st.sampled_from([None, 12.5, 12.5, 1000.0, 0.0, 1000.5]),
       st.sampled_from([None, None, 0.3, 1e300, math.nan]))
def test_swings_equal_the_validated_ones(devices: list[dict[str, Any]], rope: float | None,
                                         heading: float | None) -> None:  # fmt: skip
    def run() -> list[schemas.WireModel]:
        kb = kind_batch(devices)
        for f in kb.items:
            f.dev.state = hook.HookState(_Rules(), rest_heading_set_rad=heading)  # type: ignore[arg-type]
            f.dev.filt = type("Filt", (), {"rope_length_m": rope})()  # type: ignore[assignment]
        out = base.Output()
        with np.errstate(all="ignore"):
            hook.HookKind().post(_Ctx(), kb, 0.0, out)  # type: ignore[arg-type]
        return list(out.swings)

    with pytest.MonkeyPatch.context() as mp:
        fast, slow = both(mp, hook, "_swings_valid", run)
    assert fast == slow
