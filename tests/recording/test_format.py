"""The .rigrec format: round trip, torn tails at every byte, corrupt records, appending after a crash."""

from __future__ import annotations

import struct
import zlib
from pathlib import Path

import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from gateway.recording.format import (
    MAGIC,
    FormatError,
    ReadStats,
    Record,
    RecordWriter,
    encode_header,
    encode_record,
    iter_file,
    read_meta,
    write_recording,
)

records_st = st.lists(
    st.builds(Record, key=st.text(min_size=1, max_size=30), payload=st.binary(max_size=300),
              t_us=st.integers(-(2**62), 2**62), encoding=st.text(max_size=40)),
    max_size=12,
)  # fmt: skip


@given(records_st, st.booleans())
@settings(max_examples=60, deadline=None)
def test_round_trip_keeps_every_field_and_the_order(records: list[Record], compress: bool) -> None:
    import tempfile

    with tempfile.TemporaryDirectory() as d:
        path = Path(d) / "a.rigrec"
        write_recording(path, records, {"x": 1}, compress=compress, block_records=3)
        assert list(iter_file(path)) == records
        assert read_meta(path) == {"x": 1}


def test_compression_only_when_smaller_and_transparent(tmp_path: Path) -> None:
    payload = b'{"gyr_rad_s":[[0.001,0.002,0.003]]}' * 40
    big, small = encode_record(Record("k", payload, 1), False), encode_record(Record("k", payload, 1), True)
    assert len(small) < len(big) / 3
    raw = Record("k", bytes(range(7)), 1)  # incompressible
    assert encode_record(raw, True) == encode_record(raw, False)


def test_every_truncation_yields_exactly_the_complete_records(tmp_path: Path) -> None:
    recs = [Record(f"rig/rod/r{i}/imu", bytes([i]) * (i * 7), 1000 + i, "application/json") for i in range(8)]
    path = tmp_path / "full.rigrec"
    write_recording(path, recs, {"m": "x"}, compress=False)
    data = path.read_bytes()
    header_len = len(encode_header({"m": "x"}))
    ends = [header_len]
    for r in recs:
        ends.append(ends[-1] + len(encode_record(r)))
    assert ends[-1] == len(data)
    cut = tmp_path / "cut.rigrec"
    for n in range(header_len, len(data) + 1):
        cut.write_bytes(data[:n])
        stats = ReadStats()
        got = list(iter_file(cut, stats))
        complete = sum(1 for e in ends[1:] if e <= n)
        assert got == recs[:complete], n
        assert stats.tail_bytes == n - ends[complete]


def test_torn_header_is_a_format_error(tmp_path: Path) -> None:
    path = tmp_path / "h.rigrec"
    head = encode_header({"a": 1})
    for n in (0, 5, len(head) - 1):
        path.write_bytes(head[:n])
        with pytest.raises(FormatError):
            list(iter_file(path))
    path.write_bytes(b"not a recording at all")
    with pytest.raises(FormatError, match="magic"):
        list(iter_file(path))
    path.write_bytes(MAGIC + struct.pack("<HHI", 2, 0, 0) + struct.pack("<I", 0))
    with pytest.raises(FormatError, match="version"):
        list(iter_file(path))


def test_a_corrupt_record_stops_the_reader_there(tmp_path: Path) -> None:
    recs = [Record("k", b"payload-%d" % i, i) for i in range(5)]
    path = tmp_path / "c.rigrec"
    write_recording(path, recs, compress=False)
    data = bytearray(path.read_bytes())
    third = len(encode_header({})) + 2 * len(encode_record(recs[0]))
    data[third + 20] ^= 0xFF  # a flipped bit inside record 2's body
    path.write_bytes(bytes(data))
    stats = ReadStats()
    assert list(iter_file(path, stats)) == recs[:2]
    assert stats.torn_files == [str(path)]
    # the stored CRC is what failed: recomputing it over the damaged body differs from the stored one
    body_len, crc = struct.unpack_from("<II", data, third)
    assert zlib.crc32(bytes(data[third + 8 : third + 8 + body_len])) != crc


def test_reopening_truncates_the_torn_tail_and_appends(tmp_path: Path) -> None:
    path = tmp_path / "a.rigrec"
    first = [Record("k", b"one", 1), Record("k", b"two", 2)]
    write_recording(path, first)
    with open(path, "ab") as f:
        f.write(encode_record(Record("k", b"torn away", 3))[:-4])  # a crash mid-record
    with RecordWriter(path) as w:
        w.append(Record("k", b"three", 4))
    stats = ReadStats()
    assert list(iter_file(path, stats)) == [*first, Record("k", b"three", 4)]
    assert stats.tail_bytes == 0
