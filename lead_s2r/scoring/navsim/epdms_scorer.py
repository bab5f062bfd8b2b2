"""``epdms@navsim-2.2``: NAVSIM v2.2's extended PDM score of predictions on converted NAVSIM samples, one stage.

Everything per sample is as ``pdms@navsim-1.1`` does it (:mod:`lead_s2r.scoring.navsim.proposals`: input grid,
PDM-Closed reference and its cache; the scene from the sample, invalid rows for scenes without a followable route); the
sub-scores, the human penalty filter and the final score are ``score_proposals(..., metric="epdms@navsim-2.2")``'s.
What one stage adds is EC: as ``run_pdm_score_one_stage.infer_start_adjacent_mapping`` does, the valid original
(non-synthetic) frames of a log are sorted by time and each frame is paired with the one before it when they are at
most 0.55 s apart; the later frame's EC compares its simulation with that of the earlier frame's plan (ego state
there: the earlier sample's velocity and acceleration, its pose read from the later sample's ``past``). A frame
without such a predecessor has EC NaN and its score drops EC's weight (denominator 14).

Besides scores.parquet / scores.json, :meth:`EPDMSScorer.write_files` writes ``navsim_epdms.csv`` in the layout of
``run_pdm_score_one_stage.py``'s output (index column, ``token``, ``valid``, the v2 sub-scores in ``PDMResults``
order, ``two_frame_extended_comfort``, ``score``, then the ``average_all_frames`` row, NaN-skipping means).

A navhard two-stage split (samples carrying the adapter's ``two_stage_group``) is scored as NAVSIM's
``run_pdm_score.py`` scores it: every stage-1 and stage-2 frame alone, then EC per mapped pair, the pseudo
closed-loop weights and the ``extended_pdm_score_stage_one`` / ``_stage_two`` / ``_combined`` summaries
(:mod:`lead_s2r.scoring.navsim.two_stage_samples`), written to ``navsim_epdms_two_stage.csv``. One known difference:
NAVSIM's two-stage run simulates reactive IDM traffic, this scorer replays the log (``config.known_difference``).
"""

from collections import defaultdict
from collections.abc import Iterable, Sequence
from itertools import pairwise
from pathlib import Path
from typing import Any, ClassVar

import numpy as np
import pyarrow as pa

from lead_s2r.errors import UserError
from lead_s2r.formats.navsim_two_stage import TwoStageGroup
from lead_s2r.predictions import Prediction
from lead_s2r.schema import navsim_scene_token
from lead_s2r.scoring.base import ScoreResult, join
from lead_s2r.scoring.navsim import two_stage_samples as navhard
from lead_s2r.scoring.navsim.pdms_scorer import EXTRA_COLUMNS, PDMSScorer, write_csv
from lead_s2r.scoring.navsim.pdms_scorer import STEP_COLUMNS as PDMS_STEP_COLUMNS
from lead_s2r.scoring.navsim.proposals import Frame, ReferenceCache, first_row, frame_of
from lead_s2r.scoring.pdm import epdms
from lead_s2r.scoring.pdm.extended_comfort import MAX_INTERVAL_S
from lead_s2r.scoring.pdm.score import EPDMS_METRIC
from lead_s2r.scoring.pdm.two_stage import TwoStageResult

#: NAVSIM v2 CSV columns after ``token`` and ``valid``, in the one-stage runner's order.
NAVSIM_COLUMNS = (*epdms.SUB_SCORES, "score")
STEP_COLUMNS = (*PDMS_STEP_COLUMNS, "lane_keeping_fail_idx")
CSV_NAME = "navsim_epdms.csv"
#: the background traffic, in scores.json's config: NAVSIM's two-stage runner uses the reactive IDM policy for both
#: stages, this scorer (and the one-stage runner) replays the log (docs/metrics.md, "Known differences")
KNOWN_DIFFERENCE = (
    "NAVSIM's two-stage run_pdm_score.py simulates reactive (IDM) traffic in both stages; this score replays the "
    "logged traffic (docs/metrics.md)"
)
SCHEMA = pa.schema(
    [("key", pa.string()), ("dataset", pa.string()), ("token", pa.string()), ("valid", pa.bool_())]
    + [(name, pa.float64()) for name in (*NAVSIM_COLUMNS, *EXTRA_COLUMNS)]
    + [(name, pa.int64()) for name in STEP_COLUMNS]
    + [("previous_key", pa.string()), ("error", pa.string())]
)


def adjacent_frames(frames: Sequence[Frame]) -> dict[int, int]:
    """``{later: earlier}`` indices of frames paired for EC: valid, not synthetic, same log, consecutive in time and
    at most 0.55 s apart (``infer_start_adjacent_mapping``)."""
    by_log: dict[str, list[int]] = defaultdict(list)
    for index, frame in enumerate(frames):
        if frame.scene is not None and not frame.scene.is_synthetic:
            by_log[frame.log].append(index)
    pairs = {}
    for indices in by_log.values():
        ordered = sorted(indices, key=lambda i: frames[i].time_s)
        for earlier, later in pairwise(ordered):
            if abs(frames[later].time_s - frames[earlier].time_s) <= MAX_INTERVAL_S:
                pairs[later] = earlier
    return pairs


