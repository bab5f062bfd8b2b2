"""``pdms@navsim-1.1``: NAVSIM v1.1's PDM score of predictions on converted NAVSIM samples.

Per sample: the most probable inference is put on NAVSIM's input grid (a prediction on a regular grid
``dt, 2dt, ...`` is passed as it is, as NAVSIM passes an agent's own ``TrajectorySampling``; any other grid is
resampled to 8 poses at 0.5 s with :func:`lead_s2r.geometry.resample`, never extrapolated), the scene is built
from the sample (:func:`~lead_s2r.scoring.pdm.sample.scene_from_sample`), PDM-Closed plans the EP reference (or it
is read from ``reference_cache``), and :func:`score_proposals` scores the prediction beside it. A sample whose scene
cannot be built (no route PDM-Closed can follow) is an invalid row with NaN scores and the error, as NAVSIM's evaluation
isolates a failing token; the split score is the mean over valid rows (NAVSIM's ``average`` row).

Besides scores.parquet / scores.json, :meth:`PDMSScorer.write_files` writes ``navsim_pdms.csv`` in the layout of
NAVSIM v1.1's ``run_pdm_score.py`` output (index column, ``token``, ``valid``, the ``PDMResults`` fields in their
order, then the ``average`` row), so it diffs cleanly against an official CSV.
"""

import csv
import io
from collections.abc import Iterable
from pathlib import Path
from typing import Any, ClassVar

import numpy as np
import pyarrow as pa

from lead_s2r.files import write_text
from lead_s2r.predictions import Prediction
from lead_s2r.schema import navsim_scene_token
from lead_s2r.scoring.base import Scorer, ScoreResult, join, mean_or_none
from lead_s2r.scoring.navsim.proposals import Frame, ReferenceCache, first_row, frame_of, previous_frame
from lead_s2r.scoring.pdm import epdms
from lead_s2r.scoring.pdm.score import METRIC, STEP_COLUMNS, score_proposals
from lead_s2r.scoring.pdm.score import PROGRESS_COLUMNS as EXTRA_COLUMNS

#: NAVSIM v1.1 ``PDMResults`` fields, in the order its CSV writes them.
NAVSIM_COLUMNS = (epdms.NC, epdms.DAC, epdms.EP, epdms.TTC, "comfort", epdms.DDC, "score")
SCHEMA = pa.schema(
    [("key", pa.string()), ("dataset", pa.string()), ("token", pa.string()), ("valid", pa.bool_())]
    + [(name, pa.float64()) for name in (*NAVSIM_COLUMNS, *EXTRA_COLUMNS)]
    + [(name, pa.int64()) for name in STEP_COLUMNS]
    + [("error", pa.string())]
)


