"""Rater Feedback Score (WOD-E2E 2025), written from its definition and vectorised over frames.

Per frame, up to 3 rated trajectories with scores in [0, 10]. At the 3 s and 5 s checkpoints, the prediction's
offset from each rater is split into a longitudinal part (along the rater's own direction of travel at that
waypoint, from backward differences) and a lateral part; each is divided by a speed-scaled threshold and the
larger ratio ``nd`` gives ``label * decay ** max(nd - 1, 0)``. The best rater at each checkpoint counts
(checkpoints may pick different raters), the checkpoints are averaged, and a prediction outside every single
rater's box at both checkpoints is raised to the floor. Multiple inferences are summed with their probabilities.
All arithmetic is float64 over arrays [frames, inferences, raters, checkpoints]. See ``docs/metrics.md``.
"""

from collections.abc import Iterable, Sequence
from dataclasses import asdict, dataclass
from typing import Any, ClassVar

import numpy as np
import pyarrow as pa

from lead_s2r.predictions import Prediction, on_grid, regular_grid
from lead_s2r.schema import SchemaError
from lead_s2r.scoring.base import Scorer, ScoreResult, join, mean_or_none


@dataclass(frozen=True)
class RFSConfig:
    """Constants of the metric; the defaults are the official WOD-E2E 2025 ones."""

    threshold_times: tuple[float, ...] = (3.0, 5.0)
    base_thresholds: tuple[float, ...] = (1.0, 1.8)
    lat_lng_multipliers: tuple[float, float] = (1.0, 4.0)
    decay: float = 0.1
    floor: float = 4.0
    frequency: float = 4.0
    length_seconds: float = 5.0
    num_raters: int = 3
    speed_range: tuple[float, float] = (1.4, 11.0)
    scale_range: tuple[float, float] = (0.5, 1.0)

    @property
    def num_points(self) -> int:
        return round(self.frequency * self.length_seconds)

    @property
    def checkpoint_indices(self) -> np.ndarray:
        """Waypoint index of each threshold time (t = (k + 1) / f)."""
        return np.array([round(t * self.frequency) - 1 for t in self.threshold_times])


@dataclass
class RFSResult:
    """Per-frame score (B,), per-inference score (B, I) and trust-region flag (B, I), checkpoint scores (B, I, H)."""

    score: np.ndarray
    per_inference: np.ndarray
    fully_within: np.ndarray
    checkpoint_scores: np.ndarray


def pad_raters(
    trajectories: np.ndarray,
    lengths: np.ndarray,
    counts: np.ndarray,
    labels: np.ndarray,
    config: RFSConfig = RFSConfig(),
) -> tuple[np.ndarray, np.ndarray]:
    """Raters to exactly ``num_raters`` x ``num_points``: (B, P, T, 2) and labels (B, P), float64.

    Input is padded: trajectories (B, Pmax, Tmax, 2), lengths (B, Pmax) valid points per rater, counts (B,) valid
    raters per frame. Extra raters and points are cut; missing raters repeat the last rater and its label, missing
    points repeat the rater's last point."""
    lengths = np.asarray(lengths)
    counts = np.asarray(counts)
    if (counts < 1).any() or (lengths[np.arange(lengths.shape[1]) < counts[:, None]] < 1).any():
        raise ValueError("every frame needs at least one rater and every rater at least one point")
    frames = np.arange(len(counts))[:, None]
    rater = np.minimum(np.arange(config.num_raters)[None, :], counts[:, None] - 1)
    point = np.minimum(np.arange(config.num_points)[None, None, :], lengths[frames, rater][..., None] - 1)
    padded = np.asarray(trajectories, np.float64)[frames[..., None], rater[..., None], point]
    return padded, np.asarray(labels, np.float64)[frames, rater]


def _directions(raters: np.ndarray, indices: np.ndarray) -> np.ndarray:
    """Unit direction of travel (..., H, 2) of each rater at the waypoint indices: the backward difference
    r_t - r_(t-1) with the origin before r_0; a zero difference keeps the previous direction, and before the first
    non-zero one the direction is +x."""
    steps = np.diff(raters, axis=-2, prepend=0.0)
    moving = (steps != 0).any(axis=-1)
    last_moving = np.maximum.accumulate(np.where(moving, np.arange(raters.shape[-2]), -1), axis=-1)[..., indices]
    direction = np.take_along_axis(steps, np.maximum(last_moving, 0)[..., None], axis=-2)
    direction[last_moving < 0] = (1.0, 0.0)
    return direction / np.linalg.norm(direction, axis=-1, keepdims=True)


