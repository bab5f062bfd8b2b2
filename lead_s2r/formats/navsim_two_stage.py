"""NAVSIM v2's two-stage mapping (``reactive_all_mapping`` of a train/test-split yaml such as
``navhard_two_stage.yaml``): which synthetic (stage-2) scenes continue which logged (stage-1) frames.

A source-format concern shared by the NAVSIM adapter (it records each token's stage and group) and the two-stage
EPDMS aggregation (:mod:`lead_s2r.scoring.pdm.two_stage`), so it lives below both.
"""

from collections.abc import Sequence
from dataclasses import dataclass


@dataclass(frozen=True)
class TwoStageGroup:
    """One entry of ``reactive_all_mapping``: the stage-1 frames at t = 0 and -0.5 s and their synthetic pairs."""

    original: str
    previous: str
    pairs: tuple[tuple[str, str], ...]

    def tokens(self) -> list[str]:
        return [self.original, self.previous, *(token for pair in self.pairs for token in pair)]


def parse_mapping(raw: Sequence) -> list[TwoStageGroup]:
    """NAVSIM's ``reactive_all_mapping`` (``[[orig, prev, [[now, prev], ...]], ...]``) as groups."""
    groups = []
    for i, entry in enumerate(raw):
        try:
            original, previous, pairs = entry
            parsed = tuple((str(now), str(before)) for now, before in pairs)
        except (TypeError, ValueError):
            raise ValueError(
                f"reactive_all_mapping entry {i}: expected [orig_token, prev_token, [[now, prev], ...]], got {entry!r}"
            ) from None
        groups.append(TwoStageGroup(str(original), str(previous), parsed))
    return groups