class PDMSScorer(Scorer):
    """``pdms@navsim-1.1``: per-sample NAVSIM v1.1 sub-scores and PDMS, their means as NAVSIM's average row."""

    name: ClassVar[str] = METRIC
    version: ClassVar[str] = "1"
    fields: ClassVar[tuple[str, ...]] = ("scoring", "boxes", "agents_future", "future")
    #: any sample with a ``scoring`` context (NAVSIM, and 123D logs converted with their map), not a dataset name
    required: ClassVar[tuple[str, ...]] = ("scoring",)
    #: the CSV's score columns (after ``token``, ``valid``), the aggregate naming the split score, the CSV file
    #: and its average row's token: what ``epdms@navsim-2.2`` (:mod:`lead_s2r.scoring.navsim.epdms_scorer`) changes
    csv_columns: ClassVar[tuple[str, ...]] = NAVSIM_COLUMNS
    step_columns: ClassVar[tuple[str, ...]] = STEP_COLUMNS
    headline: ClassVar[str] = "pdms"
    csv_name: ClassVar[str] = "navsim_pdms.csv"
    average_token: ClassVar[str] = "average"

    def __init__(self, allow_missing: bool = False, reference_cache: str | ReferenceCache | None = None) -> None:
        """``reference_cache``: folder of PDM-Closed references (``<key>.npy``), read when present, else written;
        or a :class:`ReferenceCache` shared with other scorers of the same data in this process (the quickstart
        plans each reference once for PDMS and EPDMS, baseline and model)."""
        super().__init__(allow_missing)
        shared = isinstance(reference_cache, ReferenceCache)
        self.references = reference_cache if shared else ReferenceCache(reference_cache)
        self.reference_cache = None if self.references.folder is None else str(self.references.folder)

    def config(self) -> dict[str, Any]:
        return {**super().config(), "reference_cache": self.reference_cache}

    def score(self, predictions: Iterable[Prediction], data: Iterable[dict[str, Any]]) -> ScoreResult:
        """Samples without a ``scoring`` context (e.g. WOD-E2E beside NAVSIM in one run) are skipped and counted."""
        pairs = join(predictions, data, self.allow_missing)
        ours = [(sample, frame) for sample, frame in pairs if "scoring" in sample]
        rows = self.map_samples(self.score_sample, ours)
        table = pa.Table.from_pylist(rows, schema=SCHEMA)
        return ScoreResult(table, {**self._aggregate(rows), "frames_skipped_other_dataset": len(pairs) - len(ours)})

    def score_sample(self, sample: dict[str, Any], predictions: list[Prediction]) -> dict[str, Any]:
        """One row of the table: NAVSIM's sub-scores of the most probable inference, or an invalid row."""
        return self.row(frame_of(sample, predictions), None)

    def row(self, frame: Frame, earlier: Frame | None) -> dict[str, Any]:
        """One row of the table: the frame's columns (EPDMS: EC against ``earlier``), or an invalid row."""
        sample = frame.sample
        row: dict[str, Any] = {
            "key": sample["__key__"],
            "dataset": sample["meta"]["dataset"],
            "token": navsim_scene_token(sample),
            "valid": frame.scene is not None,
            "previous_key": None if earlier is None else earlier.sample["__key__"],
            "error": frame.error,
        }
        if frame.scene is None:
            return row | dict.fromkeys((*self.csv_columns, *EXTRA_COLUMNS), float("nan"))
        result = self.proposal_scores(frame, earlier)
        return row | first_row(result, (*self.csv_columns, *EXTRA_COLUMNS), self.step_columns)

    def proposal_scores(self, frame: Frame, earlier: Frame | None, with_states: bool = False) -> dict[str, np.ndarray]:
        """``score_proposals`` of the frame's plan (EPDMS: EC against ``earlier``'s plan, NaN without one)."""
        assert frame.scene is not None, "invalid frames have no scores"
        return score_proposals(
            frame.scene,
            frame.poses[None],
            frame.interval,
            reference=self.references.get(frame.scene),
            metric=self.name,
            previous=None if earlier is None else [previous_frame(frame, earlier)],
            with_states=with_states,
        )

    def _aggregate(self, rows: list[dict[str, Any]]) -> dict[str, Any]:
        valid = [row for row in rows if row["valid"]]
        means = {name: mean_or_none([row[name] for row in valid]) for name in self.csv_columns}
        return {
            self.headline: means["score"],
            **means,
            "frames": len(rows),
            "frames_valid": len(valid),
            "frames_failed": len(rows) - len(valid),
        }

    def write_files(self, result: ScoreResult, out: Path) -> None:
        """``navsim_pdms.csv``: NAVSIM v1.1's CSV layout (see the module docstring)."""
        rows = result.table.to_pylist()
        columns = self.csv_columns
        means = [mean_or_none([row[name] for row in rows]) for name in columns]
        body = [[str(i), row["token"], row["valid"], *(row[name] for name in columns)] for i, row in enumerate(rows)]
        body.append([str(len(rows)), self.average_token, all(row["valid"] for row in rows), *means])
        write_csv(Path(out) / self.csv_name, ["", "token", "valid", *columns], body)


def write_csv(path: Path, header: list[str], rows: list[list[Any]]) -> None:
    """A CSV laid out as NAVSIM's (pandas': ``\\r\\n`` line ends, cells by :func:`csv_cell`), put in place whole."""
    text = io.StringIO()
    csv.writer(text).writerows([header, *([csv_cell(cell) for cell in row] for row in rows)])
    write_text(path, text.getvalue())


def csv_cell(value: object) -> str:
    """pandas' CSV spelling of a cell, as NAVSIM's CSVs have it: a string or bool as it is, a float by its repr, empty
    for NaN / missing."""
    if isinstance(value, str | bool):
        return str(value)
    return "" if value is None or not np.isfinite(value) else repr(float(value))  # type: ignore[arg-type]
