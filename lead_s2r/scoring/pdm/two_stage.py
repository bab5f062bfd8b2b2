"""navhard's two-stage (pseudo closed-loop) EPDMS aggregation, as NAVSIM v2.2's ``run_pdm_score.py`` and
``scene_aggregator.py`` compute it, over already scored frames.

The mapping (``reactive_all_mapping`` of the split yaml) groups two stage-1 frames with the synthetic frames that
continue them. ``original`` is at t = 0 and ``previous`` at t = -0.5 s. The pairs are ``(now, previous)`` synthetic
frames that start 4 s and 3.5 s later, at a perturbed ego pose. For each group:

* EC is computed per pair of adjacent frames, ``(original, previous)`` and each synthetic ``(now, previous)``, and
  written to both frames of the pair. EC enters each frame's final EPDMS, always with weight 2/16 here.
* Stage-1 frames get weight 1. A synthetic frame gets ``exp(-d^2 / (2 * 0.1))``, where ``d`` is the distance from
  the stage-1 frame's *planned* endpoint (its last output pose, not the simulated one) to the synthetic frame's
  start rear axle. "now" variants are measured from the original's endpoint, "previous" variants from the previous
  frame's. Weights are normalised per side. If a side's weights sum to ``np.isclose(., 0)`` (atol 1e-8, i.e. every
  start is farther than about 1.9 m away) or to a non-finite value, all variants of that side get equal weights.
* Column-wise, for every sub-score and the score: group = ½·[S1(original)·Σw·S2(now) + S1(previous)·Σw·S2(previous)].
  ``extended_pdm_score_combined`` is the mean of the group values. ``_stage_one`` is the mean over the stage-1 frames of
  all groups, and ``_stage_two`` the mean over the per-side weighted stage-2 averages. Means skip NaN, as pandas does.

NAVSIM falls back to weight 1 for every frame and logs a warning when any of this throws, for example when a
synthetic token has no metric cache (issues #119, #159, #180). That silently gives a different number. Here a token
of the mapping without a row, or a row in no group, is an error that names it.
"""

from collections.abc import Iterable, Mapping, Sequence
from dataclasses import dataclass, field

import numpy as np

from lead_s2r.formats.navsim_two_stage import TwoStageGroup
from lead_s2r.scoring.pdm import epdms
from lead_s2r.scoring.pdm.extended_comfort import FeatureExtractor, two_frame_extended_comfort

SIGMA_SQUARED = 0.1
#: Columns aggregated over groups, in NAVSIM's CSV order (``score`` last).
SCORE_COLUMNS = (*epdms.FILTERED, epdms.EC, "score")
SUMMARY_TOKENS = ("extended_pdm_score_stage_one", "extended_pdm_score_stage_two", "extended_pdm_score_combined")


@dataclass(frozen=True)
class TokenRow:
    """One scored frame: a stage-1 original scene or a stage-2 synthetic scene.

    ``columns``: the sub-scores of :data:`epdms.FILTERED` after the human penalty filter. ``start_time`` [s]: only
    differences between a pair's frames matter. ``start_point`` (rear axle at t0) and ``endpoint`` (the last
    *planned* pose): ``(x, y)`` in the map frame. ``simulated_states``: the ``(41, 11)`` states EC compares."""

    token: str
    columns: Mapping[str, float]
    start_time: float
    start_point: np.ndarray
    endpoint: np.ndarray
    simulated_states: np.ndarray


@dataclass
class TwoStageResult:
    """Per-token columns (sub-scores, EC, ``score``, ``weight``, ``stage`` 1 or 2) and NAVSIM's three summaries."""

    per_token: dict[str, dict[str, float]]
    stage_one: dict[str, float] = field(default_factory=dict)
    stage_two: dict[str, float] = field(default_factory=dict)
    combined: dict[str, float] = field(default_factory=dict)


def pseudo_closed_loop_weights(endpoint: np.ndarray, start_points: np.ndarray) -> np.ndarray:
    """Normalised Gaussian weights of synthetic frames starting at ``start_points`` (V, 2) for a stage-1 frame that
    planned to end at ``endpoint`` (2,). Equal weights when the raw weights sum to (about) zero or not to a number."""
    start_points = np.asarray(start_points, np.float64).reshape(-1, 2)
    if len(start_points) == 0:
        return np.zeros(0)
    distance = np.hypot(*(start_points - np.asarray(endpoint, np.float64)).T)
    weights = np.exp(-(distance**2) / (2 * SIGMA_SQUARED))
    total = weights.sum()
    if not np.isfinite(total) or np.isclose(total, 0.0, atol=1e-8):
        return np.full(len(weights), 1.0 / len(weights))
    return weights / total


def _rows_by_token(rows: Iterable[TokenRow], groups: Sequence[TwoStageGroup]) -> dict[str, TokenRow]:
    by_token: dict[str, TokenRow] = {}
    for row in rows:
        if row.token in by_token:
            raise ValueError(f"two-stage aggregation: token {row.token} has two rows")
        by_token[row.token] = row
    mapped = {token for group in groups for token in group.tokens()}
    for group in groups:
        missing = [token for token in group.tokens() if token not in by_token]
        if missing:
            raise KeyError(
                f"two-stage aggregation: group ({group.original}, {group.previous}) names tokens with no scored row: "
                f"{', '.join(missing)}; score every stage-1 and stage-2 token of the mapping"
            )
    unmapped = sorted(set(by_token) - mapped)
    if unmapped:
        raise KeyError(f"two-stage aggregation: rows for tokens in no group of the mapping: {', '.join(unmapped)}")
    return by_token


