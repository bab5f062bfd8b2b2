"""One sample's page: its BEV, its forward camera(s) with the trajectories projected, and every metric's sub-scores
with the failing ones named and timed (``DAC 0: leaves the drivable area at t = 2.5 s``).

The PDMS / EPDMS scorers record the 0.1 s simulation step where NC, TTC, DAC and LK failed and the agent NC hit
(``lead_s2r.scoring.navsim.pdms_scorer.STEP_COLUMNS``; the agent is its row of ``boxes`` / ``agents_future``, the
number the BEV writes beside it); a sub-score without a step (DDC, TLC, comfort) is named without a time.
"""

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from lead_s2r.predictions import Prediction, most_probable
from lead_s2r.report.bev import bev_figure, save_figure
from lead_s2r.report.camera import camera_figure, forward_cameras
from lead_s2r.report.run_outputs import MetricScores, RunOutputs

#: PDMS / EPDMS simulation step [s]
STEP_S = 0.1
#: sub-score column -> (NAVSIM's short name, what losing it means, the column holding the step it was lost at)
NAVSIM_FAILURES = {
    "no_at_fault_collisions": ("NC", "at-fault collision", "collision_time_idx"),
    "drivable_area_compliance": ("DAC", "leaves the drivable area", "dac_time_idx"),
    "time_to_collision_within_bound": ("TTC", "time to collision below 0.9 s", "ttc_time_idx"),
    "lane_keeping": ("LK", "off the lane centre by more than 0.5 m for 2 s", "lane_keeping_fail_idx"),
    "driving_direction_compliance": ("DDC", "drives into oncoming traffic", None),
    "traffic_light_compliance": ("TLC", "enters a lane with a red light", None),
    "comfort": ("C", "acceleration or jerk beyond the comfort bounds", None),
    "history_comfort": ("HC", "acceleration or jerk beyond the comfort bounds", None),
    "two_frame_extended_comfort": ("EC", "plan inconsistent with the previous frame's", None),
}
#: metric family -> its sub-score columns where not NAVSIM's (``NAVSIM_FAILURES`` and ego progress)
SUB_SCORES = {"rfs": ("rfs",), "ade": ("ade", "fde")}
#: columns that are not sub-scores: bookkeeping and the failure steps
NOT_SCORES = {"key", "dataset", "token", "valid", "error", "previous_key", "cluster", "stage", "two_stage_role"}


def named_failures(scores: MetricScores, row: dict[str, Any]) -> list[tuple[str, str]]:
    """``(kind, words)`` of each sub-score ``row`` lost: the kind (``DAC``) is what a listing filters on, the words
    name it with the time it was lost where the scorer records it."""
    if row.get("valid") is False:
        return [("not scored", f"not scored: {row.get('error')}")]
    named = []
    if scores.family in ("pdms", "epdms"):
        for column, (short, what, step_column) in NAVSIM_FAILURES.items():
            value = row.get(column)
            if value is None or not np.isfinite(value) or value >= 1.0:
                continue
            step = row.get(step_column) if step_column else None
            when = f" at t = {step * STEP_S:.1f} s" if step is not None and step >= 0 else ""
            hit = row.get("collision_object_idx") if column == "no_at_fault_collisions" else None
            whom = f" with agent {hit}" if hit is not None and hit >= 0 else ""
            named.append((short, f"{short} {value:g}: {what}{whom}{when}"))
    elif scores.family == "rfs" and row.get("rfs") is not None:
        if not row.get("fully_within"):
            named.append(("RFS", f"RFS {row['rfs']:.2f}: outside every rater's trust region (raised to the floor)"))
        elif row["rfs"] < (row.get("best_label") or 0.0):
            named.append(("RFS", f"RFS {row['rfs']:.2f}: below the best rater's score {row['best_label']:g}"))
    return named


