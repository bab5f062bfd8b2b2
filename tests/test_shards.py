import errno
import os
import tarfile
from pathlib import Path

import numpy as np
import pyarrow.parquet as pq
import pytest
import webdataset as wds
from corruptions import flip_in_value
from tiny_models import sensor_spec
from toy_adapter import ToyAdapter, corrupt_header, toy_sample, write_toy_logs

from lead_s2r.convert import convert
from lead_s2r.data.datamodule import DriveDataModule, SourceSpec
from lead_s2r.models.config import TrajectoryGrid
from lead_s2r.shards import (
    MANIFEST,
    SHARD_DIR,
    ShardError,
    ShardFile,
    TarSamples,
    decode_field,
    encode_field,
    listed_keys,
    load_manifest,
    read_part,
    read_samples,
    sample_offsets,
    write_sample,
)


def assert_same_sample(a: dict, b: dict) -> None:
    assert a.keys() == b.keys()
    for name, value in a.items():
        if isinstance(value, np.ndarray):
            assert value.dtype == b[name].dtype and value.shape == b[name].shape, name
            assert value.tobytes() == b[name].tobytes(), name  # bit for bit, NaN payloads included
        elif isinstance(value, dict) and value and isinstance(next(iter(value.values())), np.ndarray):
            assert_same_sample(value, b[name])
        else:
            assert value == b[name], name


def write_shard(path, samples):
    shard = ShardFile(path)
    for sample in samples:
        shard.write(sample)
    return shard.close()


def special_sample(frame: int) -> dict:
    sample = toy_sample("log000", frame)
    sample["future"][:, 3] = np.nan  # yaw unknown
    sample["lidar"][0, 0] = np.float32(1e-45)  # subnormal survives
    sample["bev_semantic"] = np.arange(64 * 32, dtype=np.uint8).reshape(32, 64) % 7
    sample["raters"] = {
        "trajectories": np.random.default_rng(0).normal(size=(3, 20, 2)).astype(np.float32),
        "scores": np.array([10, 6, 4], np.float32),
    }
    sample["meta"]["has"].update(bev_semantic=True, raters=True)
    return sample


def test_round_trip_is_bit_exact(tmp_path):
    samples = [special_sample(i) for i in range(3)]
    write_shard(tmp_path / "a-000000.tar", samples)
    back = list(read_samples(tmp_path))
    assert len(back) == 3
    for original, decoded in zip(samples, back, strict=True):
        assert_same_sample(original, decoded)


def test_an_npz_member_with_a_damaged_zip_flag_is_a_shard_error(tmp_path):
    """Flag bit 5 (compressed patched data) of an .npz's zip entry: zipfile raised NotImplementedError."""
    path = write_shard(tmp_path / "a-000000.tar", [special_sample(0)])
    data = bytearray(path.read_bytes())
    entry = data.index(b"PK\x01\x02")  # the first central directory entry: raters.npz's first array
    data[entry + 8] |= 1 << 5  # its general purpose bit flags, which zipfile checks
    path.write_bytes(bytes(data))
    with pytest.raises(ShardError, match=r"field 'raters': cannot be decoded as \.npz \(compressed patched data"):
        list(read_samples(tmp_path))


def test_an_npy_header_numpy_cannot_tokenize_is_a_shard_error(tmp_path):
    """A bracket in the padding of future.npy's header: numpy's Python 2 fallback raised tokenize.TokenError."""
    sample = toy_sample("log000", 0)
    path = write_shard(tmp_path / "a-000000.tar", [sample])
    data = path.read_bytes()
    header = data.index(b"{'descr'", data.index(b"future.npy"))
    padding = data.index(b"}", header) + 2
    path.write_bytes(data[:padding] + b"(" + data[padding + 1 :])
    with pytest.raises(ShardError, match=r"field 'future': cannot be decoded as \.npy \(\('EOF in multi-line"):
        list(read_samples(tmp_path))


def test_jpeg_bytes_are_stored_untouched(tmp_path):
    sample = toy_sample("log000", 0)
    path = write_shard(tmp_path / "a-000000.tar", [sample])
    with tarfile.open(path) as tar:
        member = tar.extractfile(f"{sample['__key__']}.cam_front.jpg").read()
    assert member == sample["cam_front"]


def test_only_requested_fields_are_decoded(tmp_path):
    write_shard(tmp_path / "a-000000.tar", [toy_sample("log000", 0)])
    (sample,) = read_samples(tmp_path, fields=["future"])
    assert set(sample) == {"__key__", "meta", "future"}


