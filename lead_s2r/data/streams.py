"""Which samples each rank and dataloader worker reads, and in what order: seeded training streams over disjoint
rank shares, sample-split evaluation streams.

Training splits a source's samples over the ranks anew each epoch, then each rank draws shards with replacement from
its own share and shuffles samples in a buffer: within an epoch no two ranks train on the same sample (drawing the
whole source on every rank would let two ranks take the same sample into one optimizer step). Every rank computes
the same split, from (seed, epoch, source) alone: the shard order is shuffled and the sample list rotated by a
random offset, then cut into contiguous runs (:func:`share`), so a rank opens whole shards where a source has many
and a part of each shard where it has few, and a one-shard source still gives each rank other samples each epoch.
A rank draws a shard in proportion to the samples of its share in it, so each of those samples is equally likely.
Dataloader workers of one rank draw from its share with seeds of their own.

Webdataset's own resampler mixes the clock, the pid and ``os.urandom`` into its seed, and its shuffle seeds from the
clock, so two runs with the same ``seed_everything`` draw different batches. Here both generators are seeded from
(seed, epoch, rank, worker, source, purpose) and nothing else: the same seed gives the same batches, and a run
resumed at an epoch boundary draws what the uninterrupted run would have drawn next (the epoch is part of the seed,
not a counter that lives in memory).
The rank is passed in from the trainer because dataloader workers do not always see ``torch.distributed`` or a
``RANK`` variable; the worker comes from ``torch.utils.data.get_worker_info`` when the stream starts.

Evaluation splits by sample, not by shard: webdataset's ``split_by_node`` hands out whole shards (two ranks of a
one-shard split get 35 and 0 samples) and its default ``single_node_only`` refuses to run under DDP. The manifest
lists every sample with its shard and split, so each rank, and each worker within it, gets a contiguous run of the
selected samples (35 -> 18 + 17) and opens only the shards that hold it. The same manifest read lists every key
of every shard, which each opened tar is held to (a corrupt header mid-tar would otherwise end it silently).
"""

import itertools
import random
import zlib
from collections import Counter
from collections.abc import Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch.utils.data
import webdataset as wds

from lead_s2r.shards import keys_by_shard, listed_samples


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


def seeded_shuffle(size: int, seed: StreamSeed, samples: Iterator[dict[str, Any]]) -> Iterator[dict[str, Any]]:
    """``samples`` through a webdataset shuffle buffer of ``size`` with a generator from ``seed``, not the clock."""
    return wds.shuffle(size, rng=seed.rng("shuffle"))(samples)


def share(items: Sequence[Any], part: int, parts: int) -> list[Any]:
    """The ``part``-th of ``parts`` contiguous runs of ``items``; lengths differ by at most one, longer runs first."""
    n = len(items)
    return list(items[-(-part * n // parts) : -(-(part + 1) * n // parts)])


def manifest_samples(
    path: str | Path, splits: Sequence[str] | None
) -> tuple[list[tuple[str, str]], dict[str, list[str]]]:
    """(shard path, key) of every sample of a converted folder in the wanted splits, in shard order; and every key
    the manifest lists per shard, all splits (what a tar must yield, :class:`~lead_s2r.shards.ManifestCheck`)."""
    rows = listed_samples(Path(path), ("split",))
    wanted = None if splits is None else set(splits)
    kept = [(row["shard"], row["key"]) for row in rows if wanted is None or row["split"] in wanted]
    return kept, keys_by_shard((row["shard"], row["key"]) for row in rows)


class SampleShare:
    """One rank's contiguous share of the evaluation samples, shared again over its dataloader workers: :meth:`shards`
    starts a pipeline (the shards to open); calling the share on the opened samples keeps this worker's keys."""

    def __init__(self, samples: Sequence[tuple[str, str]], rank: int, world_size: int) -> None:
        self.samples = share(samples, rank, world_size)

    def mine(self) -> list[tuple[str, str]]:
        return share(self.samples, *worker_info())

    def shards(self) -> Iterator[dict[str, str]]:
        return iter([{"url": shard} for shard in dict.fromkeys(shard for shard, _ in self.mine())])

    def __call__(self, samples: Iterator[dict[str, Any]]) -> Iterator[dict[str, Any]]:
        keys = {key for _, key in self.mine()}
        return (sample for sample in samples if sample["__key__"] in keys)


class TrainShare:
    """One rank's share of a source's training samples in one epoch, drawn with replacement: :meth:`shards` starts a
    training pipeline (an endless stream of shards to open, each drawn in proportion to the samples of this share it
    holds); calling the share on the opened samples keeps this share's."""

    def __init__(self, samples: Sequence[tuple[str, str]], seed: StreamSeed, world_size: int) -> None:
        order = random.Random(stream_seed(seed.seed, seed.epoch, seed.source, "ranks"))  # the same on every rank
        by_shard = keys_by_shard(samples)
        shards = list(by_shard)
        order.shuffle(shards)
        ordered = [(shard, key) for shard in shards for key in by_shard[shard]]
        offset = order.randrange(len(ordered)) if ordered else 0
        self.samples = share(ordered[offset:] + ordered[:offset], seed.rank, world_size)
        self.seed = seed
        counts = Counter(shard for shard, _ in self.samples)
        self.urls = list(counts)
        self.cumulative = list(itertools.accumulate(counts.values()))

    def shards(self) -> Iterator[dict[str, str]]:
        if not self.urls:
            raise ValueError(f"source {self.seed.source!r}: rank {self.seed.rank} has no training samples to draw")
        rng = self.seed.rng("shards")
        while True:
            yield {"url": rng.choices(self.urls, cum_weights=self.cumulative)[0]}

    def __call__(self, samples: Iterator[dict[str, Any]]) -> Iterator[dict[str, Any]]:
        mine = set(self.samples)
        return (sample for sample in samples if (sample["__url__"], sample["__key__"]) in mine)
