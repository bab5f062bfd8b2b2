"""EPDMS (NAVSIM v2.2) aggregation over per-proposal sub-score columns, and the human penalty filter as fixed in v2.2.

Two official behaviours are easy to get wrong, and both are reproduced on purpose:

* The final score is not the scorer's own ``pdm_score`` column: that one leaves out EC and is computed before the
  filter. NAVSIM's ``compute_final_scores`` adds EC afterwards. When EC is NaN (a frame with no previous frame), EC and
  its weight are dropped, so the denominator is 14 and not 16.
* The human penalty filter (``evaluate/pdm_score.py``) scores the logged human trajectory alone. Wherever the human
  gets exactly 0 on a column, the agent's column is set to 1. A ½ (NC, DDC) is never filtered. The 2025-09-29 fix
  (commit 359c7f7, issue #151) recomputes the product of the multipliers and the weighted metrics from the filtered
  columns. Before the fix only the reported columns changed, and an agent with a filtered column kept a final score
  of 0. EP is not renormalised. The filter only applies to ORIGINAL scenes: synthetic scenes have no human
  trajectory, so ``human=None`` leaves the columns as they are.

Columns are NAVSIM's CSV names. Every function takes ``(N,)`` arrays (or scalars) per column and returns new arrays.
"""

from collections.abc import Mapping

import numpy as np

NC = "no_at_fault_collisions"
DAC = "drivable_area_compliance"
DDC = "driving_direction_compliance"
TLC = "traffic_light_compliance"
EP = "ego_progress"
TTC = "time_to_collision_within_bound"
LK = "lane_keeping"
HC = "history_comfort"
EC = "two_frame_extended_comfort"

#: Multiplied together (``multiplicative_metrics_prod``).
MULTIPLIERS = (NC, DAC, DDC, TLC)
#: Weighted average, in NAVSIM's ``WeightedMetricIndex`` order, with v2.2's ``PDMScorerConfig`` weights.
WEIGHTS = {EP: 5.0, TTC: 5.0, LK: 2.0, HC: 2.0, EC: 2.0}
#: Columns the human penalty filter may set to 1 (EC is aggregated later and is never filtered).
FILTERED = (*MULTIPLIERS, EP, TTC, LK, HC)
SUB_SCORES = (*FILTERED, EC)

Columns = Mapping[str, np.ndarray | float]


def _column(columns: Columns, name: str) -> np.ndarray:
    if name not in columns:
        raise KeyError(f"sub-score column {name!r} is missing (have: {', '.join(sorted(columns))})")
    return np.asarray(columns[name], np.float64)


def multiplicative_product(columns: Columns) -> np.ndarray:
    """``multiplicative_metrics_prod``: NC * DAC * DDC * TLC."""
    return np.prod([_column(columns, name) for name in MULTIPLIERS], axis=0)


def weighted_metrics(columns: Columns) -> tuple[np.ndarray, np.ndarray]:
    """``weighted_metrics`` and ``weighted_metrics_array`` as ``compute_final_scores`` leaves them: ``(N, 5)`` values
    and weights in :data:`WEIGHTS` order, with EC's value and weight set to 0 where EC is NaN (or absent)."""
    ec = np.asarray(columns.get(EC, np.nan), np.float64)
    values = np.stack(np.broadcast_arrays(*(_column(columns, name) for name in (EP, TTC, LK, HC)), ec), axis=-1)
    weights = np.broadcast_to(np.array(list(WEIGHTS.values())), values.shape).copy()
    missing = np.isnan(values[..., -1])
    values[..., -1] = np.where(missing, 0.0, values[..., -1])
    weights[..., -1] = np.where(missing, 0.0, weights[..., -1])
    return values, weights


def epdms(columns: Columns) -> np.ndarray:
    """The final EPDMS: ``NC*DAC*DDC*TLC*(5*EP + 5*TTC + 2*LK + 2*HC + 2*EC)/16``, or ``/14`` without EC where EC is
    NaN. Apply :func:`human_penalty_filter` first: the score is computed from the columns as given."""
    values, weights = weighted_metrics(columns)
    return multiplicative_product(columns) * (values * weights).sum(-1) / weights.sum(-1)


def human_penalty_filter(columns: Columns, human: Mapping[str, float] | None) -> dict[str, np.ndarray]:
    """The agent's columns after v2.2's filter: each column in :data:`FILTERED` where the human's value is exactly
    0 becomes 1; EC passes through. Compute :func:`epdms` and the product from the result."""
    out = {name: np.asarray(value, np.float64).copy() for name, value in columns.items()}
    if human is None:
        return out
    for name in FILTERED:
        if name not in human:
            raise KeyError(f"human penalty filter: the human's column {name!r} is missing")
        if float(human[name]) == 0.0:
            out[name] = np.ones_like(_column(columns, name))
    return out