def test_shards_are_plain_webdataset_tars(tmp_path):
    samples = [toy_sample("log000", i) for i in range(4)]
    write_shard(tmp_path / "a-000000.tar", samples)
    raw = list(wds.WebDataset(str(tmp_path / "a-000000.tar"), shardshuffle=False))
    assert [r["__key__"] for r in raw] == [s["__key__"] for s in samples]
    assert {"meta.json", "future.npy", "cam_front.jpg", "lidar.npy"} <= set(raw[0])
    assert not any(name.endswith(("pyd", "pkl", "pickle")) for r in raw for name in r)


def test_same_samples_give_same_bytes(tmp_path):
    a = write_shard(tmp_path / "a-000000.tar", [toy_sample("log000", 1)])
    b = write_shard(tmp_path / "b-000000.tar", [toy_sample("log000", 1)])
    assert a.read_bytes() == b.read_bytes()


@pytest.mark.parametrize("in_kernel", [True, False])
def test_appended_fragments_give_the_bytes_one_writer_gives(tmp_path, monkeypatch, in_kernel):
    samples = [toy_sample("a", 0), toy_sample("b", 0), toy_sample("b", 1), toy_sample("c", 0)]
    whole = write_shard(tmp_path / "whole-000000.tar", samples)
    fragment = tmp_path / "b.partial"
    with open(fragment, "wb") as file:
        for sample in samples[1:3]:
            write_sample(file, sample)
    if not in_kernel:  # a file system that refuses copy_file_range: the copy goes through Python

        def refuse(*args: object) -> int:
            raise OSError(errno.EXDEV, "Invalid cross-device link")

        monkeypatch.setattr(os, "copy_file_range", refuse)
    shard = ShardFile(tmp_path / "joined-000000.tar")
    shard.write(samples[0])  # still in the file object's buffer when the fragment is appended
    shard.append(fragment, 2)
    shard.write(samples[3])
    assert shard.count == 4
    assert shard.close().read_bytes() == whole.read_bytes()


def test_partial_shard_is_invisible_until_closed(tmp_path):
    shard = ShardFile(tmp_path / "a-000000.tar")
    shard.write(toy_sample("log000", 0))
    assert not (tmp_path / "a-000000.tar").exists()
    shard.close()
    assert (tmp_path / "a-000000.tar").exists() and not shard.partial.exists()


def test_json_refuses_nan():
    meta = toy_sample("log000", 0)["meta"]
    meta["ego"]["speed"] = float("nan")
    try:
        encode_field("meta", meta)
    except ValueError as err:
        assert "JSON" in str(err) or "nan" in str(err).lower()
    else:
        raise AssertionError("NaN in meta must not be written")
    assert decode_field("meta", encode_field("meta", {"a": 1})) == {"a": 1}


def test_read_samples_reads_everything_under_ddp(toy_data, monkeypatch):
    monkeypatch.setenv("RANK", "1")  # what webdataset sees on rank 1 of 2; its default splitter refuses to run
    monkeypatch.setenv("WORLD_SIZE", "2")
    assert len(list(read_samples(toy_data, fields=()))) == 24


@pytest.fixture
def one_log(tmp_path) -> Path:
    """A converted folder of one log: 3 samples in one shard."""
    write_toy_logs(tmp_path / "src", n_logs=1, frames=3)
    convert(ToyAdapter(), tmp_path / "src", tmp_path / "data")
    return tmp_path / "data"


def test_a_flipped_manifest_value_fails_its_page_checksum(one_log):
    """Without the CRC sample 1 would be listed 1 µs later (the middle timestamp: in no page's min/max statistics,
    which no CRC covers)."""
    flip_in_value(one_log / MANIFEST, np.int64(1_500_000).tobytes())
    with pytest.raises(ShardError, match=rf"{MANIFEST}: cannot be read as a manifest \(.*(CRC|checksum)"):
        load_manifest(one_log)


def test_a_manifest_written_before_the_checksums_reads_as_before(one_log):
    written = load_manifest(one_log)
    pq.write_table(written, one_log / MANIFEST)  # no page CRCs, as conversions wrote them before
    assert load_manifest(one_log).equals(written) and len(listed_keys(one_log)[next(iter(listed_keys(one_log)))]) == 3


def test_a_corrupt_header_mid_shard_is_an_error_not_a_short_read(one_log):
    (shard,) = (one_log / SHARD_DIR).glob("*.tar")
    assert len(list(read_samples(one_log, fields=()))) == 3
    corrupt_header(shard, "toy_log000_000001.meta.json")  # tarfile now yields sample 0 and stops
    message = f"{shard}: read 1 of the 3 samples the manifest lists"
    with pytest.raises(ShardError, match=message):
        list(read_samples(one_log, fields=()))
    for part in (shard, one_log / SHARD_DIR):  # a shard of a converted folder is held to its manifest too
        with pytest.raises(ShardError, match=message):
            list(read_samples(part, fields=()))
    inputs = sensor_spec(image_size=(32, 64), trajectory_grids={"toy": TrajectoryGrid(4, 0.5)}, radar=False)
    spec = SourceSpec([str(one_log)], cameras=["front"])
    datamodule = DriveDataModule(train={"toy": spec}, predict={"toy": spec}, inputs=inputs)
    (loader,) = datamodule.predict_dataloader()
    with pytest.raises(ShardError, match=message):
        list(loader)


