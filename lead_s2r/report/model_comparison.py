"""Two models over their seeds, scene by scene: where model B loses to model A, by how much, on which sub-score.

A model is every run whose id ends with the given path (``ltfv6`` matches ``runs/navsim/ltfv6`` and
``runs/wod/ltfv6``, as a table row matches its runs: :func:`lead_s2r.report.tables.matches`), so one comparison spans
the datasets a model was scored on. Per metric (versioned metric on a dataset) and scene, each model's headline
(``run_outputs.HEADLINES``) and sub-scores are averaged over the seeds **both** models scored the scene with: a seed
only one of them has would compare a lucky seed with an average. A scene's tags come from the converted data's
manifest; the subsets a run scored on their own (``lead-s2r score --tag``, the quickstart's "needs perception"
scenes) are summarised first, since those are the scenes the table's question is about.
"""

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from lead_s2r.errors import UserError
from lead_s2r.report.comparison import paired_metrics
from lead_s2r.report.run_outputs import HEADLINES, MetricScores, RunOutputs
from lead_s2r.report.sample_page import is_score, named_failures, sub_scores
from lead_s2r.report.tables import Run, id_ends_with

ALL_SCENES = "all scenes"


@dataclass(frozen=True)
class Model:
    """The runs of one model as ``(seed, run)``, named by the path they were selected with."""

    name: str
    runs: tuple[tuple[int, RunOutputs], ...]


def select_model(runs: dict[Path, RunOutputs], found: list[Run], name: str) -> Model:
    """The scored ``runs`` (by folder) whose id (``found``: the runs ``lead-s2r table`` sees) ends with ``name``; none
    is a :class:`UserError` that lists the models there are."""
    chosen = tuple((run.seed, runs[run.path]) for run in found if run.path in runs and id_ends_with(run.run_id, name))
    if not chosen:
        known = sorted({"/".join(Path(run.run_id).parts[-2:]) for run in found})
        raise UserError(f"--compare {name}: no scored run of that name; the runs are {', '.join(known)}")
    return Model(name, chosen)


@dataclass(frozen=True)
class SceneDelta:
    """One scene of one metric both models scored: the means over the shared seeds, B's gain (positive: B better),
    the sub-score B loses most on and by how much (its gain, negative), and what B's runs failed on."""

    metric: str
    family: str
    dataset: str
    key: str
    tags: tuple[str, ...]
    seeds: tuple[int, ...]
    a: float
    b: float
    gain: float
    sub_score: str
    sub_gain: float
    failures: tuple[str, ...]


def scene_deltas(a: Model, b: Model, tags: dict[str, list[str]]) -> list[SceneDelta]:
    """Every (metric, scene) both models scored on a shared seed: the scenes of the subsets the runs scored on their own
    first (:func:`subset_tags`), scores before errors (PDMS before ADE), then per metric B's largest losses first."""
    subsets = set(subset_tags([a, b]))
    by_scene: dict[tuple[str, str], list[tuple[int, MetricScores, MetricScores]]] = {}
    for seed, mine in sorted(a.runs, key=lambda entry: entry[0]):
        for scores_a, scores_b in (pair for s, theirs in b.runs if s == seed for pair in paired_metrics(mine, theirs)):
            for key in sorted(scores_a.rows.keys() & scores_b.rows.keys()):
                if scores_a.headline(key) is not None and scores_b.headline(key) is not None:
                    by_scene.setdefault((scores_a.label, key), []).append((seed, scores_a, scores_b))
    deltas = [_delta(label, key, seeds, tags.get(key, [])) for (label, key), seeds in by_scene.items()]
    return sorted(
        deltas, key=lambda d: (not subsets & set(d.tags), not HEADLINES[d.family][1], d.metric, d.gain, d.key)
    )


def _delta(label: str, key: str, seeds: list[tuple[int, MetricScores, MetricScores]], tags: list[str]) -> SceneDelta:
    first = seeds[0][1]
    sign = 1.0 if HEADLINES[first.family][1] else -1.0
    mean_a = float(np.mean([scores_a.headline(key) for _, scores_a, _ in seeds]))
    mean_b = float(np.mean([scores_b.headline(key) for _, _, scores_b in seeds]))
    gains: dict[str, list[float]] = {}
    kinds: dict[str, None] = {}
    for _, scores_a, scores_b in seeds:
        row_a, row_b = scores_a.rows[key], scores_b.rows[key]
        for column in sub_scores(first.family):
            value, other = row_b.get(column), row_a.get(column)
            if is_score(column, value) and value is not None and isinstance(other, int | float):
                gains.setdefault(column, []).append(sign * (float(value) - float(other)))
        kinds.update(dict.fromkeys(kind for kind, _ in named_failures(scores_b, row_b)))
    mean_gains = {column: float(np.mean(values)) for column, values in gains.items() if np.isfinite(values).all()}
    column = min(mean_gains, key=lambda c: (mean_gains[c], c), default="")
    sub_gain = mean_gains.get(column, 0.0)
    return SceneDelta(
        label,
        first.family,
        first.dataset,
        key,
        tuple(tags),
        tuple(seed for seed, _, _ in seeds),
        mean_a,
        mean_b,
        sign * (mean_b - mean_a),
        column if sub_gain < 0 else "",
        min(sub_gain, 0.0),
        tuple(kinds),
    )


@dataclass(frozen=True)
class SubsetSummary:
    """One metric on one subset of scenes (a tag, or every scene): the models' means, B's mean gain, how many scenes
    B loses and wins, and the sub-score whose mean B loses most on."""

    subset: str
    metric: str
    scenes: int
    a: float
    b: float
    gain: float
    lost: int
    won: int
    sub_score: str
    sub_gain: float


def subset_summaries(deltas: list[SceneDelta], subsets: list[str], threshold: float) -> list[SubsetSummary]:
    """Per subset tag (in the order given) then every scene, per metric: what :class:`SubsetSummary` holds."""
    summaries = []
    for subset in [*subsets, ALL_SCENES]:
        chosen = [d for d in deltas if subset == ALL_SCENES or subset in d.tags]
        for metric in dict.fromkeys(d.metric for d in chosen):
            rows = [d for d in chosen if d.metric == metric]
            by_sub: dict[str, list[float]] = {}
            for row in rows:
                if row.sub_score:
                    by_sub.setdefault(row.sub_score, []).append(row.sub_gain)
            worst = min(by_sub, key=lambda c: (sum(by_sub[c]), c), default="")
            summaries.append(
                SubsetSummary(
                    subset,
                    metric,
                    len(rows),
                    float(np.mean([r.a for r in rows])),
                    float(np.mean([r.b for r in rows])),
                    float(np.mean([r.gain for r in rows])),
                    sum(r.gain < -threshold for r in rows),
                    sum(r.gain > threshold for r in rows),
                    worst,
                    sum(by_sub.get(worst, [])) / len(rows) if worst else 0.0,
                )
            )
    return summaries


def subset_tags(models: list[Model]) -> list[str]:
    """The tags the models' runs scored subsets with (``lead-s2r score --tag``), in first-seen order."""
    return list(dict.fromkeys(tag for model in models for _, run in model.runs for tag in run.subsets))