def speed_scale(speed: np.ndarray, config: RFSConfig = RFSConfig()) -> np.ndarray:
    """Trust-region scale: ``scale_range[0]`` up to ``speed_range[0]``, linear to ``scale_range[1]`` at the top."""
    (v_low, v_high), (s_low, s_high) = config.speed_range, config.scale_range
    fraction = (np.asarray(speed, np.float64) - v_low) / (v_high - v_low)
    return np.clip(s_low + (s_high - s_low) * fraction, s_low, s_high)


def rater_feedback_score(
    predictions: np.ndarray,
    probabilities: np.ndarray,
    raters: np.ndarray,
    labels: np.ndarray,
    speed: np.ndarray,
    config: RFSConfig = RFSConfig(),
) -> RFSResult:
    """RFS of B frames: predictions (B, I, T, 2) with probabilities (B, I); raters (B, P, T, 2) and labels (B, P)
    as :func:`pad_raters` returns them; speed (B,) the ego speed at t0 in m/s."""
    predictions = np.asarray(predictions, np.float64)
    raters = np.asarray(raters, np.float64)
    if predictions.ndim != 4 or raters.ndim != 4 or predictions.shape[2:] != raters.shape[2:]:
        raise ValueError(
            f"predictions (B, I, T, 2) and raters (B, P, T, 2) disagree: {predictions.shape}, {raters.shape}"
        )
    if predictions.shape[2] < config.checkpoint_indices.max() + 1:
        raise ValueError(f"trajectories of {predictions.shape[2]} points do not reach the last checkpoint")
    indices = config.checkpoint_indices
    longitudinal = _directions(raters, indices)[:, None]  # (B, 1, P, H, 2)
    lateral = np.stack([-longitudinal[..., 1], longitudinal[..., 0]], axis=-1)
    offset = predictions[:, :, None, indices] - raters[:, None, :, indices]  # (B, I, P, H, 2)
    scale = speed_scale(speed, config)[:, None, None, None]
    base = np.asarray(config.base_thresholds, np.float64)
    lat_multiplier, lng_multiplier = config.lat_lng_multipliers
    lng_distance = np.abs((offset * longitudinal).sum(-1)) / (scale * base * lng_multiplier)
    lat_distance = np.abs((offset * lateral).sum(-1)) / (scale * base * lat_multiplier)
    distance = np.maximum(lng_distance, lat_distance)
    per_rater = np.asarray(labels, np.float64)[:, None, :, None] * config.decay ** np.maximum(distance - 1.0, 0.0)
    checkpoint_scores = per_rater.max(axis=2)  # (B, I, H)
    fully_within = (distance <= 1.0).all(axis=-1).any(axis=-1)  # (B, I)
    per_inference = checkpoint_scores.mean(axis=-1)
    per_inference = np.where(fully_within, per_inference, np.maximum(per_inference, config.floor))
    probabilities = np.asarray(probabilities, np.float64)
    return RFSResult((per_inference * probabilities).sum(-1), per_inference, fully_within, checkpoint_scores)


