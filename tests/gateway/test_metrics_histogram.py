"""`BatchedHistogram` (the latency histogram of /metrics, binned a batch at a time) against prometheus_client's own
`Histogram` observed value by value: the same text exposition, scrape after scrape."""

from __future__ import annotations

import math
import re

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from prometheus_client import CollectorRegistry, Histogram, generate_latest

from gateway.api.routes import metrics
from gateway.api.routes.metrics import LATENCY_BUCKETS_S, BatchedHistogram

NAME, HELP = "rig_sample_to_publish_seconds", "Device wall time of a sample -> gateway publish"
LABELS = ("kind", "topic")
SERIES = [("rod", "attitude"), ("hook", "attitude"), ("rod", "alarm")]
_CREATED = re.compile(rb"^(\S+_created\{[^}]*\}) \S+$", re.MULTILINE)

delays = st.one_of(
    st.floats(-1.0, 10.0), st.sampled_from([*LATENCY_BUCKETS_S, 0.0, -0.0, 1e-300, 5.000000000000001, math.inf]),
    st.floats(allow_nan=True, allow_infinity=True),
)  # fmt: skip
events = st.lists(st.one_of(st.tuples(st.sampled_from(SERIES), delays), st.just(None)), max_size=120)  # None: scrape


def _text(registry: CollectorRegistry) -> bytes:
    """The exposition with each `_created` value blanked (creation times differ by microseconds)."""
    return _CREATED.sub(rb"\1 T", generate_latest(registry))


@settings(max_examples=200, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(events, st.sampled_from([1, 3, 4096]))
def test_exposition_equals_histogram_observed_one_by_one(monkeypatch: pytest.MonkeyPatch,
                                                         steps: list[tuple[tuple[str, str], float] | None],
                                                         flush_every: int) -> None:  # fmt: skip
    """Random delays (negative, on a bucket bound, huge, inf, NaN) in 3 series, scrapes in between, binned at every
    1st / 3rd / 4096th observation: buckets, counts, sums (to the last bit) and series order are Histogram's."""
    monkeypatch.setattr(metrics, "HISTOGRAM_FLUSH_EVERY", flush_every)
    ref_registry, got_registry = CollectorRegistry(auto_describe=True), CollectorRegistry(auto_describe=True)
    reference = Histogram(NAME, HELP, LABELS, buckets=LATENCY_BUCKETS_S, registry=ref_registry)
    batched = BatchedHistogram(NAME, HELP, LABELS, LATENCY_BUCKETS_S)
    got_registry.register(batched)
    for step in [*steps, None]:
        if step is None:
            assert _text(got_registry) == _text(ref_registry)
            continue
        labelvalues, delay_s = step
        reference.labels(*labelvalues).observe(max(0.0, delay_s))  # what Metrics._observe did
        batched.observe(labelvalues, delay_s)


def test_a_series_holds_at_most_flush_every_observations() -> None:
    """Without a scraper, observations are binned as they reach `HISTOGRAM_FLUSH_EVERY`: memory stays bounded."""
    h = BatchedHistogram(NAME, HELP, LABELS, LATENCY_BUCKETS_S)
    for i in range(3 * metrics.HISTOGRAM_FLUSH_EVERY + 5):
        h.observe(("rod", "attitude"), i * 1e-4)
    assert len(h._series[("rod", "attitude")].pending) == 5
    assert sum(h._series[("rod", "attitude")].counts) == 3 * metrics.HISTOGRAM_FLUSH_EVERY
