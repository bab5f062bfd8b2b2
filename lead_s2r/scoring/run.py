"""Score a predictions file against converted data: the body of ``lead-s2r score``.

A predictions file may hold several datasets: each folder scores the predictions of its own dataset(s), the
others are counted in ``other_datasets``. Samples without a prediction are listed in ``unpredicted`` and, with
``allow_missing=True`` (the CLI's default; ``--strict`` turns it off), left out of the scores. ``split`` and ``tag``
choose the samples scored (a tag of ``meta.tags``, e.g. ``scene_filter:pedestrians_ahead``): one selection, before
the scorer sees anything, so a subset's aggregates are computed exactly as the whole set's.
"""

import contextlib
import inspect
import time
from pathlib import Path
from typing import Any

from lead_s2r import __version__
from lead_s2r.errors import UserError
from lead_s2r.predictions import read_predictions, write_predictions
from lead_s2r.processes import Executor
from lead_s2r.registry import SCORER_GROUP, load
from lead_s2r.schema import SchemaError
from lead_s2r.scoring.base import Scorer, coverage
from lead_s2r.scoring.scores_file import ScoresFile
from lead_s2r.shards import (
    listed_keys,
    listed_samples,
    read_part,
    read_samples,
    shard_parts,
)

#: Samples one job of a parallel read decodes: NAVSIM's take 4 ms each, a job's messages a few ms.
SAMPLES_PER_READ = 64


def planner_predictions(planner: str, data: Path | list[Path], path: Path, split: str | None = None) -> Path:
    """Write the predictions of a model-free planner (``lead_s2r.scoring.baselines.PLANNERS``) on the samples of
    ``data`` to ``path``. Samples without the field the planner needs (a test split's future) get no prediction."""
    from lead_s2r.scoring.baselines import PLANNER_NEEDS, PLANNERS

    if planner not in PLANNERS:
        raise ValueError(f"unknown planner {planner!r}; choose one of {sorted(PLANNERS)}")
    predict, needs = PLANNERS[planner], PLANNER_NEEDS.get(planner)
    folders = _folders(data)
    samples = choose_samples(folders, ("future",), split)[0]
    try:
        predictions = [predict(s) for s in samples if needs is None or needs in s]
    except SchemaError as err:  # the data's own values, not a planner's mistake: name where they are
        where = ", ".join(map(str, folders))
        raise UserError(f"{where}: {err} (lead-s2r inspect {where} lists every such sample)") from None
    return write_predictions(path, predictions)


def _folders(data: Path | list[Path]) -> list[Path]:
    return [Path(folder) for folder in (data if isinstance(data, list | tuple) else [data])]


class SampleCache(dict[tuple[Any, ...], tuple[list[dict[str, Any]], set[str]]]):
    """What :func:`choose_samples` chose, by folders, fields, split and tag, kept for later scorings in this process:
    the quickstart scores some twenty prediction sets against the same held-out samples, whose decoding was a fifth
    of its time. The folders must not change while the cache lives. Scorers share the samples, so a scorer must only
    read them (the quickstart's PDMS, EPDMS, ADE and RFS print the same table with the cache as without)."""


def choose_samples(
    folders: list[Path],
    fields: tuple[str, ...],
    split: str | None,
    executor: Executor | None = None,
    tag: str | None = None,
    cache: SampleCache | None = None,
) -> tuple[list[dict[str, Any]], set[str]]:
    """The samples of ``folders`` of ``split`` (a folder converted from a whole dataset holds several) with ``tag`` in
    ``meta.tags``, each if given, in shard order, and the keys of ``split``'s samples passed over for want of ``tag``.

    A folder's manifest says which samples those are, so only they are decoded: NAVSIM's scoring context costs
    about 4 ms a sample, and a held-out split or a tag is a fraction of a folder. ``executor`` decodes them (decoding
    costs about a tenth of scoring: left to the driver, it would bound what more workers gain). A folder of tars
    without a manifest is decoded whole and chosen from after.
    """
    key = (tuple(str(Path(folder).resolve()) for folder in folders), tuple(fields), split, tag)
    if cache is not None and key in cache:
        return cache[key]
    entries = [entry for folder in folders for entry in sample_listing(folder, fields)]
    in_split = [entry for entry in entries if split is None or entry["split"] == split]
    if not in_split:
        held = sorted({entry["split"] for entry in entries})
        raise UserError(f"--split {split}: {', '.join(map(str, folders))} holds no such split; it holds {held}")
    chosen = [entry for entry in in_split if tag is None or tag in entry["tags"]]
    if not chosen:
        held = sorted({t for entry in in_split for t in entry["tags"]})
        raise UserError(f"--tag {tag}: no sample of {', '.join(map(str, folders))} has it; their tags: {held}")
    passed_over = {entry["key"] for entry in in_split} - {entry["key"] for entry in chosen}
    result = decode_listed(chosen, fields, executor), passed_over
    if cache is not None:
        cache[key] = result
    return result


