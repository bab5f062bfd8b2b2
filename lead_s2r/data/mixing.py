"""Per-source batch composition over epochs: how much synthetic data each step sees, on every rank.

LEAD's sim-to-real schedule mixes CARLA into the real-data batches with a share that halves at each cosine
warm-restart boundary and reaches zero at epoch 31, after which training is real-only (a fine-tune inside one
run). Its code hard-codes a global batch of 64 and two sources; this generalises it to any anchor table, any
batch size and any world size, with exact integer batch sizes per rank.
"""

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Literal

#: LEAD's Sim2RealSampleScheduler anchors: epoch -> (sim, real) samples of a global batch of 64.
LEAD_SIM2REAL_ANCHORS = {0: (40, 24), 1: (32, 32), 3: (24, 40), 7: (16, 48), 15: (8, 56), 31: (0, 64)}


def largest_remainder(shares: Mapping[str, float], total: int) -> dict[str, int]:
    """Integers proportional to ``shares`` that sum to ``total``, each within one of its exact value: leftover units go
    to the largest fractional parts, ties to the source listed first, so every rank gets the same answer."""
    weight = sum(shares.values())
    if weight <= 0:
        raise ValueError(f"shares must have a positive sum, got {dict(shares)}")
    exact = {name: total * share / weight for name, share in shares.items()}
    counts = {name: int(value) for name, value in exact.items()}
    order = sorted(exact, key=lambda name: (-(exact[name] - counts[name]), list(exact).index(name)))
    for name in order[: total - sum(counts.values())]:
        counts[name] += 1
    return counts


@dataclass
class MixingSchedule:
    """Source composition of each batch as a function of the epoch.

    Args:
        anchors: ``{epoch: {source: weight}}``; a composition holds from its epoch until the next anchor
            (``mode="step"``, LEAD's behaviour) or blends linearly towards it (``mode="linear"``). Weights are
            relative; LEAD's table uses samples of its global batch.
        global_batch_size: samples per optimizer step over all ranks.
        mode: "step" or "linear".
    """

    anchors: dict[int, dict[str, float]]
    global_batch_size: int = 64
    mode: Literal["step", "linear"] = "step"

    def __post_init__(self) -> None:
        # epochs may arrive as strings (JSON, dumped configs)
        self.anchors = {int(epoch): dict(mix) for epoch, mix in sorted(self.anchors.items(), key=lambda i: int(i[0]))}
        if 0 not in self.anchors:
            raise ValueError("anchors must start at epoch 0")
        sources = list(self.anchors[0])
        for epoch, mix in self.anchors.items():
            if list(mix) != sources:
                raise ValueError(f"anchor at epoch {epoch} lists {list(mix)}; every anchor must list {sources}")
            if any(weight < 0 for weight in mix.values()) or sum(mix.values()) <= 0:
                raise ValueError(f"anchor at epoch {epoch}: weights must be >= 0 with a positive sum, got {mix}")
        if self.global_batch_size < 1:
            raise ValueError(f"global_batch_size must be positive, got {self.global_batch_size}")

    @classmethod
    def lead_sim2real(cls, sim: str, real: str, global_batch_size: int = 64) -> "MixingSchedule":
        """LEAD's sim-to-real table (40/24 -> ... -> 0/64 at epochs 0/1/3/7/15/31), scaled to any batch."""
        anchors = {epoch: {sim: float(s), real: float(r)} for epoch, (s, r) in LEAD_SIM2REAL_ANCHORS.items()}
        return cls(anchors, global_batch_size)

    @classmethod
    def constant(cls, weights: Mapping[str, float], global_batch_size: int = 64) -> "MixingSchedule":
        return cls({0: dict(weights)}, global_batch_size)

    @property
    def sources(self) -> list[str]:
        return list(self.anchors[0])

    def shares(self, epoch: int) -> dict[str, float]:
        """The fraction of each source at ``epoch`` (before rounding to samples); sums to 1."""
        epochs = list(self.anchors)
        current = max(e for e in epochs if e <= epoch)
        mix = _normalised(self.anchors[current])
        later = [e for e in epochs if e > epoch]
        if self.mode == "linear" and later:
            target = _normalised(self.anchors[later[0]])
            alpha = (epoch - current) / (later[0] - current)
            mix = {source: (1 - alpha) * share + alpha * target[source] for source, share in mix.items()}
        return mix

    def batch_sizes(self, epoch: int, world_size: int = 1) -> dict[str, int]:
        """Samples of each source in one rank's batch at ``epoch``, the same on every rank; they sum to
        ``global_batch_size / world_size`` exactly, so the global batch is preserved."""
        if world_size < 1 or self.global_batch_size % world_size:
            raise ValueError(f"global_batch_size {self.global_batch_size} must be divisible by world_size {world_size}")
        return largest_remainder(self.shares(epoch), self.global_batch_size // world_size)


def _normalised(mix: Mapping[str, float]) -> dict[str, float]:
    total = sum(mix.values())
    return {source: weight / total for source, weight in mix.items()}
