import pytest

from gateway.fusion.registry import make_filter


def test_unknown_filter_names_the_known_ones():
    with pytest.raises(KeyError, match="unknown filter 'nope'"):
        make_filter("nope")