def test_a_sample_the_manifest_does_not_list_is_an_error(one_log):
    manifest = pq.read_table(one_log / MANIFEST)
    pq.write_table(manifest.slice(0, 2), one_log / MANIFEST)  # as if the third sample came from elsewhere
    with pytest.raises(ShardError, match="sample 'toy_log000_000002' is not in the manifest"):
        list(read_samples(one_log, fields=()))


def test_a_part_of_a_shard_decodes_what_reading_the_folder_gives(toy_data):
    whole = {sample["__key__"]: sample for sample in read_samples(toy_data, fields=("future", "boxes"))}
    shard = sorted(listed_keys(toy_data))[1]
    keys = listed_keys(toy_data)[shard]
    offsets = sample_offsets(shard)
    assert list(offsets) == keys and offsets[keys[0]] == 0 and offsets[keys[2]] % 512 == 0
    part = read_part(shard, keys[2:5], ("future", "boxes"), offsets[keys[2]])
    assert [sample["__key__"] for sample in part] == keys[2:5]
    for sample in part:
        assert "lidar" not in sample and "cam_front" not in sample  # not asked for: not read
        assert_same_sample(sample, whole[sample["__key__"]])
    with pytest.raises(ShardError, match=f"sample {keys[1]!r}, which the manifest lists in it, is not in the tar"):
        read_part(shard, keys[1:3], (), offsets[keys[2]])  # the part starts past its first sample
    with pytest.raises(ShardError, match=f"sample {keys[2]!r}, which the manifest lists in it, is not in the tar"):
        read_part(shard, keys[2:3], (), offsets[keys[2]] + 512)  # mid-member: tarfile sees no header, yields nothing


def _tar_reading(shard: str, fields: tuple[str, ...] | None = None, ours: bool = True) -> list[dict] | str:
    """The raw samples of ``shard`` as :class:`TarSamples` reads them, or as webdataset's own reader does (which it
    replaces); or ``"unreadable"`` where the reader raised (ours: a ShardError naming the tar)."""
    read = TarSamples(fields) if ours else wds.tarfile_to_samples(handler=wds.reraise_exception)
    try:
        return list(wds.DataPipeline(lambda: iter([{"url": shard}]), read))
    except ShardError as err:
        assert ours and str(err).startswith(f"{shard}: cannot be read (") and "truncated or corrupt" in str(err)
        return "unreadable"
    except (OSError, tarfile.TarError):
        assert not ours
        return "unreadable"


def _members(reading: list[dict] | str) -> list[list[str]] | str:
    return reading if isinstance(reading, str) else [list(raw) for raw in reading]


def test_tar_samples_are_webdatasets_samples_with_only_the_wanted_members_read(one_log, tmp_path):
    (shard,) = (one_log / SHARD_DIR).glob("*.tar")
    theirs = _tar_reading(str(shard), ours=False)
    assert len(theirs) == 3 and _tar_reading(str(shard)) == theirs  # every key, member and byte, in their order
    wanted = _tar_reading(str(shard), ("future", "cam_front"))
    assert _members(wanted) == _members(theirs)  # unread members still listed
    for mine, raw in zip(wanted, theirs, strict=True):
        for name, data in raw.items():
            read = name.startswith("__") or name.split(".")[0] in ("meta", "future", "cam_front")
            assert mine[name] == (data if read else b""), name
    data = shard.read_bytes()
    header = data.index(b"toy_log000_000001.meta.json")
    damaged = {
        "cut inside a member": data[: header + 700],
        "cut after a header": data[: header + 512],
        "cut at a header": data[:header],
        "a header's checksum broken": data[: header + 148] + b"0000000\0" + data[header + 156 :],
        "a header zeroed": data[:header] + bytes(512) + data[header + 512 :],
        "not a tar": b"x" * 4096,
        "empty": b"",
    }
    for what, content in damaged.items():
        broken = tmp_path / "broken.tar"
        broken.write_bytes(content)
        theirs = _tar_reading(str(broken), ours=False)
        assert _tar_reading(str(broken)) == theirs, what
        assert _members(_tar_reading(str(broken), ("future",))) == _members(theirs), what
    assert _tar_reading(str(tmp_path / "gone.tar")) == "unreadable"
