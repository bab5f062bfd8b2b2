"""What a report reads: one run's scores, predictions, config and training logs, and the converted samples it scored.

A run is a folder holding ``scores.json`` / ``scores.parquet`` pairs anywhere below it (one folder per metric, as
``lead-s2r score --out`` writes them). Each scores.json records the predictions file and the converted folders it
was scored on, so a run whose predictions sit elsewhere (the quickstart's expert keeps one file per dataset) is
found all the same; ``predictions.parquet`` in the run folder is the fallback. Every problem a user can fix (no
scores, predictions gone, a ``--data`` folder without the run's samples, a damaged scores file or training log) is a
:class:`UserError` naming the path.
"""

from collections import defaultdict
from collections.abc import Iterable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from lead_s2r.errors import UserError
from lead_s2r.fields import is_number
from lead_s2r.predictions import Prediction, group_by_key, read_predictions
from lead_s2r.report.tables import TableError, folder_identity, run_identity
from lead_s2r.report.training_log import TRAINING_LOG, TrainingLog
from lead_s2r.scoring.run import decode_listed
from lead_s2r.scoring.scores_file import SCORES_JSON, ScoresFile, scores_folders
from lead_s2r.shards import listed_samples

PREDICTIONS = "predictions.parquet"
#: metric family -> (the per-sample headline column, True when higher is better): what "worst" and "wins" mean
HEADLINES = {"pdms": ("score", True), "epdms": ("score", True), "rfs": ("rfs", True), "ade": ("ade", False)}


@dataclass
class MetricScores:
    """One ``lead-s2r score`` output: the scores.json content and its per-sample rows by key."""

    folder: Path
    report: dict[str, Any]
    rows: dict[str, dict[str, Any]]

    @property
    def metric(self) -> str:
        return str(self.report["metric"])

    @property
    def family(self) -> str:
        """``pdms`` of ``pdms@navsim-1.1``: what the views key their choices on."""
        return self.metric.split("@")[0]

    @property
    def dataset(self) -> str:
        datasets = sorted({str(row.get("dataset")) for row in self.rows.values() if row.get("dataset")})
        return ", ".join(datasets) or "-"

    @property
    def label(self) -> str:
        return f"{self.metric} on {self.dataset}"

    def headline(self, key: str) -> float | None:
        """The headline value of sample ``key`` (None: not scored, invalid, or a metric without a headline)."""
        column = HEADLINES.get(self.family, (None, True))[0]
        row = self.rows.get(key)
        value = None if row is None or column is None else row.get(column)
        return float(value) if is_number(value) else None


@dataclass
class RunOutputs:
    """A run as the report sees it."""

    path: Path
    scores: list[MetricScores]
    predictions: dict[str, list[Prediction]]
    config: str | None = None
    logs: dict[str, list[tuple[float, float]]] = field(default_factory=dict)
    #: the tags of the subsets scored on their own (``lead-s2r score --tag``), whole set or not
    subsets: tuple[str, ...] = ()

    @property
    def name(self) -> str:
        """``<family> / <name> / seed<k>`` from the run layout ``runs/<family>/<name>/seed<k>``, else from the
        ``config.yaml`` ``lead-s2r fit`` saved (``trainer.default_root_dir``, ``seed_everything``: what ``lead-s2r
        table`` reads), else the folder's own name: a run is named by what it is, never by its last folder alone."""
        path = self.path.resolve()  # "." is a run too
        identity = folder_identity(path)
        configs = sorted(path.rglob("config.yaml"))
        if identity is None and configs:
            try:
                identity = run_identity(configs[0])
            except TableError:  # a config without the run's identity (hand-written): the folder names the run
                identity = None
        if identity is None:
            return path.name
        run_id, seed = identity
        return " / ".join([*Path(run_id).parts[-2:], f"seed{seed}"])

    @property
    def slug(self) -> str:
        """The run's name as a folder or file name: ``navsim-ltfv6-seed0``."""
        return "-".join(self.name.split(" / "))

    def data_folders(self) -> list[Path]:
        """The converted folders the scores.json files record, in first-seen order."""
        folders = [Path(folder) for scores in self.scores for folder in scores.report.get("data", [])]
        return list(dict.fromkeys(folders))