class EPDMSScorer(PDMSScorer):
    """``epdms@navsim-2.2``: per-sample NAVSIM v2.2 sub-scores, EC from adjacent frames and the final EPDMS; on a
    navhard two-stage split, NAVSIM's two-stage aggregation (:mod:`lead_s2r.scoring.navsim.two_stage_samples`)."""

    name: ClassVar[str] = EPDMS_METRIC
    version: ClassVar[str] = "1"
    fields: ClassVar[tuple[str, ...]] = (*PDMSScorer.fields, "past")
    #: NAVSIM's frames only: EC pairs adjacent frames by NAVSIM's scene tokens and navhard's two stages
    datasets: ClassVar[tuple[str, ...] | None] = ("navsim",)
    csv_columns: ClassVar[tuple[str, ...]] = NAVSIM_COLUMNS
    step_columns: ClassVar[tuple[str, ...]] = STEP_COLUMNS
    headline: ClassVar[str] = "epdms"
    csv_name: ClassVar[str] = CSV_NAME
    average_token: ClassVar[str] = "average_all_frames"

    def __init__(
        self,
        allow_missing: bool = False,
        reference_cache: str | ReferenceCache | None = None,
        two_stage: bool | None = None,
    ) -> None:
        """``two_stage``: None scores navhard's two stages when the samples carry a two-stage mapping
        (``meta.extras.navsim.two_stage_group``, written by the adapter's ``two_stage_mapping``) and one stage
        otherwise; True requires the mapping; False scores every frame as one stage."""
        if two_stage not in (None, True, False):
            raise ValueError(f"two_stage must be true, false or null (automatic), got {two_stage!r}")
        super().__init__(allow_missing, reference_cache)
        self.two_stage = two_stage
        #: the last two-stage result, laid out as NAVSIM's two-stage CSV by :meth:`write_files`
        self.two_stage_result: TwoStageResult | None = None

    def config(self) -> dict[str, Any]:
        scored = self.two_stage_result is not None
        config = {**super().config(), "two_stage": self.two_stage, "scored_two_stage": scored}
        return config | {"traffic_agents": "log_replay"} | ({"known_difference": KNOWN_DIFFERENCE} if scored else {})

    def score(self, predictions: Iterable[Prediction], data: Iterable[dict[str, Any]]) -> ScoreResult:
        """Samples of other datasets are skipped and counted, as :class:`PDMSScorer` does."""
        data = list(data)
        ours = [sample for sample in data if sample["meta"]["dataset"] in self.datasets]
        mapping = [] if self.two_stage is False else navhard.mapping_of(ours)
        if self.two_stage and not mapping:
            raise UserError(
                "--option two_stage=true: no sample carries meta.extras.navsim.two_stage_group; convert the split "
                "with the adapter's two_stage_mapping (docs/datasets/navsim.md)"
            )
        pairs = join(predictions, data, self.allow_missing)
        frames = self.map_samples(frame_of, [pair for pair in pairs if pair[0]["meta"]["dataset"] in self.datasets])
        skipped = {"frames_skipped_other_dataset": len(pairs) - len(frames)}
        self.two_stage_result = None
        if mapping:
            table, aggregates = self.score_two_stage(frames, mapping, ours)
            return ScoreResult(table, aggregates | skipped)
        earlier = adjacent_frames(frames)
        rows = self.map_samples(
            self.row, [(frame, frames[earlier[i]] if i in earlier else None) for i, frame in enumerate(frames)]
        )
        table = pa.Table.from_pylist(rows, schema=SCHEMA)
        return ScoreResult(table, {**self._aggregate(rows), **skipped})

    def score_two_stage(
        self, frames: list[Frame], mapping: list[TwoStageGroup], samples: list[dict[str, Any]]
    ) -> tuple[pa.Table, dict[str, Any]]:
        """Every frame of the mapping scored alone, then NAVSIM's two-stage weights, EC and summaries."""
        navhard.check_complete(mapping, samples, {navsim_scene_token(frame.sample): frame.error for frame in frames})
        results = self.map_samples(self.proposal_scores, [(frame, None, True) for frame in frames])
        tokens = [navsim_scene_token(frame.sample) for frame in frames]
        rows = [navhard.token_row(frame, result) for frame, result in zip(frames, results, strict=True)]
        self.two_stage_result = navhard.aggregate(rows, mapping)
        table = []
        for token, frame, result in zip(tokens, frames, results, strict=True):
            per = self.two_stage_result.per_token[token]
            table.append(
                {"key": frame.sample["__key__"], "dataset": frame.sample["meta"]["dataset"], "token": token}
                | {"valid": True, "stage": int(per["stage"]), "weight": per["weight"], "error": None}
                | {"two_stage_role": navhard.navsim_extras(frame.sample).get("two_stage_role")}
                | {name: per[name] for name in navhard.TABLE_COLUMNS}
                | first_row(result, EXTRA_COLUMNS)
            )
        stage_one = sum(1 for row in table if row["stage"] == 1)
        counts = {"frames": len(table), "frames_valid": len(table), "frames_failed": 0, "groups": len(mapping)}
        counts |= {"frames_stage_one": stage_one, "frames_stage_two": len(table) - stage_one}
        return pa.Table.from_pylist(table, schema=navhard.SCHEMA), navhard.summaries(self.two_stage_result) | counts

    def _aggregate(self, rows: list[dict[str, Any]]) -> dict[str, Any]:
        with_ec = sum(1 for row in rows if row["valid"] and np.isfinite(row[epdms.EC]))
        return {**super()._aggregate(rows), "frames_with_ec": with_ec}

    def write_files(self, result: ScoreResult, out: Path) -> None:
        """``navsim_epdms.csv`` (one stage) or ``navsim_epdms_two_stage.csv`` (NAVSIM's two-stage layout)."""
        if self.two_stage_result is None:
            return super().write_files(result, out)
        write_csv(Path(out) / navhard.CSV_NAME, *navhard.csv_table(self.two_stage_result))
