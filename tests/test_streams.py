"""Who reads which sample: contiguous sample shares for evaluation, process-independent seeds for training."""

import os
import subprocess
import sys
from collections import Counter

import pytest

from lead_s2r.data import streams
from lead_s2r.data.streams import SampleShare, StreamSeed, manifest_samples, share, stream_seed
from lead_s2r.shards import ShardError, read_samples


def test_share_splits_contiguously_with_the_longer_runs_first():
    items = list(range(35))
    parts = [share(items, part, 2) for part in range(2)]
    assert [len(p) for p in parts] == [18, 17] and parts[0] + parts[1] == items
    assert [len(share(items, part, 4)) for part in range(4)] == [9, 9, 9, 8]
    assert [share([1, 2], part, 3) for part in range(3)] == [[1], [2], []]


def test_every_sample_once_over_ranks_and_workers(toy_data, monkeypatch):
    samples, listed = manifest_samples(toy_data, splits=None)
    assert len(samples) == 24 and len({shard for shard, _ in samples}) == 4
    assert {shard: len(keys) for shard, keys in listed.items()} == {shard: 6 for shard, _ in samples}
    seen = Counter()
    for rank in range(2):
        mine = SampleShare(samples, rank, world_size=2)
        for worker in range(3):
            monkeypatch.setattr(streams, "worker_info", lambda worker=worker: (worker, 3))
            urls = [item["url"] for item in mine.shards()]
            assert len(urls) <= 2  # 4 samples of 6-sample shards: at most 2 shards opened
            raw = ({"__key__": sample["__key__"]} for url in urls for sample in read_samples(url, fields=()))
            seen.update(sample["__key__"] for sample in mine(raw))
    assert sorted(seen) == sorted(key for _, key in samples) and set(seen.values()) == {1}


def test_manifest_split_filter_and_missing_manifest(toy_data, tmp_path):
    samples, listed = manifest_samples(toy_data, splits=["val"])
    assert samples == []  # toy data is all "train"
    assert sum(len(keys) for keys in listed.values()) == 24  # what each tar holds, whatever the split
    with pytest.raises(ShardError, match=r"manifest\.parquet"):
        manifest_samples(tmp_path, splits=None)


def test_seeds_do_not_depend_on_the_process():
    script = "from lead_s2r.data.streams import stream_seed; print(stream_seed(0, 3, 1, 0, 'navsim', 'shuffle'))"
    env = {**os.environ, "PYTHONHASHSEED": "1"}
    other = subprocess.check_output([sys.executable, "-c", script], text=True, env=env)
    assert int(other) == stream_seed(0, 3, 1, 0, "navsim", "shuffle")  # str hashes are salted per process
    places = [(0, 0, 0, "a"), (1, 0, 0, "a"), (0, 1, 0, "a"), (0, 0, 1, "a"), (0, 0, 0, "b")]
    draws = {tuple(StreamSeed(*place).rng("shards").random() for _ in range(3)) for place in places}
    assert len(draws) == 5
