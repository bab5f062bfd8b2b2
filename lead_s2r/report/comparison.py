"""Two runs on the same data, sample by sample: where run B wins and where it loses against run A.

Per metric both runs scored (same versioned metric on the same dataset), the headline column of each sample
(``run_outputs.HEADLINES``: the PDMS / EPDMS score, RFS, ADE) is compared; a difference larger than ``threshold`` in the
metric's better direction is a win for B, in the other a loss. Samples only one run scored are counted, not compared.
"""

from dataclasses import dataclass
from pathlib import Path
from typing import Any

from lead_s2r.report.run_outputs import HEADLINES, MetricScores, RunOutputs
from lead_s2r.report.sample_page import draw_sample


@dataclass(frozen=True)
class Difference:
    """One sample of one metric where the runs differ: the values of A and B and B's gain (positive: B better)."""

    metric: str
    key: str
    a: float
    b: float
    gain: float


def paired_metrics(a: RunOutputs, b: RunOutputs) -> list[tuple[MetricScores, MetricScores]]:
    """The metric outputs both runs hold, matched by label (metric and dataset)."""
    theirs = {scores.label: scores for scores in b.scores}
    return [(mine, theirs[mine.label]) for mine in a.scores if mine.label in theirs and mine.family in HEADLINES]


def differences(a: RunOutputs, b: RunOutputs, threshold: float = 1e-9) -> list[Difference]:
    """Every (metric, sample) where B's headline differs from A's by more than ``threshold``, largest first."""
    found = []
    for mine, theirs in paired_metrics(a, b):
        higher_is_better = HEADLINES[mine.family][1]
        for key in mine.rows.keys() & theirs.rows.keys():
            value_a, value_b = mine.headline(key), theirs.headline(key)
            if value_a is None or value_b is None or abs(value_b - value_a) <= threshold:
                continue
            gain = value_b - value_a if higher_is_better else value_a - value_b
            found.append(Difference(mine.label, key, value_a, value_b, gain))
    return sorted(found, key=lambda d: (-abs(d.gain), d.metric, d.key))


def unmatched(a: RunOutputs, b: RunOutputs) -> dict[str, int]:
    """Per paired metric, how many samples only one of the runs scored."""
    return {mine.label: len(mine.rows.keys() ^ theirs.rows.keys()) for mine, theirs in paired_metrics(a, b)}


def pair_view(sample: dict[str, Any], a: RunOutputs, b: RunOutputs, site: Path) -> dict[str, Any]:
    """The side-by-side page of one sample: A's and B's prediction drawn together over the same BEV and cameras,
    and both runs' headline values per metric."""
    key = sample["__key__"]
    images = draw_sample(sample, {f"A {a.name}": a, f"B {b.name}": b}, site, f"pair_{key}")
    rows = [(mine.label, mine.headline(key), theirs.headline(key)) for mine, theirs in paired_metrics(a, b)]
    return {"key": key, "images": images, "rows": rows}
