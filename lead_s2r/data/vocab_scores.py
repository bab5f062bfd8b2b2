"""A scene's vocabulary targets (``lead-s2r vocab score``'s ``vocab_scores.pkl``, GTRS's layout) attached to its
NAVSIM samples, for a scoring head to learn every sub-score of every entry.

A sample gets ``vocab_scores`` ``(M, V)`` float32 (the pickle's metrics in its order, values as scored: NC and DDC
keep their 0.5, which GTRS maps to 0 in its loss) and ``vocab_scores_mask`` (bool): False, with zeros, for a sample
whose scene token the pickle lacks (a scene that failed, another split), so a loss can skip it. The pickle is read
once per loader worker, on first use, not sent to the workers with the pipeline."""

from pathlib import Path
from typing import Any

import numpy as np
import torch

from lead_s2r.gtrs_targets import Targets, read_targets
from lead_s2r.schema import navsim_scene_token

VOCAB_SCORES = "vocab_scores"
VOCAB_SCORES_MASK = "vocab_scores_mask"


class VocabScores:
    """Attach the targets in ``path`` to transformed samples (``__call__(sample, out)``)."""

    def __init__(self, path: str | Path) -> None:
        self.path = Path(path)
        self._targets: Targets | None = None
        self._shape: tuple[int, int] = (0, 0)

    def __getstate__(self) -> dict[str, Any]:
        return {"path": self.path, "_targets": None, "_shape": (0, 0)}

    def targets(self) -> Targets:
        if self._targets is None:
            self._targets = read_targets(self.path)
            first = next(iter(self._targets.values()), {})
            self._shape = (len(first), len(next(iter(first.values()), ())))
        return self._targets

    def __call__(self, sample: dict[str, Any], out: dict[str, Any]) -> dict[str, Any]:
        columns = self.targets().get(navsim_scene_token(sample))
        if columns is None:
            scores = np.zeros(self._shape, np.float32)
        else:
            scores = np.stack([np.asarray(values, np.float32) for values in columns.values()])
        out[VOCAB_SCORES] = torch.from_numpy(scores)
        out[VOCAB_SCORES_MASK] = torch.tensor(columns is not None)
        return out