def sample_listing(folder: Path, fields: tuple[str, ...]) -> list[dict[str, Any]]:
    """A folder's samples as entries (``key``, ``split``, ``tags``, and ``shard`` or the decoded ``sample``): from
    its manifest, or, for a folder of tars without one, from every sample decoded."""
    if listed_keys(folder) is None:
        return [
            {"key": s["__key__"], "split": s["meta"]["split"], "tags": s["meta"].get("tags") or (), "sample": s}
            for s in read_samples(folder, fields=fields)
        ]
    return [row | {"tags": row["tags"] or ()} for row in listed_samples(folder, ("split", "tags"))]


def decode_listed(
    chosen: list[dict[str, Any]], fields: tuple[str, ...] | None, executor: Executor | None = None
) -> list[dict[str, Any]]:
    """The samples of ``chosen`` entries (:func:`sample_listing`'s), in their order: decoded already, or read from
    their shards in parts of consecutive chosen samples (``fields`` None: every field)."""
    if chosen and "sample" in chosen[0]:
        return [entry["sample"] for entry in chosen]
    parts = [(shard, keys, fields, offset) for shard, keys, offset in shard_parts(chosen, SAMPLES_PER_READ)]
    decoded = executor.map(read_part, parts, per_job=1) if executor is not None else (read_part(*p) for p in parts)
    return [sample for part in decoded for sample in part]


def make_scorer(metric: str, **config: Any) -> Scorer:
    """The scorer registered under ``metric`` (e.g. ``rfs@wod-e2e-2025``, ``ade``), configured."""
    cls = load(metric, SCORER_GROUP)
    try:
        return cls(**config)
    except (TypeError, ValueError) as err:  # a scorer's constructor validates its options
        raise UserError(
            f"--metric {metric}: bad --option ({err}); it takes {', '.join(scorer_options(cls))} (see docs/metrics.md)"
        ) from None


def scorer_options(cls: type[Scorer]) -> list[str]:
    """The ``--option`` names a scorer takes: its default configuration's keys (a metric's constants included),
    or its constructor's parameters when it has no default configuration."""
    try:
        return [name for name in cls().config() if name != "allow_missing"]
    except (TypeError, ValueError):
        parameters = inspect.signature(cls).parameters.values()
        return [p.name for p in parameters if p.kind not in (p.VAR_KEYWORD, p.VAR_POSITIONAL)]


def score_predictions(
    metric: str,
    predictions: Path,
    data: Path | list[Path],
    out: Path,
    split: str | None = None,
    executor: Executor | None = None,
    tag: str | None = None,
    sample_cache: SampleCache | None = None,
    **config: Any,
) -> dict[str, Any]:
    """Score ``predictions`` (predictions.parquet) against one or more converted folders.

    Writes ``out/scores.parquet`` (one row per scored sample) and ``out/scores.json`` and returns the latter's content.
    Without ``allow_missing=True`` in ``config`` an unpredicted sample is an error
    (:func:`~lead_s2r.scoring.base.join`). With or without ``executor`` the files are the same bytes, but the
    ``seconds`` of scores.json.
    """
    scorer = make_scorer(metric, **config)
    scorer.executor = executor
    folders = _folders(data)
    start = time.perf_counter()
    with executor.session() if executor is not None else contextlib.nullcontext():  # one Ray connection
        samples, passed_over = choose_samples(folders, scorer.fields, split, executor, tag, sample_cache)
        # a prediction of a sample the tag passed over is no sign of mismatched data (one of no sample at all still is)
        predicted = [p for p in read_predictions(predictions) if p.key not in passed_over]
        _check_metric_fits(scorer, folders, samples)
        covered = coverage(predicted, samples)
        if len(covered["unpredicted"]) == len(samples):
            datasets = sorted({sample["meta"]["dataset"] for sample in samples})
            raise UserError(
                f"{predictions}: no prediction for any sample of {', '.join(map(str, folders))} (datasets {datasets}); "
                "check that --predictions and --data belong together"
            )
        result = scorer.score(predicted, samples)
    report = {
        "metric": scorer.name,
        "metric_version": scorer.version,
        "package_version": __version__,
        "config": scorer.config(),
        "predictions": str(predictions),
        "data": [str(folder) for folder in folders],
        "split": split,
        "tag": tag,
        "aggregates": result.aggregates,
        "unpredicted": {"count": len(covered["unpredicted"]), "keys": covered["unpredicted"]},
        "other_datasets": covered["other_datasets"],
        "seconds": round(time.perf_counter() - start, 3),
    }
    out = Path(out)
    report = ScoresFile(out, report, result.table).write()
    scorer.write_files(result, out)
    return report


def _check_metric_fits(scorer: Scorer, folders: list[Path], samples: list[dict[str, Any]]) -> None:
    """A metric asked of data it is not defined on (RFS on data without raters, PDMS on WOD-E2E) scores nothing:
    an error naming the datasets, not a scores.json of null aggregates."""
    datasets = sorted({sample["meta"]["dataset"] for sample in samples})
    if not scorer.scores_any(samples):
        wrong_dataset = scorer.datasets is not None and not set(datasets) & set(scorer.datasets)
        needs = f"datasets {list(scorer.datasets)}" if wrong_dataset else f"samples with {list(scorer.required)}"
        raise UserError(
            f"--metric {scorer.name} scores {needs}, but {', '.join(map(str, folders))} holds datasets {datasets} "
            "without them; choose the metric of that dataset (docs/metrics.md) or other --data"
        )
