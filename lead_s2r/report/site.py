"""``lead-s2r report``: a static site over scored runs that opens offline, from the file system.

One run (``lead-s2r report RUN``): ``DIR/index.html`` (summary), ``DIR/samples/<key>.html`` (one per sample shown),
``DIR/comparison.html`` and ``DIR/compare/<key>.html`` with a baseline run. Many runs (``--runs 'runs/*/*/seed*'``):
``DIR/index.html`` lists every run with its headline scores (mean ± std over seeds, computed by
:mod:`lead_s2r.report.tables` as ``lead-s2r table`` does), each run's own site under
``DIR/runs/<family>-<name>-seed<k>``, and with ``--compare A B`` model B against model A scene by scene
(:mod:`lead_s2r.report.model_comparison`) in ``DIR/models.html`` and ``DIR/models/<key>.html``. Every picture is
a PNG under an ``img`` folder; links are relative; the one script, ``table.js`` (ours, no library), sorts and filters
the sample lists in the page. Pages are rendered by jinja2 (autoescaped templates in ``report/templates``).

Shown by default: per metric with a headline (``run_outputs.HEADLINES``) the ``worst`` samples, then
:data:`RANDOM_SHOWN` random others (fixed seed) so the good cases are seen too (over many runs: the worst one per
metric and no random ones, or the pages of forty runs take minutes). The site is written into a
temporary sibling folder and renamed into place at the end, so a failed report leaves ``DIR`` as it was.
"""

from collections.abc import Collection
from importlib import resources
from pathlib import Path
from typing import Any

import numpy as np
from jinja2 import Environment, PackageLoader, StrictUndefined

from lead_s2r.errors import UserError
from lead_s2r.files import staged_folder, write_text
from lead_s2r.report.comparison import Difference, differences, pair_view, unmatched
from lead_s2r.report.model_comparison import (
    Model,
    SceneDelta,
    scene_deltas,
    select_model,
    subset_summaries,
    subset_tags,
)
from lead_s2r.report.overview import headline_tables
from lead_s2r.report.run_outputs import HEADLINES, RunOutputs, load_run, load_samples, sample_tags
from lead_s2r.report.sample_page import draw_sample, named_failures, sample_view
from lead_s2r.report.summary import curves_figure, flat_numbers, histograms
from lead_s2r.report.tables import Run, find_runs

RANDOM_SHOWN = 3
DEFAULT_WORST = 5
#: the sorting and filtering script every page with a sample list loads
SCRIPT = "table.js"


def choose_samples(
    run: RunOutputs, worst: int, keys: list[str] | None = None, seed: int = 0, random: int = RANDOM_SHOWN
) -> dict[str, str]:
    """``{key: why it is shown}``: ``keys`` when given (each must be scored in the run), else the worst per metric
    and ``random`` others."""
    scored = {key for scores in run.scores for key in scores.rows}
    if keys:
        unknown = [key for key in keys if key not in scored]
        if unknown:
            raise UserError(f"--samples: no scores of {run.path} list the sample {unknown[0]!r}")
        return dict.fromkeys(keys, "asked for (--samples)")
    chosen: dict[str, str] = {}
    for scores in run.scores:
        column, higher_is_better = HEADLINES.get(scores.family, (None, True))
        values = [(scores.headline(key), key) for key in sorted(scores.rows)]
        ranked = sorted(
            ((v, k) for v, k in values if v is not None), key=lambda vk: vk[0] * (1 if higher_is_better else -1)
        )
        for value, key in ranked[:worst]:
            side = "lowest" if higher_is_better else "largest"
            chosen.setdefault(key, f"{side} {column} of {scores.label} ({value:.3g})")
    rest = sorted(scored - chosen.keys())
    for index in sorted(np.random.default_rng(seed).permutation(len(rest))[:random].tolist()):
        chosen[rest[index]] = "a random pick, to show good cases too"
    return chosen


def existing(folders: list[Path], fix: str) -> list[Path]:
    """``folders``, each checked to exist (``fix``: what the error tells the user to do)."""
    missing = [folder for folder in folders if not folder.is_dir()]
    if missing:
        raise UserError(f"converted folder {missing[0]} does not exist; {fix}")
    return folders


def build_report(
    run: str | Path,
    out: str | Path,
    baseline: str | Path | None = None,
    data: list[Path] | None = None,
    worst: int = DEFAULT_WORST,
    samples: list[str] | None = None,
    threshold: float = 1e-9,
) -> Path:
    """Write the report of ``run`` (compared with ``baseline``) to ``out``; return ``out/index.html``."""
    _check_worst(worst)
    a = load_run(run)
    b = None if baseline is None else load_run(baseline)
    shown = choose_samples(a, worst, samples)
    changed = [] if b is None else differences(a, b, threshold)
    folders = [Path(folder) for folder in data] if data else a.data_folders()
    folders = existing(folders, "pass the run's converted data with --data")
    loaded = load_samples(folders, list(dict.fromkeys([*shown, *(d.key for d in changed)])))
    with staged_folder(Path(out)) as staging:
        pages = Pages(staging)
        pages.summary(a, shown, loaded, sample_tags(folders, shown), None if b is None else b.name)
        if b is not None:
            pages.comparison(a, b, changed, loaded, threshold)
    return Path(out) / "index.html"


