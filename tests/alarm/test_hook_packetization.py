"""Same hook samples, same alarms: the swing and torsion rules decide sample by sample in device time, so a stream
cut into any blocks gives exactly the conditions (type, severity, time, value, threshold, message) of the whole
stream in one block (issue 11; the rules used to judge each block's peak and time a fall at the block's end)."""

from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from gateway.alarm.hook import HookAlarms, hook_rules

RATE_HZ = 100.0


def _signals(seed: int, seconds: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A hook swinging 2-12° and twisting 20-70° around the default limits (swing 5/10°, torsion 30/60°)."""
    rng = np.random.default_rng(seed)
    t = np.arange(int(seconds * RATE_HZ)) / RATE_HZ
    envelope = 7.0 + 5.0 * np.sin(2 * np.pi * t / rng.uniform(15.0, 40.0))
    swing = np.abs(envelope * np.sin(2 * np.pi * t / rng.uniform(3.0, 8.0))) + rng.normal(0.0, 0.2, t.size)
    twist = 45.0 + 25.0 * np.sin(2 * np.pi * t / rng.uniform(20.0, 50.0))
    torsion = twist * np.sin(2 * np.pi * t / rng.uniform(4.0, 12.0)) + rng.normal(0.0, 0.5, t.size)
    return t, np.radians(np.abs(swing)), np.radians(torsion)


def _conditions(t: np.ndarray, swing: np.ndarray, torsion: np.ndarray, cuts: list[int]) -> list[tuple]:
    hook = HookAlarms("hook-1")
    out = []
    bounds = [0, *sorted(set(cuts)), t.size]
    for a, b in zip(bounds[:-1], bounds[1:], strict=True):
        for c in hook.update(t[a:b], swing[a:b], torsion[a:b]):
            out.append((c.type, c.severity, round(c.t_s, 6), round(c.value, 9), c.threshold, c.message))
    return out


@settings(max_examples=25, deadline=None)
@given(seed=st.integers(0, 1000), cuts=st.lists(st.integers(1, 11_999), max_size=400))
def test_hook_alarms_do_not_depend_on_packetization(seed: int, cuts: list[int]) -> None:
    t, swing, torsion = _signals(seed, 120.0)
    whole = _conditions(t, swing, torsion, [])
    assert any(c[1] is not None for c in whole) and any(c[1] is None for c in whole)  # raises and clears happen
    assert _conditions(t, swing, torsion, cuts) == whole


def test_block_size_does_not_move_a_fall_or_its_message() -> None:
    """Fixed packet sizes a device might use: 1, 5, 10, 25 and 100 samples per block, all alike."""
    t, swing, torsion = _signals(7, 120.0)
    whole = _conditions(t, swing, torsion, [])
    for n in (1, 5, 10, 25, 100):
        assert _conditions(t, swing, torsion, list(range(n, t.size, n))) == whole, n


@settings(max_examples=20, deadline=None)
@given(seeds=st.lists(st.integers(0, 1000), min_size=1, max_size=5), block=st.sampled_from([1, 5, 10, 37]),
       nan_at=st.integers(0, 11_999))  # fmt: skip
def test_batched_hook_rules_equal_each_hook_alone(seeds: list[int], block: int, nan_at: int) -> None:
    """`hook_rules` over several hooks' concatenated blocks (one max/min reduction for all) gives every hook the
    conditions, in order, that its own `HookAlarms.update` gives, and leaves it in the same state."""
    streams = [_signals(s, 120.0) for s in seeds]
    streams[0][1][nan_at] = np.nan  # a gap: max/min propagate it alike
    alone = [HookAlarms(f"hook-{i}") for i in range(len(seeds))]
    batched = [HookAlarms(f"hook-{i}") for i in range(len(seeds))]
    seen = 0
    for a in range(0, streams[0][0].size, block):
        blocks = [(t[a : a + block], sw[a : a + block], to[a : a + block]) for t, sw, to in streams]
        expected = [h.update(*b) for h, b in zip(alone, blocks, strict=True)]
        sizes = np.array([b[0].size for b in blocks])
        stop = np.cumsum(sizes)
        got = hook_rules(batched, *(np.concatenate([b[k] for b in blocks]) for k in range(3)), stop - sizes, stop)
        assert got == expected
        seen += sum(map(len, expected))
    assert seen > 0
    state = [(vars(h.swing), vars(h.torsion)) for h in alone]
    assert [(vars(h.swing), vars(h.torsion)) for h in batched] == state
