"""Ragged per-frame rater lists (as WOD-E2E's protos and the official samples give them) as :func:`pad_raters`
input, through the same stacking the scorer applies to converted samples (:func:`rater_arrays`)."""

from collections.abc import Sequence

import numpy as np

from lead_s2r.scoring.rfs import RFSConfig, pad_raters, rater_arrays


def pad_rater_lists(
    trajectories: Sequence[Sequence[np.ndarray]],
    labels: Sequence[Sequence[float]],
    config: RFSConfig | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """Frames of (T_p, 2) rater trajectories and their labels, padded to the config's raters x points."""
    samples = []
    for index, (frame, frame_labels) in enumerate(zip(trajectories, labels, strict=True)):
        padded = np.full((len(frame), max(len(t) for t in frame), 2), np.nan)
        for p, trajectory in enumerate(frame):
            padded[p, : len(trajectory)] = trajectory
        lengths = np.array([len(t) for t in frame])
        raters = {"trajectories": padded, "lengths": lengths, "scores": np.asarray(frame_labels, np.float64)}
        samples.append({"__key__": f"frame{index}", "raters": raters})
    return pad_raters(*rater_arrays(samples), config or RFSConfig())
