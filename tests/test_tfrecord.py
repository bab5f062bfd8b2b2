"""TFRecord framing: our reader against the synthetic writer (separate code) and PyPI ``tfrecord``; bad records."""

import struct
from pathlib import Path

import pyarrow as pa
import pyarrow.parquet as pq
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from tfrecord.reader import tfrecord_iterator

from lead_s2r.synthetic.wod_e2e import frame_record
from lead_s2r_adapters.tfrecord import (
    HEADER,
    RecordReader,
    TFRecordError,
    build_index,
    cached_index,
    iter_records,
    masked_crc32c,
)

payloads = st.lists(st.binary(max_size=300), max_size=8)


def write(path: Path, records: list[bytes]) -> list[int]:
    """Write framed records; return the offset of each."""
    offsets, data = [], b""
    for payload in records:
        offsets.append(len(data))
        data += frame_record(payload)
    path.write_bytes(data)
    return offsets


def test_masked_crc_known_values():
    # CRC-32C("123456789") = 0xE3069283 (the Castagnoli check value); masking rotates right 15 and adds 0xA282EAD8
    crc = 0xE3069283
    assert masked_crc32c(b"123456789") == (((crc >> 15) | (crc << 17)) + 0xA282EAD8) & 0xFFFFFFFF
    # the empty payload's masked CRC, as TensorFlow writes it for a zero-length record
    assert masked_crc32c(b"") == 0xA282EAD8


@settings(max_examples=40, deadline=None)
@given(records=payloads)
def test_scan_and_random_access_round_trip(tmp_path_factory, records):
    path = tmp_path_factory.mktemp("tfr") / "shard.tfrecord"
    offsets = write(path, records)
    scanned = list(iter_records(path))
    assert [r.payload for r in scanned] == records
    assert [r.offset for r in scanned] == offsets
    with RecordReader() as reader:
        for offset, payload in reversed(list(zip(offsets, records, strict=True))):
            assert reader.read(path, offset, len(payload)) == payload


@settings(max_examples=20, deadline=None)
@given(records=payloads)
def test_same_bytes_as_pypi_tfrecord(tmp_path_factory, records):
    path = tmp_path_factory.mktemp("tfr") / "shard.tfrecord"
    write(path, records)
    theirs = [bytes(view) for view in tfrecord_iterator(str(path))]
    assert [r.payload for r in iter_records(path)] == theirs


def test_bad_payload_crc_is_reported_and_the_scan_goes_on(tmp_path):
    path = tmp_path / "shard.tfrecord"
    offsets = write(path, [b"first", b"second", b"third"])
    data = bytearray(path.read_bytes())
    data[offsets[1] + HEADER + 2] ^= 0x01
    path.write_bytes(bytes(data))
    items = list(iter_records(path))
    assert [type(i).__name__ for i in items] == ["Record", "TFRecordError", "Record"]
    assert items[1].offset == offsets[1] and "payload CRC mismatch" in str(items[1]) and str(path) in str(items[1])
    assert items[2].payload == b"third"
    with RecordReader() as reader, pytest.raises(TFRecordError, match=f"offset {offsets[1]}: payload CRC"):
        reader.read(path, offsets[1], len(b"second"))


def test_bad_length_crc_ends_the_scan(tmp_path):
    path = tmp_path / "shard.tfrecord"
    offsets = write(path, [b"first", b"second", b"third"])
    data = bytearray(path.read_bytes())
    data[offsets[1] + 8] ^= 0xFF  # the length's CRC
    path.write_bytes(bytes(data))
    items = list(iter_records(path))
    assert len(items) == 2 and items[0].payload == b"first"
    assert isinstance(items[1], TFRecordError) and items[1].offset == offsets[1] and "length CRC" in str(items[1])


@pytest.mark.parametrize("cut", [3, HEADER, HEADER + 4, HEADER + 6 + 3])
def test_truncated_final_record(tmp_path, cut):
    path = tmp_path / "shard.tfrecord"
    offsets = write(path, [b"first", b"second"])
    path.write_bytes(path.read_bytes()[: offsets[1] + cut])
    items = list(iter_records(path))
    assert items[0].payload == b"first" and len(items) == 2
    assert isinstance(items[1], TFRecordError) and items[1].offset == offsets[1] and "truncated" in str(items[1])


def test_random_access_checks_the_indexed_length(tmp_path):
    path = tmp_path / "shard.tfrecord"
    write(path, [b"payload"])
    with RecordReader() as reader, pytest.raises(TFRecordError, match="differs from the index"):
        reader.read(path, 0, 3)