def build_site(
    patterns: list[str],
    out: str | Path,
    compare: tuple[str, str] | None = None,
    worst: int = 1,
    random: int = 0,
    threshold: float = 1e-9,
) -> Path:
    """Write the report (module docstring) of every run ``patterns`` match (``runs/*/*/seed*``) to ``out``, with
    ``compare`` = (A, B) model B against model A; return ``out/index.html``."""
    _check_worst(worst)
    table_runs = find_runs(patterns)
    runs = {run.path: load_run(run.path) for run in table_runs if run.scores}
    folders = same_data(list(runs.values()))
    models = None if compare is None else [select_model(runs, table_runs, name) for name in compare]
    shown = {path: choose_samples(run, worst, random=random) for path, run in runs.items()}
    deltas = [] if models is None else scene_deltas(*models, sample_tags(folders, _scored_keys(models)))
    drawn = _pair_keys(deltas, worst, threshold)
    keys = {key for chosen in shown.values() for key in chosen} | {key for _, key in drawn}
    loaded = load_samples(folders, sorted(keys))
    tags = sample_tags(folders, keys)
    with staged_folder(Path(out)) as staging:
        for path, run in runs.items():
            Pages(staging / "runs" / run.slug, home="../../").summary(run, shown[path], loaded, tags, None)
        pages = Pages(staging)
        if models is not None:
            pages.models(models, deltas, drawn, loaded, threshold)
        pages.overview(table_runs, list(runs.values()), models)
    return Path(out) / "index.html"


def _check_worst(worst: int) -> None:
    if worst < 0:
        raise UserError(f"--worst {worst}: give the number of samples to show per metric (0 or more)")


def same_data(runs: Collection[RunOutputs]) -> list[Path]:
    """The converted folders the runs were scored on, once each; two runs that scored one metric on one dataset from
    different folders are a :class:`UserError` (their scenes are not the same scenes)."""
    seen: dict[str, tuple[frozenset[Path], RunOutputs]] = {}
    for run in runs:
        for scores in run.scores:
            folders = frozenset(Path(folder).resolve() for folder in scores.report.get("data", []))
            first = seen.setdefault(scores.label, (folders, run))
            if first[0] != folders:
                raise UserError(
                    f"{run.path}: scored {scores.label} on {sorted(map(str, folders))}, but "
                    f"{first[1].path} on {sorted(map(str, first[0]))}; report runs scored on the same data"
                )
    folders = list(dict.fromkeys(folder for run in runs for folder in run.data_folders()))
    return existing(folders, "the runs' scores.json name it as the data they were scored on")


def _scored_keys(models: list[Model]) -> set[str]:
    return {key for model in models for _, run in model.runs for scores in run.scores for key in scores.rows}


def _pair_keys(deltas: list[SceneDelta], worst: int, threshold: float) -> list[tuple[str, str]]:
    """(metric, key) of the scenes drawn side by side: per metric, the first ``worst`` scenes B loses (in
    :func:`scene_deltas`'s order: the scored subsets' scenes first, largest losses first)."""
    drawn: list[tuple[str, str]] = []
    for metric in dict.fromkeys(d.metric for d in deltas):
        drawn += [(metric, d.key) for d in deltas if d.metric == metric and d.gain < -threshold][:worst]
    return drawn