def _pair_ec(rows: Mapping[str, TokenRow], now: str, before: str, features: FeatureExtractor) -> float:
    interval = rows[now].start_time - rows[before].start_time
    try:
        return two_frame_extended_comfort(rows[now].simulated_states, rows[before].simulated_states, interval, features)
    except ValueError as err:
        raise ValueError(f"two-stage aggregation: pair ({now}, {before}): {err}") from None


def _token_columns(row: TokenRow, ec: float, weight: float, stage: int) -> dict[str, float]:
    missing = [name for name in epdms.FILTERED if name not in row.columns]
    if missing:
        raise KeyError(f"two-stage aggregation: token {row.token} has no column {', '.join(missing)}")
    columns = {name: float(row.columns[name]) for name in epdms.FILTERED}
    columns[epdms.EC] = ec
    columns["score"] = float(epdms.epdms(columns))
    return columns | {"weight": weight, "stage": stage}


def _weighted_average(table: Mapping[str, Mapping[str, float]], tokens: Sequence[str]) -> np.ndarray:
    """Column-wise weighted average of ``tokens`` (NaN for none), as ``calculate_weighted_average_score``."""
    values = np.array([[table[t][name] for name in SCORE_COLUMNS] for t in tokens])
    weights = np.array([table[t]["weight"] for t in tokens])
    total = weights.sum()
    if total == 0:
        return np.full(len(SCORE_COLUMNS), np.nan)
    return (values * weights[:, None]).sum(0) / total


def _nanmean(rows: list[np.ndarray]) -> dict[str, float]:
    stacked = np.array(rows).reshape(-1, len(SCORE_COLUMNS))
    counts = (~np.isnan(stacked)).sum(0)
    sums = np.nansum(stacked, 0)
    means = np.divide(sums, counts, out=np.full(len(SCORE_COLUMNS), np.nan), where=counts > 0)
    return dict(zip(SCORE_COLUMNS, means.tolist(), strict=True))


def two_stage_aggregate(
    rows: Iterable[TokenRow], mapping: Sequence[TwoStageGroup], features: FeatureExtractor
) -> TwoStageResult:
    """Per-token EC, weights and final EPDMS, and the stage-one / stage-two / combined summaries (module docstring).
    ``features`` extracts the EC comfort features of a slice of simulated states (the comfort module's extractor)."""
    groups = list(mapping)
    by_token = _rows_by_token(rows, groups)
    table: dict[str, dict[str, float]] = {}
    stage_one, stage_two, combined = [], [], []
    for group in groups:
        ec = _pair_ec(by_token, group.original, group.previous, features)
        table[group.original] = _token_columns(by_token[group.original], ec, 1.0, 1)
        table[group.previous] = _token_columns(by_token[group.previous], ec, 1.0, 1)
        sides = []
        for side, first in enumerate((group.original, group.previous)):
            variants = [pair[side] for pair in group.pairs]
            starts = np.array([by_token[t].start_point for t in variants]).reshape(-1, 2)
            weights = pseudo_closed_loop_weights(by_token[first].endpoint, starts)
            sides.append((first, variants, weights))
        for now, before in group.pairs:
            pair_ec = _pair_ec(by_token, now, before, features)
            for (_, variants, weights), token in zip(sides, (now, before), strict=True):
                table[token] = _token_columns(by_token[token], pair_ec, float(weights[variants.index(token)]), 2)
        group_values = []
        for first, variants, _ in sides:
            first_values = _weighted_average(table, [first])
            second_values = _weighted_average(table, variants)
            stage_one.append(first_values)
            stage_two.append(second_values)
            group_values.append(first_values * second_values)
        combined.append((group_values[0] + group_values[1]) / 2)
    return TwoStageResult(table, _nanmean(stage_one), _nanmean(stage_two), _nanmean(combined))


def navsim_csv_rows(result: TwoStageResult) -> list[dict[str, object]]:
    """NAVSIM's two-stage CSV: per token ``<column>_stage_one`` or ``<column>_stage_two`` (the other stage's columns
    empty) and ``score``, then the rows ``extended_pdm_score_stage_one``, ``_stage_two`` and ``_combined``. The
    combined row carries both stages' sub-score means and the combined score."""
    columns = [name for name in SCORE_COLUMNS if name != "score"]
    header = [f"{c}_stage_one" for c in columns] + [f"{c}_stage_two" for c in columns] + ["score"]
    rows: list[dict[str, object]] = []
    for token, values in result.per_token.items():
        suffix = "_stage_one" if values["stage"] == 1 else "_stage_two"
        row: dict[str, object] = {"token": token, "valid": True} | dict.fromkeys(header, np.nan)
        row |= {f"{c}{suffix}": values[c] for c in columns} | {"score": values["score"]}
        rows.append(row)
    one = {f"{c}_stage_one": result.stage_one[c] for c in columns}
    two = {f"{c}_stage_two": result.stage_two[c] for c in columns}
    empty = dict.fromkeys(header, np.nan)
    rows.append({"token": SUMMARY_TOKENS[0], "valid": True} | empty | one | {"score": result.stage_one["score"]})
    rows.append({"token": SUMMARY_TOKENS[1], "valid": True} | empty | two | {"score": result.stage_two["score"]})
    rows.append({"token": SUMMARY_TOKENS[2], "valid": True} | empty | one | two | {"score": result.combined["score"]})
    return rows