def describe(payload: bytes) -> dict:
    if not payload.startswith(b"rec"):
        raise ValueError("not one of ours")
    return {"n": int(payload[3:])}


def test_index_rows_skips_and_cache(tmp_path):
    shards = [tmp_path / "a.tfrecord", tmp_path / "b.tfrecord"]
    offsets_a = write(shards[0], [b"rec1", b"junk", b"rec2"])
    offsets_b = write(shards[1], [b"rec3"])
    index = build_index(shards, describe, {"n": pa.int64()})
    assert index.table.to_pylist() == [
        {"shard": str(shards[0]), "offset": offsets_a[0], "length": 4, "n": 1},
        {"shard": str(shards[0]), "offset": offsets_a[2], "length": 4, "n": 2},
        {"shard": str(shards[1]), "offset": offsets_b[0], "length": 4, "n": 3},
    ]
    assert index.skipped == [
        {
            "shard": str(shards[0]),
            "offset": offsets_a[1],
            "error": f"{shards[0]}: record at offset {offsets_a[1]}: not one of ours",
        }
    ]
    cache = tmp_path / "cache" / "index.parquet"
    first = cached_index(shards, describe, {"n": pa.int64()}, cache)
    assert cache.exists() and first.table.equals(index.table) and first.skipped == index.skipped

    def must_not_run(payload: bytes) -> dict:
        raise AssertionError("a valid cache must not rescan")

    again = cached_index(shards, must_not_run, {"n": pa.int64()}, cache)
    assert again.table.equals(index.table) and again.skipped == index.skipped
    write(shards[1], [b"rec3", b"rec4"])  # the shard changed: the cache is stale and rebuilt
    rebuilt = cached_index(shards, describe, {"n": pa.int64()}, cache)
    assert rebuilt.table["n"].to_pylist() == [1, 2, 3, 4]


def test_a_damaged_index_cache_is_rebuilt_never_believed(tmp_path):
    """Every single-bit flip anywhere in the cache file: the index returned is the one a fresh scan builds."""
    shards = [tmp_path / "a.tfrecord", tmp_path / "b.tfrecord"]
    write(shards[0], [b"rec1", b"junk", b"rec2"])
    write(shards[1], [b"rec3"])
    cache = tmp_path / "index.parquet"
    fresh = cached_index(shards, describe, {"n": pa.int64()}, cache)
    intact = cache.read_bytes()
    rescans = 0

    def counting(payload: bytes) -> dict:
        nonlocal rescans
        rescans += 1
        return describe(payload)

    for position in range(len(intact)):
        damaged = bytearray(intact)
        damaged[position] ^= 1 << (position % 8)
        cache.write_bytes(bytes(damaged))
        index = cached_index(shards, counting, {"n": pa.int64()}, cache)
        assert index.table.equals(fresh.table) and index.skipped == fresh.skipped, f"bit flipped at byte {position}"
    assert rescans > 0  # most flips are caught and rebuilt (the rest land where parquet never reads)


def test_a_cache_whose_columns_changed_type_is_rebuilt(tmp_path):
    """A flipped bit in the footer's Arrow schema can retype a column (offsets' int64 read as a duration) with every
    page CRC and the stamp intact: the columns are checked too."""
    shards = [tmp_path / "a.tfrecord"]
    write(shards[0], [b"rec1", b"rec2"])
    cache = tmp_path / "index.parquet"
    fresh = cached_index(shards, describe, {"n": pa.int64()}, cache)
    stored = pq.read_table(cache)
    offsets = stored.schema.get_field_index("offset")
    retyped = stored.set_column(offsets, "offset", stored["offset"].cast(pa.duration("s")))
    assert retyped.schema.metadata == stored.schema.metadata  # the stamp still matches
    pq.write_table(retyped, cache, write_page_checksum=True)
    index = cached_index(shards, describe, {"n": pa.int64()}, cache)
    assert index.table.equals(fresh.table)
    assert pq.read_table(cache)["offset"].type == pa.int64()  # rebuilt


def test_header_layout_is_little_endian_length_then_crc(tmp_path):
    path = tmp_path / "shard.tfrecord"
    write(path, [b"x" * 300])
    length, crc = struct.unpack("<QI", path.read_bytes()[:HEADER])
    assert length == 300 and crc == masked_crc32c(struct.pack("<Q", 300))