def load_run(path: str | Path) -> RunOutputs:
    """Read a run folder (see the module docstring)."""
    path = Path(path)
    if not path.is_dir():
        raise UserError(f"{path}: no such run folder; give the folder `lead-s2r score --out` wrote into (or above it)")
    every = [_metric_scores(folder) for folder in scores_folders(path)]
    scores = _whole_sets(every)
    if not scores:
        raise UserError(f"{path}: no {SCORES_JSON} below it; score the run first (`lead-s2r score ... --out`)")
    subsets = tuple(dict.fromkeys(entry.report["tag"] for entry in every if entry.report.get("tag")))
    return RunOutputs(path, scores, _predictions(path, scores), _config(path), training_curves(path), subsets)


def _whole_sets(scores: list[MetricScores]) -> list[MetricScores]:
    """The scores without those of a tagged subset (``lead-s2r score --tag``) whose metric was also scored on the
    whole set: the subset's rows are the whole set's again, and a view would show each sample twice."""
    whole = {entry.metric for entry in scores if not entry.report.get("tag")}
    return [entry for entry in scores if not entry.report.get("tag") or entry.metric not in whole]


def _metric_scores(folder: Path) -> MetricScores:
    scores = ScoresFile.read(folder)
    return MetricScores(folder, scores.report, {row["key"]: row for row in scores.table.to_pylist()})


def _predictions(path: Path, scores: list[MetricScores]) -> dict[str, list[Prediction]]:
    """Every predictions file the scores name (relative to the working folder or to the run), else the run's own."""
    files: list[Path] = []
    for entry in scores:
        recorded = Path(entry.report.get("predictions", ""))
        candidates = [recorded, path / recorded.name, path / PREDICTIONS]
        found = next((c for c in candidates if str(c) != "." and c.is_file()), None)
        if found is None:
            raise UserError(f"{entry.folder / SCORES_JSON}: its predictions {recorded} are gone and {path} holds no "
                            f"{PREDICTIONS}; the report draws the predicted trajectories")  # fmt: skip
        files.append(found.resolve())
    return group_by_key(p for file in dict.fromkeys(files) for p in read_predictions(file))


def _config(path: Path) -> str | None:
    configs = sorted(path.rglob("config.yaml"))
    if not configs:
        return None
    try:
        return configs[0].read_text()
    except UnicodeDecodeError as err:
        raise UserError(f"{configs[0]}: not UTF-8 text ({err}); the report shows the run's saved config") from None


def training_curves(path: Path) -> dict[str, list[tuple[float, float]]]:
    """``{column: [(step, value), ...]}`` of every loss / validation column in the Lightning CSV logs
    (``metrics.csv``; the x axis is the optimizer step) below ``path``, else in ``path/../lightning_logs``: a
    prediction folder inside its training's root (``<default_root_dir>/trained``) shows the training's curves."""
    curves: dict[str, list[tuple[float, float]]] = defaultdict(list)
    logs = sorted(path.rglob(TRAINING_LOG)) or sorted((path.parent / "lightning_logs").rglob(TRAINING_LOG))
    for log in logs:
        for name, step, value in TrainingLog(log).read():
            curves[name].append((step, value))
    return dict(curves)


def load_samples(folders: Iterable[Path], keys: Iterable[str]) -> dict[str, dict[str, Any]]:
    """The samples of ``keys`` from converted ``folders``, every field decoded, reading only the shards that hold
    them (the manifest says which). A key none of the folders holds is a :class:`UserError`."""
    wanted, folders = set(keys), list(folders)
    chosen = [row for folder in folders for row in listed_samples(folder) if row["key"] in wanted]
    missing = sorted(wanted - {row["key"] for row in chosen})
    if missing:
        where = ", ".join(str(folder) for folder in folders) or "no --data folder"
        more = f" (and {len(missing) - 1} more)" if len(missing) > 1 else ""
        raise UserError(f"sample {missing[0]!r}{more} is not in {where}; pass the converted folders the run was "
                        "scored on with --data")  # fmt: skip
    return {sample["__key__"]: sample for sample in decode_listed(chosen, None)}


def sample_tags(folders: Iterable[Path], keys: Iterable[str]) -> dict[str, list[str]]:
    """The manifest's tags (``scene_filter:pedestrians_ahead``) of each of ``keys`` the converted ``folders`` hold."""
    wanted, rows = set(keys), (row for folder in folders for row in listed_samples(folder, ("tags",), check=False))
    return {row["key"]: row["tags"] or [] for row in rows if row["key"] in wanted}