def rater_arrays(samples: Sequence[dict[str, Any]]) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Stack the ``raters`` fields of samples (each with at least one rating) into :func:`pad_raters` inputs;
    ratings below 0 (unlabelled) are dropped here too, in case a converter kept them."""
    frames = []
    for sample in samples:
        trajectories, lengths, scores = (
            np.asarray(sample["raters"][name]) for name in ("trajectories", "lengths", "scores")
        )
        _check_raters(sample["__key__"], trajectories, lengths, scores)
        valid = scores >= 0
        frames.append((trajectories[valid], lengths[valid], scores[valid]))
    width = max(len(scores) for _, _, scores in frames)
    longest = max(trajectories.shape[1] for trajectories, _, _ in frames)
    stacked = np.full((len(frames), width, longest, 2), np.nan)
    lengths = np.zeros((len(frames), width), np.int64)
    labels = np.zeros((len(frames), width))
    for b, (trajectories, length, scores) in enumerate(frames):
        stacked[b, : len(scores), : trajectories.shape[1]] = trajectories
        lengths[b, : len(scores)] = length
        labels[b, : len(scores)] = scores
    counts = np.array([len(scores) for _, _, scores in frames])
    return stacked, lengths, counts, labels


def _check_raters(key: str, trajectories: np.ndarray, lengths: np.ndarray, scores: np.ndarray) -> None:
    """Raise :class:`SchemaError` naming the sample if its ``raters`` field cannot be scored."""
    if (
        trajectories.ndim != 3
        or trajectories.shape[2] != 2
        or not (lengths.shape == scores.shape == (len(trajectories),))
    ):
        raise SchemaError(key, "raters", "expected trajectories (P, T, 2), lengths (P,), scores (P,)")
    if (lengths < 1).any() or (lengths > trajectories.shape[1]).any():
        raise SchemaError(key, "raters", f"lengths {lengths.tolist()} outside 1..{trajectories.shape[1]}")
    valid_points = np.arange(trajectories.shape[1]) < lengths[:, None]
    if not np.isfinite(trajectories[valid_points]).all():
        raise SchemaError(key, "raters", "trajectories must be finite within their lengths")


def has_rating(sample: dict[str, Any]) -> bool:
    """Whether a sample carries at least one usable rated trajectory."""
    raters = sample.get("raters")
    return raters is not None and bool((np.asarray(raters.get("scores", [])) >= 0).any())


def cluster_of(sample: dict[str, Any]) -> str | None:
    """WOD-E2E scenario cluster of a sample, if the converter knew it."""
    return sample["meta"].get("extras", {}).get("wod_e2e", {}).get("cluster")


class RFSScorer(Scorer):
    """``rfs@wod-e2e-2025``: RFS of every rated frame, frame mean and the official cluster macro-average."""

    name: ClassVar[str] = "rfs@wod-e2e-2025"
    version: ClassVar[str] = "1"
    fields: ClassVar[tuple[str, ...]] = ("raters",)
    required: ClassVar[tuple[str, ...]] = ("raters",)

    def __init__(self, allow_missing: bool = False, **constants: Any) -> None:
        """``constants`` override :class:`RFSConfig` fields (thresholds, decay, floor, frequency...)."""
        super().__init__(allow_missing)
        self.rfs = RFSConfig(**{k: tuple(v) if isinstance(v, list) else v for k, v in constants.items()})

    def config(self) -> dict[str, Any]:
        return {**super().config(), **asdict(self.rfs)}

    def score(self, predictions: Iterable[Prediction], data: Iterable[dict[str, Any]]) -> ScoreResult:
        pairs = join(predictions, data, self.allow_missing)
        rated = [(sample, frame) for sample, frame in pairs if has_rating(sample)]
        names = [f"rfs_{t:g}s" for t in self.rfs.threshold_times]
        schema = pa.schema(
            [("key", pa.string()), ("dataset", pa.string()), ("cluster", pa.string()), ("speed", pa.float64())]
            + [(name, pa.float64()) for name in ("rfs", *names)]
            + [("fully_within", pa.bool_()), ("best_label", pa.float64())]
        )
        columns: dict[str, list[Any]] = {name: [] for name in schema.names}
        if rated:
            samples = [sample for sample, _ in rated]
            xy, probabilities = on_grid(
                [frame for _, frame in rated], regular_grid(self.rfs.frequency, self.rfs.length_seconds)
            )
            raters, labels = pad_raters(*rater_arrays(samples), self.rfs)
            speed = np.array([sample["meta"]["ego"]["speed"] for sample in samples], np.float64)
            result = rater_feedback_score(xy, probabilities, raters, labels, speed, self.rfs)
            columns = {
                "key": [sample["__key__"] for sample in samples],
                "dataset": [sample["meta"]["dataset"] for sample in samples],
                "cluster": [cluster_of(sample) for sample in samples],
                "speed": speed.tolist(),
                "rfs": result.score.tolist(),
                **{
                    name: (result.checkpoint_scores[..., h] * probabilities).sum(-1).tolist()
                    for h, name in enumerate(names)
                },
                "fully_within": result.fully_within[np.arange(len(samples)), probabilities.argmax(-1)].tolist(),
                "best_label": labels.max(-1).tolist(),
            }
        table = pa.table(columns, schema=schema)
        return ScoreResult(table, self._aggregate(table, len(pairs), len(pairs) - len(rated)))

    def _aggregate(self, table: pa.Table, frames: int, skipped: int) -> dict[str, Any]:
        scores = np.asarray(table["rfs"].to_pylist(), np.float64)
        clusters = table["cluster"].to_pylist()
        per_cluster: dict[str, list[float]] = {}
        for cluster, value in zip(clusters, scores, strict=True):
            if cluster is not None:
                per_cluster.setdefault(cluster, []).append(value)
        cluster_means = {name: float(np.mean(values)) for name, values in sorted(per_cluster.items())}
        return {
            "rfs": mean_or_none(scores),
            "rfs_cluster_macro": float(np.mean(list(cluster_means.values()))) if cluster_means else None,
            "rfs_per_cluster": cluster_means,
            "fully_within_rate": mean_or_none(table["fully_within"].to_pylist()),
            "frames": frames,
            "frames_scored": len(scores),
            "frames_skipped_no_rating": skipped,
            "frames_without_cluster": int(sum(cluster is None for cluster in clusters)),
        }
