"""Displacement metrics: ADE/FDE against the logged future (every dataset) and ADE@3s/5s against the best rater.

Two ADE families that must not be confused:

- ``ade``/``fde`` compare the most probable inference with the sample's logged ``future`` at the future's own
  time stamps, up to the shorter of the two horizons (the prediction is interpolated, never extrapolated);
  ``min_ade``/``min_fde`` take the best inference.
- ``ade_3s``/``ade_5s`` (the WOD-E2E leaderboard tie-breakers) compare the most probable inference on the
  4 Hz grid with the highest-rated trajectory (first one on ties; short raters padded with their last point as
  in RFS): mean L2 over the waypoints up to 3 s (12 points) and 5 s (20 points).
"""

from collections.abc import Iterable
from typing import Any, ClassVar

import numpy as np
import pyarrow as pa

from lead_s2r.predictions import TIME_TOLERANCE, Prediction, on_grid, regular_grid
from lead_s2r.scoring.base import Scorer, ScoreResult, join, mean_or_none
from lead_s2r.scoring.rfs import RFSConfig, has_rating, pad_raters, rater_arrays

#: per-sample columns from the logged future (:func:`future_errors`) and from the best rater.
FUTURE_COLUMNS = ("ade", "fde", "min_ade", "min_fde", "horizon_s")
RATER_COLUMNS = ("ade_3s", "ade_5s")
SUMMED = ("ade", "fde", "min_ade", "min_fde", *RATER_COLUMNS)
SCHEMA = pa.schema(
    [("key", pa.string()), ("dataset", pa.string())]
    + [(name, pa.float64()) for name in (*FUTURE_COLUMNS, *RATER_COLUMNS)]
)


def future_errors(frame: list[Prediction], future: np.ndarray) -> dict[str, float]:
    """ADE/FDE of the most probable inference and min over inferences against a logged future (T, 4), over the
    future times the prediction covers (``horizon_s``: how far that was, NaN if none)."""
    horizon = min(float(p.t[-1]) for p in frame)
    times = future[:, 0].astype(np.float64)
    covered = times <= horizon + TIME_TOLERANCE
    if not covered.any():
        return dict.fromkeys(FUTURE_COLUMNS, float("nan"))
    xy, probabilities = on_grid([frame], times[covered])
    errors = np.linalg.norm(xy[0] - future[covered, 1:3].astype(np.float64), axis=-1)  # (I, T)
    top = int(probabilities[0].argmax())
    return {
        "ade": float(errors[top].mean()),
        "fde": float(errors[top, -1]),
        "min_ade": float(errors.mean(-1).min()),
        "min_fde": float(errors[:, -1].min()),
        "horizon_s": float(times[covered][-1]),
    }


def best_rater_ade(
    predictions: np.ndarray,
    probabilities: np.ndarray,
    raters: np.ndarray,
    labels: np.ndarray,
    t: np.ndarray,
    horizons: tuple[float, ...] = (3.0, 5.0),
) -> np.ndarray:
    """(B, H) mean L2 between the most probable inference (B, I, T, 2) and the best-rated trajectory (B, P, T, 2)
    over the grid points ``t`` up to each horizon."""
    frames = np.arange(len(predictions))
    top = predictions[frames, probabilities.argmax(-1)]
    best = raters[frames, labels.argmax(-1)]
    errors = np.linalg.norm(top - best, axis=-1)
    return np.stack([errors[:, t <= h + TIME_TOLERANCE].mean(-1) for h in horizons], axis=-1)


class DisplacementScorer(Scorer):
    """``ade``: displacement errors of every predicted sample, overall and per dataset."""

    name: ClassVar[str] = "ade"
    version: ClassVar[str] = "1"
    fields: ClassVar[tuple[str, ...]] = ("future", "raters")

    def __init__(self, allow_missing: bool = False, frequency: float = 4.0, length_seconds: float = 5.0) -> None:
        """``frequency``/``length_seconds``: the rater grid of ADE@3s/5s (WOD-E2E: 4 Hz x 5 s)."""
        super().__init__(allow_missing)
        self.frequency = frequency
        self.length_seconds = length_seconds

    def config(self) -> dict[str, Any]:
        return {**super().config(), "frequency": self.frequency, "length_seconds": self.length_seconds}

    def score(self, predictions: Iterable[Prediction], data: Iterable[dict[str, Any]]) -> ScoreResult:
        pairs = join(predictions, data, self.allow_missing)
        rows = []
        for sample, frame in pairs:
            row = {"key": sample["__key__"], "dataset": sample["meta"]["dataset"]}
            row |= dict.fromkeys((*FUTURE_COLUMNS, *RATER_COLUMNS), float("nan"))
            if "future" in sample:
                row.update(future_errors(frame, sample["future"]))
            rows.append(row)
        rated = [b for b, (sample, _) in enumerate(pairs) if has_rating(sample)]
        if rated:
            grid = regular_grid(self.frequency, self.length_seconds)
            xy, probabilities = on_grid([pairs[b][1] for b in rated], grid)
            config = RFSConfig(frequency=self.frequency, length_seconds=self.length_seconds)
            raters, labels = pad_raters(*rater_arrays([pairs[b][0] for b in rated]), config)
            ade = best_rater_ade(xy, probabilities, raters, labels, grid)
            for b, (ade_3s, ade_5s) in zip(rated, ade, strict=True):
                rows[b]["ade_3s"], rows[b]["ade_5s"] = float(ade_3s), float(ade_5s)
        table = pa.Table.from_pylist(rows, schema=SCHEMA)
        return ScoreResult(table, self._aggregate(rows))

    @staticmethod
    def _aggregate(rows: list[dict[str, Any]]) -> dict[str, Any]:
        def summary(subset: list[dict[str, Any]]) -> dict[str, Any]:
            out: dict[str, Any] = {name: mean_or_none([row[name] for row in subset]) for name in SUMMED}
            out["frames"] = len(subset)
            out["frames_with_future"] = int(sum(np.isfinite(row["ade"]) for row in subset))
            out["frames_rated"] = int(sum(np.isfinite(row["ade_3s"]) for row in subset))
            return out

        datasets = sorted({row["dataset"] for row in rows})
        return {**summary(rows), "per_dataset": {d: summary([r for r in rows if r["dataset"] == d]) for d in datasets}}
