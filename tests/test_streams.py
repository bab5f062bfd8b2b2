"""Who reads which sample: contiguous sample shares for evaluation, disjoint rank shares and process-independent seeds
for training."""

import itertools
import os
import subprocess
import sys
from collections import Counter

import pytest

from lead_s2r.data import streams
from lead_s2r.data.streams import SampleShare, StreamSeed, TrainShare, manifest_samples, share, stream_seed
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


def test_training_shares_partition_the_samples_anew_each_epoch(toy_data):
    samples, _ = manifest_samples(toy_data, splits=None)
    epochs = []
    for epoch in range(3):
        shares = [TrainShare(samples, StreamSeed(0, epoch, rank, "real"), world_size=2) for rank in range(2)]
        assert [len(part.samples) for part in shares] == [12, 12]
        assert sorted(shares[0].samples + shares[1].samples) == sorted(samples)  # disjoint, every sample
        # contiguous runs of whole shards after a rotation: 12 samples of 6-sample shards touch 2 or 3 shards
        assert all(len(part.urls) in (2, 3) for part in shares)
        epochs.append(shares[0].samples)
    assert epochs[0] != epochs[1] != epochs[2]  # the split moves with the epoch
    assert TrainShare(samples, StreamSeed(0, 0, 0, "real"), 1).samples != samples  # rotated, but all of them
    assert sorted(TrainShare(samples, StreamSeed(0, 0, 0, "real"), 1).samples) == sorted(samples)


def test_a_rank_draws_shards_by_its_samples_in_them_and_keeps_only_its_own(toy_data):
    samples, _ = manifest_samples(toy_data, splits=None)
    (first, _), (second, _) = samples[0], samples[6]
    mine = TrainShare(samples[5:12], StreamSeed(0, 0, 0, "real"), world_size=1)  # 1 sample of shard 0, 6 of shard 1
    draws = Counter(item["url"] for item in itertools.islice(mine.shards(), 7000))
    assert set(draws) == {first, second} and draws[second] / draws[first] == pytest.approx(6, rel=0.15)
    raw = [{"__url__": url, "__key__": key} for url, key in samples] + [{"__url__": second, "__key__": samples[0][1]}]
    assert [(sample["__url__"], sample["__key__"]) for sample in mine(iter(raw))] == samples[5:12]
    with pytest.raises(ValueError, match="rank 2 has no training samples"):
        next(TrainShare(samples[:2], StreamSeed(0, 0, 2, "real"), world_size=3).shards())