def sub_scores(family: str) -> tuple[str, ...]:
    """The columns of a family's per-sample table that are sub-scores (NAVSIM's multipliers and weighted terms, RFS,
    ADE and FDE): progress in metres or a normaliser is a number, not a sub-score to compare or plot."""
    if family in ("pdms", "epdms"):
        return (*NAVSIM_FAILURES, "ego_progress")
    return SUB_SCORES.get(family, ())


def is_score(name: str, value: object) -> bool:
    """Whether a scores-table cell is a sub-score or a number worth showing (bookkeeping and step indices are not;
    None is a score that is missing, e.g. EC without a previous frame)."""
    if name in NOT_SCORES or name.endswith("_idx") or isinstance(value, bool):
        return False
    return value is None or isinstance(value, int | float)


def score_cells(row: dict[str, Any]) -> list[tuple[str, str]]:
    """``(column, value)`` of every sub-score and number of a row, for the page's table."""
    return [(name, f"{value:.4g}") for name, value in row.items() if is_score(name, value) and value is not None]


def top_xy(frame: list[Prediction]) -> np.ndarray:
    """The most probable inference's ``(T, 2)`` positions."""
    return np.asarray(most_probable(frame).xy, np.float64)


def reference_xy(run: RunOutputs, key: str) -> np.ndarray | None:
    """PDM-Closed's reference of ``key`` where a scorer cached it on disk (``reference_cache``)."""
    for scores in run.scores:
        folder = scores.report.get("config", {}).get("reference_cache")
        if folder and (Path(folder) / f"{key}.npy").is_file():
            return np.load(Path(folder) / f"{key}.npy")[:, :2]
    return None


def trajectories(sample: dict[str, Any], runs: dict[str, RunOutputs]) -> dict[str, np.ndarray]:
    """``logged``, ``reference`` (where cached) and each run's prediction of the sample, by label."""
    key = sample["__key__"]
    drawn: dict[str, np.ndarray] = {}
    if "future" in sample:
        drawn["logged"] = np.asarray(sample["future"], np.float64)[:, 1:3]
    for run in runs.values():
        reference = reference_xy(run, key)
        if reference is not None:
            drawn["reference"] = reference
            break
    for label, run in runs.items():
        if key in run.predictions:
            drawn[label] = top_xy(run.predictions[key])
    return drawn


@dataclass
class SampleView:
    """What a sample page shows: image paths relative to the site, and per metric the cells and failures."""

    key: str
    dataset: str
    images: list[tuple[str, str]] = field(default_factory=list)
    metrics: list[dict[str, Any]] = field(default_factory=list)


def draw_sample(sample: dict[str, Any], runs: dict[str, RunOutputs], site: Path, stem: str) -> list[tuple[str, str]]:
    """Write the BEV and forward-camera PNGs of ``sample`` under ``site/img`` as ``<stem>_*.png``; return
    ``(caption, relative path)`` of each."""
    drawn = trajectories(sample, runs)
    path = f"img/{stem}_bev.png"
    save_figure(bev_figure(sample, drawn, title=sample["__key__"]), site / path)
    images = [("bird's-eye view (ego frame: forward up, left left)", path)]
    for camera in forward_cameras(sample):
        name = camera.get("tile_name", camera["id"])
        path = f"img/{stem}_cam_{name}.png"
        if camera_figure(sample, camera, drawn, site / path):
            images.append((f"camera {name}", path))
    return images


def sample_view(sample: dict[str, Any], run: RunOutputs, site: Path) -> SampleView:
    """Draw ``sample`` for ``run`` and collect its sub-scores and failures per metric."""
    key = sample["__key__"]
    view = SampleView(key, sample["meta"]["dataset"], draw_sample(sample, {"predicted": run}, site, key))
    for scores in run.scores:
        row = scores.rows.get(key)
        if row is not None:
            failed = [words for _, words in named_failures(scores, row)]
            view.metrics.append({"label": scores.label, "cells": score_cells(row), "failures": failed})
    return view
