"""Rendezvous ownership of devices by shards (gateway/shard/ownership.py): properties, not examples."""

from __future__ import annotations

from hypothesis import given
from hypothesis import strategies as st

from gateway.shard.ownership import Ownership, ShardInfo, glob_to_key_chunk, owner_of

ids = st.from_regex(r"[A-Za-z0-9_-]{1,12}", fullmatch=True)


@given(st.sets(ids, min_size=1, max_size=6), st.lists(ids, min_size=1, max_size=40))
def test_every_device_has_exactly_one_owner_and_every_shard_agrees(shards: set[str], devices: list[str]) -> None:
    views = [Ownership(ShardInfo(s)) for s in shards]
    for v in views:
        for s in shards:
            v.update(ShardInfo(s), True)
    for d in devices:
        assert sum(v.owns(d) for v in views) == 1
        assert {v.owner(d) for v in views} == {owner_of(d, [ShardInfo(s) for s in shards])}


@given(st.sets(ids, min_size=2, max_size=6), st.lists(ids, min_size=1, max_size=60), st.data())
def test_a_leaving_shard_moves_only_its_own_devices(shards: set[str], devices: list[str], data: st.DataObject) -> None:
    gone = data.draw(st.sampled_from(sorted(shards)))
    before = {d: owner_of(d, [ShardInfo(s) for s in shards]) for d in devices}
    after = {d: owner_of(d, [ShardInfo(s) for s in shards - {gone}]) for d in devices}
    assert all(after[d] == before[d] for d in devices if before[d] != gone)
    assert gone not in after.values()


def test_the_ids_spread_over_shards_roughly_evenly() -> None:
    shards = [ShardInfo(f"gw-{k}") for k in range(4)]
    counts = {s.shard_id: 0 for s in shards}
    for i in range(4000):
        counts[str(owner_of(f"rod-{i}", shards))] += 1
    assert all(850 <= n <= 1150 for n in counts.values()), counts  # 1000 each, binomial sd ~27


def test_site_patterns_limit_a_shard_and_travel_in_its_token() -> None:
    site1 = ShardInfo("s1", ("site1-*",))
    anywhere = ShardInfo("any")
    assert ShardInfo.from_token_key(site1.token_key) == site1
    assert ShardInfo.from_token_key(anywhere.token_key) == anywhere
    assert ShardInfo.from_token_key("gw/shard/x/not-hex") is None
    assert owner_of("site2-rod-1", [site1]) is None
    assert owner_of("site2-rod-1", [site1, anywhere]) == "any"
    assert glob_to_key_chunk("site1-*") == "site1-$*"
    assert glob_to_key_chunk("rod-?") is None


def test_own_token_never_leaves_the_live_set() -> None:
    me = Ownership(ShardInfo("a"))
    assert me.update(ShardInfo("b"), True) and not me.update(ShardInfo("b"), True)
    assert not me.update(ShardInfo("a"), False)
    assert me.update(ShardInfo("b"), False)
    assert me.owns("anything")
