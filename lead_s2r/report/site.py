"""``lead-s2r report``: a static site over one scored run (and optionally a baseline run) that opens offline.

``DIR/index.html`` (summary), ``DIR/samples/<key>.html`` (one per sample shown), ``DIR/comparison.html`` and
``DIR/compare/<key>.html`` with a baseline, every picture a PNG under ``DIR/img``; no script, no network, only
relative links. Pages are rendered by jinja2 (autoescaped templates in ``report/templates``).

Shown by default: per metric with a headline (``run_outputs.HEADLINES``) the ``worst`` samples, then
:data:`RANDOM_SHOWN` random others (fixed seed) so the good cases are seen too. The site is written into a
temporary sibling folder and renamed into place at the end, so a failed report leaves ``DIR`` as it was.
"""

import shutil
import tempfile
from pathlib import Path
from typing import Any

import numpy as np
from jinja2 import Environment, PackageLoader, StrictUndefined

from lead_s2r.errors import UserError
from lead_s2r.files import replace_folder
from lead_s2r.report.comparison import Difference, differences, pair_view, unmatched
from lead_s2r.report.run_outputs import HEADLINES, RunOutputs, load_run, load_samples
from lead_s2r.report.sample_page import sample_view
from lead_s2r.report.summary import curves_figure, flat_numbers, histograms

RANDOM_SHOWN = 3
DEFAULT_WORST = 5


def choose_samples(run: RunOutputs, worst: int, keys: list[str] | None = None, seed: int = 0) -> dict[str, str]:
    """``{key: why it is shown}``: ``keys`` when given (each must be scored in the run), else the worst per metric
    and a few random others."""
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
    for index in sorted(np.random.default_rng(seed).permutation(len(rest))[:RANDOM_SHOWN].tolist()):
        chosen[rest[index]] = "a random pick, to show good cases too"
    return chosen


def data_folders(run: RunOutputs, data: list[Path] | None) -> list[Path]:
    """``--data`` when given, else the folders the run's scores.json record (each must exist)."""
    folders = [Path(folder) for folder in data] if data else run.data_folders()
    missing = [folder for folder in folders if not folder.is_dir()]
    if missing:
        raise UserError(f"converted folder {missing[0]} does not exist; pass the run's converted data with --data")
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
    if worst < 0:
        raise UserError(f"--worst {worst}: give the number of samples to show per metric (0 or more)")
    out = Path(out)
    a = load_run(run)
    b = None if baseline is None else load_run(baseline)
    shown = choose_samples(a, worst, samples)
    changed = [] if b is None else differences(a, b, threshold)
    keys = list(dict.fromkeys([*shown, *(d.key for d in changed)]))
    loaded = load_samples(data_folders(a, data), keys)
    out.parent.mkdir(parents=True, exist_ok=True)
    staging = Path(tempfile.mkdtemp(prefix=f".{out.name}-", dir=out.parent))
    try:
        for folder in ("img", "samples", *(() if b is None else ("compare",))):
            (staging / folder).mkdir()
        pages = Pages(staging)
        pages.summary(a, shown, loaded, None if b is None else b.name)
        if b is not None:
            pages.comparison(a, b, changed, loaded, threshold)
        replace_folder(staging, out)
        out.chmod(0o755)  # mkdtemp's 0700 would hide the site from a web server
    except BaseException:
        shutil.rmtree(staging, ignore_errors=True)
        raise
    return out / "index.html"


class Pages:
    """Renders the templates into a site folder."""

    def __init__(self, site: Path) -> None:
        self.site = site
        self.env = Environment(loader=PackageLoader("lead_s2r.report", "templates"), autoescape=True,
                               undefined=StrictUndefined)  # fmt: skip

    def write(self, template: str, target: str, **context: Any) -> None:
        html = self.env.get_template(template).render(**context)
        (self.site / target).write_text(html, encoding="utf-8")

    def summary(self, run: RunOutputs, shown: dict[str, str], loaded: dict[str, Any], baseline: str | None) -> None:
        """``index.html`` and one page per shown sample."""
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
            self.write("sample.html", f"samples/{key}.html", title=f"{key} — {run.name}", view=view, reason=reason)
            listed.append({"key": key, "dataset": view.dataset, "reason": reason})
        self.write("index.html", "index.html", title=f"Report {run.name}", run=run.name, path=str(run.path),
                   metrics=metrics, curves=curves, samples=listed, config=run.config, comparison=baseline)  # fmt: skip

    def comparison(
        self, a: RunOutputs, b: RunOutputs, changed: list[Difference], loaded: dict[str, Any], threshold: float
    ) -> None:
        """``comparison.html`` and one side-by-side page per sample that differs."""
        for key in dict.fromkeys(d.key for d in changed):
            pair = pair_view(loaded[key], a, b, self.site)
            self.write("pair.html", f"compare/{key}.html", title=f"{key}: {a.name} vs {b.name}", pair=pair,
                       a=a.name, b=b.name)  # fmt: skip
        self.write("comparison.html", "comparison.html", title=f"{b.name} against {a.name}", a=a.name, b=b.name,
                   threshold=threshold, unmatched=unmatched(a, b), wins=[d for d in changed if d.gain > 0],
                   losses=[d for d in changed if d.gain < 0])  # fmt: skip