class Pages:
    """Renders the templates into a site folder; ``home``: the relative path from it to the site's root (where the
    script and, over many runs, the index of runs are; the root's pages write the script)."""

    def __init__(self, site: Path, home: str = "") -> None:
        self.site = site
        self.home = home
        if not home:
            (site / SCRIPT).write_bytes(resources.files("lead_s2r.report").joinpath("templates", SCRIPT).read_bytes())
        for folder in ("img", "samples"):
            (site / folder).mkdir(parents=True, exist_ok=True)
        self.env = Environment(loader=PackageLoader("lead_s2r.report", "templates"), autoescape=True,
                               undefined=StrictUndefined)  # fmt: skip

    def write(self, template: str, target: str, **context: Any) -> None:
        html = self.env.get_template(template).render(home=self.home, **context)
        write_text(self.site / target, html)

    def summary(
        self,
        run: RunOutputs,
        shown: dict[str, str],
        loaded: dict[str, Any],
        tags: dict[str, list[str]],
        baseline: str | None,
    ) -> None:
        """``index.html`` and one page per shown sample; the list has a row per sample and metric."""
        metrics = []
        for index, scores in enumerate(run.scores):
            histogram = f"img/histograms_{index}.png"
            metrics.append(
                {
                    "label": scores.label,
                    "metric": scores.metric,
                    "folder": scores.folder.relative_to(run.path).as_posix(),
                    "numbers": flat_numbers(scores.report.get("aggregates", {})),
                    "histogram": histogram if histograms(scores, self.site / histogram) else None,
                }
            )
        curves = "img/curves.png" if curves_figure(run.logs, self.site / "img" / "curves.png") else None
        listed = []
        for key, reason in shown.items():
            view = sample_view(loaded[key], run, self.site)
            self.write("sample.html", f"samples/{key}.html", title=f"{key} — {run.name}", view=view, reason=reason,
                       run=run.name)  # fmt: skip
            for scores in run.scores:
                if key in scores.rows:
                    listed.append(
                        {
                            "key": key,
                            "dataset": view.dataset,
                            "reason": reason,
                            "metric": scores.label,
                            "tags": tags.get(key, []),
                            "value": scores.headline(key),
                            "failures": [kind for kind, _ in named_failures(scores, scores.rows[key])],
                        }
                    )
        self.write("index.html", "index.html", title=f"Report: {run.name}", run=run.name, path=str(run.path),
                   metrics=metrics, curves=curves, samples=listed, config=run.config, comparison=baseline)  # fmt: skip

    def comparison(
        self, a: RunOutputs, b: RunOutputs, changed: list[Difference], loaded: dict[str, Any], threshold: float
    ) -> None:
        """``comparison.html`` and one side-by-side page per sample that differs."""
        for key in dict.fromkeys(d.key for d in changed):
            pair = pair_view(loaded[key], a, b, self.site)
            self.write("pair.html", f"compare/{key}.html", title=f"{key}: {a.name} vs {b.name}", pair=pair,
                       a=a.name, b=b.name, back="../comparison.html")  # fmt: skip
        self.write("comparison.html", "comparison.html", title=f"{b.name} against {a.name}", a=a.name, b=b.name,
                   threshold=threshold, unmatched=unmatched(a, b), wins=[d for d in changed if d.gain > 0],
                   losses=[d for d in changed if d.gain < 0])  # fmt: skip

    def models(
        self, models: list[Model], deltas: list[SceneDelta], drawn: list[tuple[str, str]], loaded: dict[str, Any],
        threshold: float,
    ) -> None:  # fmt: skip
        """``models.html``: model B against model A per subset and scene; ``models/<key>.html`` for the scenes B
        loses most (the first seed both scored, both plans drawn together)."""
        a, b = models
        pages = {}
        for metric, key in drawn:
            if key in pages:
                continue
            delta = next(d for d in deltas if d.metric == metric and d.key == key)
            run_a = next(run for seed, run in a.runs if seed == delta.seeds[0] and key in run.predictions)
            run_b = next(run for seed, run in b.runs if seed == delta.seeds[0] and key in run.predictions)
            images = draw_sample(loaded[key], {f"A {run_a.name}": run_a, f"B {run_b.name}": run_b}, self.site,
                                 f"models_{key}")  # fmt: skip
            rows = [(d.metric, d.a, d.b) for d in deltas if d.key == key]
            self.write("pair.html", f"models/{key}.html", title=f"{key}: {b.name} against {a.name}",
                       pair={"key": key, "images": images, "rows": rows}, a=run_a.name, b=run_b.name,
                       back="../models.html")  # fmt: skip
            pages[key] = f"models/{key}.html"
        summaries = subset_summaries(deltas, subset_tags(models), threshold)
        self.write("models.html", "models.html", title=f"{b.name} against {a.name}", a=_model_title(a),
                   b=_model_title(b), summaries=summaries, deltas=deltas, pages=pages, threshold=threshold)  # fmt: skip

    def overview(self, table_runs: list[Run], listed: list[RunOutputs], models: list[Model] | None) -> None:
        """``index.html`` over many runs: headline scores per model, the runs with links, the comparison."""
        self.write(
            "overview.html",
            "index.html",
            title=f"Report: {len(table_runs)} runs",
            families=headline_tables(table_runs),
            runs=[(run.name, f"runs/{run.slug}/index.html") for run in listed],
            unscored=[str(run.path) for run in table_runs if not run.scores],
            models=None if models is None else [_model_title(model) for model in models],
        )


def _model_title(model: Model) -> str:
    """``ltfv6 (navsim / ltfv6, wod / ltfv6; seeds 0, 1, 2)``."""
    names = dict.fromkeys(" / ".join(run.name.split(" / ")[:-1]) for _, run in model.runs)
    seeds = sorted({seed for seed, _ in model.runs})
    return f"{model.name} ({', '.join(names)}; seeds {', '.join(map(str, seeds))})"
