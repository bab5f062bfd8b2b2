"""Which samples each rank and dataloader worker reads, and in what order: seeded training streams, sample-split
evaluation streams.

Training draws shards with replacement and shuffles samples in a buffer. Webdataset's own resampler mixes the
clock, the pid and ``os.urandom`` into its seed, and its shuffle seeds from the clock, so two runs with the same
``seed_everything`` draw different batches. Here both generators are seeded from (seed, epoch, rank, worker, source,
purpose) and nothing else: the same seed gives the same batches, and a run resumed at an epoch boundary draws what
the uninterrupted run would have drawn next (the epoch is part of the seed, not a counter that lives in memory).
The rank is passed in from the trainer because dataloader workers do not always see ``torch.distributed`` or a
``RANK`` variable; the worker comes from ``torch.utils.data.get_worker_info`` when the stream starts.

Evaluation splits by sample, not by shard: webdataset's ``split_by_node`` hands out whole shards (two ranks of a
one-shard split get 35 and 0 samples) and its default ``single_node_only`` refuses to run under DDP. The manifest
lists every sample with its shard and split, so each rank, and each worker within it, gets a contiguous run of the
selected samples (35 -> 18 + 17) and opens only the shards that hold it. The same manifest read lists every key
of every shard, which each opened tar is held to (a corrupt header mid-tar would otherwise end it silently).
"""

import random
import zlib
from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch.utils.data
import webdataset as wds

from lead_s2r.shards import MANIFEST, SHARD_DIR, ShardError, check_listed_shards, keys_by_shard, load_manifest


def worker_info() -> tuple[int, int]:
    """(this dataloader worker's index, number of workers); (0, 1) in the main process."""
    info = torch.utils.data.get_worker_info()
    return (0, 1) if info is None else (info.id, info.num_workers)


def stream_seed(*parts: int | str) -> int:
    """A seed from ints and strings, the same in every process (Python salts ``hash`` of a str per process)."""
    words = [zlib.crc32(part.encode()) if isinstance(part, str) else int(part) % 2**32 for part in parts]
    return int(np.random.SeedSequence(words).generate_state(1, np.uint64)[0])


@dataclass(frozen=True)
class StreamSeed:
    """Where a training stream sits: the run's seed, the epoch, the rank and the source it feeds."""

    seed: int
    epoch: int
    rank: int
    source: str

    def rng(self, purpose: str) -> random.Random:
        """A generator for ``purpose`` ("shards", "shuffle") in the calling dataloader worker."""
        return random.Random(stream_seed(self.seed, self.epoch, self.rank, worker_info()[0], self.source, purpose))


class ResampledShards:
    """An endless stream of ``{"url": shard}`` drawn with replacement; the first stage of a training pipeline."""

    def __init__(self, shards: Sequence[str], seed: StreamSeed) -> None:
        if not shards:
            raise ValueError(f"source {seed.source!r} has no shards to draw from")
        self.shards = list(shards)
        self.seed = seed

    def __call__(self) -> Iterator[dict[str, str]]:
        rng = self.seed.rng("shards")
        while True:
            yield {"url": rng.choice(self.shards)}


class SeededShuffle:
    """A webdataset shuffle buffer whose generator comes from a :class:`StreamSeed`, not the clock."""

    def __init__(self, size: int, seed: StreamSeed) -> None:
        self.size = size
        self.seed = seed

    def __call__(self, samples: Iterator[dict[str, Any]]) -> Iterator[dict[str, Any]]:
        return wds.shuffle(self.size, rng=self.seed.rng("shuffle"))(samples)


def share(items: Sequence[Any], part: int, parts: int) -> list[Any]:
    """The ``part``-th of ``parts`` contiguous runs of ``items``; lengths differ by at most one, longer runs first."""
    n = len(items)
    return list(items[-(-part * n // parts) : -(-(part + 1) * n // parts)])


def manifest_samples(
    path: str | Path, splits: Sequence[str] | None
) -> tuple[list[tuple[str, str]], dict[str, list[str]]]:
    """(shard path, key) of every sample of a converted folder in the wanted splits, in shard order; and every key
    the manifest lists per shard, all splits (what a tar must yield, :class:`~lead_s2r.shards.ManifestCheck`)."""
    folder = Path(path)
    if not (folder / MANIFEST).is_file():
        raise ShardError(
            f"{folder / MANIFEST} not found: evaluation splits samples over ranks by the manifest; "
            "point the data at a folder written by `lead-s2r convert`"
        )
    rows = load_manifest(folder, columns=("key", "shard", "split")).to_pylist()
    wanted = None if splits is None else set(splits)
    kept = [row for row in rows if wanted is None or row["split"] in wanted]
    kept.sort(key=lambda row: row["shard"])  # stable: manifest order within a shard
    listed = keys_by_shard(folder, rows)
    check_listed_shards(listed)
    return [(str(folder / SHARD_DIR / row["shard"]), row["key"]) for row in kept], listed


class SampleShare:
    """One rank's contiguous share of the evaluation samples, shared again over its dataloader workers.

    :meth:`shards` starts a pipeline (the shards to open); calling the share on the opened samples keeps this
    worker's keys.
    """

    def __init__(self, samples: Sequence[tuple[str, str]], rank: int, world_size: int) -> None:
        self.samples = share(samples, rank, world_size)

    def mine(self) -> list[tuple[str, str]]:
        return share(self.samples, *worker_info())

    def shards(self) -> Iterator[dict[str, str]]:
        return iter([{"url": shard} for shard in dict.fromkeys(shard for shard, _ in self.mine())])

    def __call__(self, samples: Iterator[dict[str, Any]]) -> Iterator[dict[str, Any]]:
        keys = {key for _, key in self.mine()}
        return (sample for sample in samples if sample["__key__"] in keys)
