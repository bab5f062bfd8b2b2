"""navhard two-stage EPDMS of scored frames: the mapping read from the samples, completeness, rows, aggregates, CSV.

``EPDMSScorer`` scores each frame (stage 1 and stage 2 alike) with ``score_proposals(..., with_states=True)``;
this module turns those frames into :class:`~lead_s2r.scoring.pdm.two_stage.TokenRow` and runs
:func:`~lead_s2r.scoring.pdm.two_stage.two_stage_aggregate`. The mapping is the one the adapter stored in every
mapped sample (``meta.extras.navsim.two_stage_group``, the same entries as ``info.json``'s ``two_stage``), so a
scorer that only sees samples (``lead-s2r score``, the validation callback) finds it without reading info.json.

Traps handled here:

* NAVSIM skips a token without a metric cache and then silently falls back to weight 1 for every frame. Here a
  mapped token whose sample is missing, unpredicted or unscorable (no route PDM-Closed can follow) is a
  :class:`UserError` naming the token, before any aggregation.
* The stage-2 weights measure from the stage-1 frame's *planned* endpoint (the last pose the planner output, taken
  to the map frame), not the simulated one; the start point is the sample's rear axle in the map frame
  (``scoring.origin``).
* EC compares simulated states of two frames whose ego frames differ. Its features (acceleration magnitude, jerk,
  yaw rate, yaw acceleration) do not change under a rigid motion of the states, so each frame's states stay in its
  own ego frame where NAVSIM keeps global ones.
"""

import math
from collections.abc import Sequence
from typing import Any

import numpy as np
import pyarrow as pa

from lead_s2r.errors import UserError
from lead_s2r.formats.navsim_two_stage import TwoStageGroup, parse_mapping
from lead_s2r.geometry import to_global
from lead_s2r.schema import navsim_scene_token
from lead_s2r.scoring.navsim.proposals import Frame, first_row
from lead_s2r.scoring.pdm import epdms, two_stage
from lead_s2r.scoring.pdm.comfort import extended_comfort_features
from lead_s2r.scoring.pdm.score import PROGRESS_COLUMNS

#: per-token table of a two-stage run: the one-stage columns, the token's stage, role and pseudo closed-loop weight.
TABLE_COLUMNS = (*epdms.SUB_SCORES, "score")
SCHEMA = pa.schema(
    [("key", pa.string()), ("dataset", pa.string()), ("token", pa.string()), ("valid", pa.bool_())]
    + [("stage", pa.int8()), ("two_stage_role", pa.string()), ("weight", pa.float64())]
    + [(name, pa.float64()) for name in (*TABLE_COLUMNS, *PROGRESS_COLUMNS)]
    + [("error", pa.string())]
)
CSV_NAME = "navsim_epdms_two_stage.csv"


def navsim_extras(sample: dict[str, Any]) -> dict[str, Any]:
    return sample["meta"].get("extras", {}).get("navsim", {})


def mapping_of(samples: Sequence[dict[str, Any]]) -> list[TwoStageGroup]:
    """The two-stage groups recorded in ``samples`` (each once, in data order); empty for a one-stage split."""
    raw: dict[str, Any] = {}
    for sample in samples:
        group = navsim_extras(sample).get("two_stage_group")
        if group is not None:
            raw.setdefault(str(group[0]), group)
    return parse_mapping(list(raw.values()))


def check_complete(
    mapping: Sequence[TwoStageGroup], samples: Sequence[dict[str, Any]], scored: dict[str, str | None]
) -> None:
    """Every token of ``mapping`` has a sample, a prediction and a scene; else a one-line error naming the token.
    ``scored``: token -> None (scored) or the reason its scene could not be built, for every predicted sample; one in
    no group is an error too (NAVSIM scores only the mapping's tokens on a two-stage split)."""
    stray = sorted(set(scored) - {token for group in mapping for token in group.tokens()})
    if stray:
        raise UserError(
            f"navhard two-stage: token {stray[0]} ({len(stray)} such) is in no group of the two-stage mapping; "
            "leave it out of --data or score one stage with --option two_stage=false"
        )
    converted = {navsim_scene_token(sample) for sample in samples}
    for group in mapping:
        for stage, tokens in ((1, (group.original, group.previous)), (2, [t for p in group.pairs for t in p])):
            for token in tokens:
                where = f"navhard two-stage: stage-{stage} token {token} (group of {group.original})"
                if token not in converted:
                    raise UserError(f"{where} has no sample in --data; convert the whole split with its mapping")
                if token not in scored:
                    raise UserError(
                        f"{where} has no prediction; the two-stage score needs every stage-1 and stage-2 token "
                        "predicted (NAVSIM would silently fall back to equal weights)"
                    )
                if scored[token] is not None:
                    raise UserError(f"{where} cannot be scored: {scored[token]}")


def token_row(frame: Frame, result: dict[str, np.ndarray]) -> two_stage.TokenRow:
    """A frame scored by ``score_proposals(..., with_states=True)`` (one proposal, its plan) as a two-stage row."""
    origin = np.asarray(frame.sample["scoring"]["origin"], np.float64)
    return two_stage.TokenRow(
        token=navsim_scene_token(frame.sample),
        columns=first_row(result, epdms.FILTERED),
        start_time=frame.time_s,
        start_point=origin[:2],
        endpoint=to_global(np.asarray(frame.poses, np.float64)[-1], origin)[:2],
        simulated_states=np.asarray(result["simulated_states"])[0],
    )


def aggregate(rows: Sequence[two_stage.TokenRow], mapping: Sequence[TwoStageGroup]) -> two_stage.TwoStageResult:
    """:func:`two_stage_aggregate`, with its input errors (a stray token, frames not 0.5 s apart) as one line."""
    try:
        return two_stage.two_stage_aggregate(rows, mapping, extended_comfort_features)
    except (KeyError, ValueError) as err:
        raise UserError(str(err.args[0] if isinstance(err, KeyError) else err)) from None


def _json(value: float) -> float | None:
    return None if not math.isfinite(value) else float(value)


def summaries(result: two_stage.TwoStageResult) -> dict[str, Any]:
    """scores.json aggregates: ``epdms`` (= combined), NAVSIM's three summary scores and their sub-score means."""
    stages = dict(zip(two_stage.SUMMARY_TOKENS, (result.stage_one, result.stage_two, result.combined), strict=True))
    return {
        "epdms": _json(result.combined["score"]),
        **{token: _json(values["score"]) for token, values in stages.items()},
        **{f"{token}_columns": {k: _json(v) for k, v in values.items()} for token, values in stages.items()},
    }


def csv_table(result: two_stage.TwoStageResult) -> tuple[list[str], list[list[Any]]]:
    """NAVSIM's two-stage CSV (``navsim_csv_rows``) as a header and rows for :func:`write_csv`: pandas' index column
    first."""
    rows = two_stage.navsim_csv_rows(result)
    header = list(rows[0])
    return ["", *header], [[str(index), *(row[name] for name in header)] for index, row in enumerate(rows)]
