"""`bench.pipeline_cost.join_periods`: the packets a bench batch holds when the gateway waits several periods."""

import pytest
from hypothesis import given
from hypothesis import strategies as st

from bench.pipeline_cost import join_periods


@given(st.lists(st.lists(st.integers(), max_size=5), max_size=12), st.integers(1, 5))
def test_joined_periods_keep_every_packet_in_order_k_periods_a_batch(periods: list[list[int]], k: int) -> None:
    joined = join_periods(periods, k)
    assert [p for b in joined for p in b] == [p for b in periods for p in b]
    assert len(joined) == -(-len(periods) // k)
    for i, batch in enumerate(joined):
        assert batch == [p for b in periods[i * k:(i + 1) * k] for p in b]


def test_one_period_a_batch_is_the_periods_as_they_are() -> None:
    periods = [[("k", b"a"), ("k", b"b")], [("k", b"c")]]
    assert join_periods(periods, 1) == periods


def test_fewer_than_one_period_a_batch_is_refused() -> None:
    with pytest.raises(ValueError, match="at least 1"):
        join_periods([[1]], 0)
