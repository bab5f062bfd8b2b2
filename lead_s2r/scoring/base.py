"""The scorer interface: predictions + converted samples -> a per-sample table and aggregates.

A scorer is registered by its versioned metric name in the ``lead_s2r.scorers`` entry-point group and names the
sample fields it reads (``meta`` always comes), so the data is decoded once with only what it needs.
"""

from abc import ABC, abstractmethod
from collections import Counter
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, ClassVar

import numpy as np
import pyarrow as pa

from lead_s2r.predictions import Prediction, PredictionError, group_by_key
from lead_s2r.processes import Executor

#: Samples per job of a scorer's executor: a PDM-scored sample takes 50 ms, its job's messages a few ms.
SAMPLES_PER_JOB = 8


@dataclass
class ScoreResult:
    """``table``: one row per scored sample (key, dataset, sub-scores); ``aggregates``: JSON-ready summary."""

    table: pa.Table
    aggregates: dict[str, Any]


class Scorer(ABC):
    """A versioned open-loop metric. Subclasses set ``name``, ``version`` and ``fields``."""

    name: ClassVar[str]
    version: ClassVar[str]
    #: sample fields read from the converted data besides ``meta``.
    fields: ClassVar[tuple[str, ...]]
    #: datasets the metric is defined on (None: all); the validation callback skips the others.
    datasets: ClassVar[tuple[str, ...] | None] = None
    #: fields without which a sample cannot be scored: data where no sample has them is the wrong data.
    required: ClassVar[tuple[str, ...]] = ()
    #: where :meth:`map_samples` runs the per-sample work (``lead-s2r score --workers / --executor``): this process
    #: when None. Not part of :meth:`config`: the scores are the same wherever they are computed.
    executor: Executor | None = None

    def __init__(self, allow_missing: bool = False) -> None:
        """``allow_missing``: score only the predicted samples instead of failing on unpredicted ones (off by
        default in Python, where a missing prediction is usually a bug; ``lead-s2r score`` turns it on unless
        ``--strict``, and lists the unpredicted samples in scores.json)."""
        self.allow_missing = allow_missing

    def scores_any(self, samples: Iterable[dict[str, Any]]) -> bool:
        """Whether some sample is of a dataset this metric is defined on and carries the fields it requires."""
        return any(
            (self.datasets is None or sample["meta"]["dataset"] in self.datasets)
            and all(name in sample for name in self.required)
            for sample in samples
        )

    def config(self) -> dict[str, Any]:
        """JSON-ready configuration, written next to the scores."""
        return {"allow_missing": self.allow_missing}

    def write_files(self, result: ScoreResult, out: Path) -> None:
        """Extra files beside scores.parquet / scores.json (e.g. a benchmark's own CSV); none by default."""
        return None

    def __getstate__(self) -> dict[str, Any]:
        """A scorer sent to a worker leaves its executor behind: the worker scores in place."""
        return {name: value for name, value in self.__dict__.items() if name != "executor"}

    def map_samples(self, function: Callable[..., Any], items: Sequence[tuple[Any, ...]]) -> list[Any]:
        """``[function(*item) for item in items]`` in order, spread over :attr:`executor` in jobs of
        :data:`SAMPLES_PER_JOB` items (``function`` and the items are pickled there: a bound method of the scorer
        is fine)."""
        if self.executor is None:
            return [function(*item) for item in items]
        return self.executor.map(function, items, SAMPLES_PER_JOB)

    @abstractmethod
    def score(self, predictions: Iterable[Prediction], data: Iterable[dict[str, Any]]) -> ScoreResult:
        """Score predictions against samples (dicts with ``__key__``, ``meta`` and :attr:`fields`)."""


def join(
    predictions: Iterable[Prediction], data: Iterable[dict[str, Any]], allow_missing: bool = False
) -> list[tuple[dict[str, Any], list[Prediction]]]:
    """Pair each sample with its predictions, in data order. Predictions of a dataset the data does not hold are left
    aside (one predictions file may cover several datasets, scored one folder at a time)."""
    data = list(data)
    groups = group_by_key(predictions)
    pairs, unpredicted = [], []
    for sample in data:
        key = sample["__key__"]
        frame = groups.pop(key, None)
        if frame is None:
            unpredicted.append(key)
            continue
        dataset = sample["meta"]["dataset"]
        for p in frame:
            if p.dataset != dataset:
                raise PredictionError(f"prediction {key!r}: dataset {p.dataset!r} but the sample is {dataset!r}")
        pairs.append((sample, frame))
    held = _datasets(data)
    unknown = [key for key, frame in groups.items() if frame[0].dataset in held]
    if unknown:
        raise PredictionError(
            f"prediction {unknown[0]!r} has no sample in the data although it holds its dataset "
            f"{groups[unknown[0]][0].dataset!r} ({len(unknown)} such key(s)); is --data the right split?"
        )
    if unpredicted and not allow_missing:
        raise PredictionError(
            f"sample {unpredicted[0]!r} has no prediction ({len(unpredicted)} such sample(s)); "
            "leave out --strict (lead-s2r score) or pass allow_missing=True (Python) to score only the predicted ones"
        )
    return pairs


def coverage(predictions: Iterable[Prediction], data: Iterable[dict[str, Any]]) -> dict[str, Any]:
    """Which samples have no prediction, and how many predictions belong to datasets the data does not hold:
    ``{"unpredicted": [key, ...] in data order, "other_datasets": {dataset: predictions}}``."""
    data = list(data)
    predictions = list(predictions)
    predicted = {p.key for p in predictions}
    held = _datasets(data)
    other = dict(Counter(p.dataset for p in predictions if p.dataset not in held))
    return {"unpredicted": [s["__key__"] for s in data if s["__key__"] not in predicted], "other_datasets": other}


def _datasets(data: Iterable[dict[str, Any]]) -> set[str]:
    return {sample["meta"]["dataset"] for sample in data}


def mean_or_none(values: Sequence[float] | np.ndarray) -> float | None:
    """Mean of the finite values, None when there are none (JSON has no NaN)."""
    values = np.asarray(values, np.float64)
    values = values[np.isfinite(values)]
    return float(values.mean()) if len(values) else None
