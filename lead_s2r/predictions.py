"""The ``predictions.parquet`` format: what a planner predicted for each sample, as scorers read it.

One row per (sample, inference): ``key`` str, ``dataset`` str, ``t``/``x``/``y``/``yaw`` list<float32> in the ISO
ego frame of the sample (rear axle at t0, x forward, y left), ``t`` > 0 in seconds and strictly increasing, and
optionally ``probability`` float and ``inference`` int for multi-modal outputs. ``yaw`` may be NaN where a
model predicts no heading; ``t``, ``x``, ``y`` must be finite. :func:`write_predictions` stores a CRC32 of every
data page and :func:`read_predictions` checks those a file carries, and the column names against the copy of the
schema pyarrow keeps beside them (:mod:`lead_s2r.files`): parquet has no other guard, so a flipped bit in a
coordinate or a column name would otherwise be scored as a slightly different prediction or a missing column.

:func:`on_grid` puts trajectories on a scorer's time grid. A prediction on another grid (e.g. 2 Hz x 10) is
linearly interpolated, with the ego origin (0, 0) at t = 0 as the first knot, because the sample's ego frame
puts the ego there. It never extrapolates: a target time after the last predicted one is an error, so a 5 s
checkpoint is never filled by copying the 4.75 s point.
"""

from collections import defaultdict
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path

import numpy as np
import pyarrow as pa

from lead_s2r.errors import UserError
from lead_s2r.files import read_parquet, write_parquet

#: Seconds within which two time stamps are the same grid point.
TIME_TOLERANCE = 1e-3

SCHEMA = pa.schema(
    [
        ("key", pa.string()),
        ("dataset", pa.string()),
        ("t", pa.list_(pa.float32())),
        ("x", pa.list_(pa.float32())),
        ("y", pa.list_(pa.float32())),
        ("yaw", pa.list_(pa.float32())),
        ("probability", pa.float64()),
        ("inference", pa.int32()),
    ]
)
REQUIRED_COLUMNS = ("key", "dataset", "t", "x", "y", "yaw")


class PredictionError(UserError, ValueError):
    """A prediction is malformed; the message names the sample key (or the row when the key itself is bad)."""


@dataclass(frozen=True, eq=False)
class Prediction:
    """One predicted trajectory of one sample; ``xy`` is (T, 2), ``t`` and ``yaw`` are (T,)."""

    key: str
    dataset: str
    t: np.ndarray
    xy: np.ndarray
    yaw: np.ndarray
    probability: float = 1.0
    inference: int = 0

    def __post_init__(self) -> None:
        """Raise :class:`PredictionError` naming the key if this prediction breaks the format."""
        key = self.key
        if not isinstance(key, str) or not key:
            raise PredictionError(f"prediction with missing key (got {key!r}, dataset {self.dataset!r})")
        t, xy, yaw = np.asarray(self.t), np.asarray(self.xy), np.asarray(self.yaw)
        if t.ndim != 1 or xy.shape != (len(t), 2) or yaw.shape != t.shape:
            raise PredictionError(
                f"prediction {key!r}: ragged lengths: t {t.shape}, xy {xy.shape} (want (T, 2)), yaw {yaw.shape}"
            )
        if len(t) == 0:
            raise PredictionError(f"prediction {key!r}: empty trajectory")
        if not (np.isfinite(t).all() and np.isfinite(xy).all()):
            raise PredictionError(f"prediction {key!r}: t, x, y must be finite (found NaN or inf)")
        if np.isinf(yaw).any():
            raise PredictionError(f"prediction {key!r}: yaw must not be infinite")
        if t[0] <= 0 or (np.diff(t) <= 0).any():
            raise PredictionError(f"prediction {key!r}: t must be > 0 and strictly increasing, got {t.tolist()}")
        probability = self.probability
        if not (np.isfinite(probability) and 0.0 <= probability <= 1.0):
            raise PredictionError(f"prediction {key!r}: probability must lie in [0, 1], got {probability!r}")


def write_predictions(path: str | Path, predictions: Iterable[Prediction]) -> Path:
    """Write predictions to a parquet file (checked on construction, duplicates rejected)."""
    predictions = list(predictions)
    _check_unique(predictions)
    columns = {
        "key": [p.key for p in predictions],
        "dataset": [p.dataset for p in predictions],
        "t": [np.asarray(p.t, np.float32) for p in predictions],
        "x": [np.asarray(p.xy[:, 0], np.float32) for p in predictions],
        "y": [np.asarray(p.xy[:, 1], np.float32) for p in predictions],
        "yaw": [np.asarray(p.yaw, np.float32) for p in predictions],
        "probability": [float(p.probability) for p in predictions],
        "inference": [int(p.inference) for p in predictions],
    }
    table = pa.table(columns, schema=SCHEMA)
    return write_parquet(Path(path), table)


def read_predictions(path: str | Path) -> list[Prediction]:
    """Read and check a predictions file; a single inference per key may omit ``probability``/``inference``."""
    try:
        table = read_parquet(path)
    except (OSError, pa.ArrowException, ValueError) as err:  # ValueError: a name that is not UTF-8 or base64
        raise PredictionError(
            f"{path}: not a readable parquet file ({err}); write it with lead_s2r.predictions.write_predictions"
        ) from None
    missing = [name for name in REQUIRED_COLUMNS if name not in table.column_names]
    if missing:
        raise PredictionError(f"{path}: missing column(s) {missing}; expected {list(REQUIRED_COLUMNS)}")
    predictions = []
    for index, row in enumerate(table.to_pylist()):
        key = row["key"]
        if key is None or key == "":
            raise PredictionError(f"{path}: row {index} has a missing key")
        arrays = [row[name] for name in ("t", "x", "y", "yaw")]
        if any(array is None for array in arrays):
            raise PredictionError(f"{path}: prediction {key!r}: t, x, y and yaw must all be given")
        t, x, y, yaw = (np.asarray(array, np.float32) for array in arrays)
        if not len(t) == len(x) == len(y) == len(yaw):
            raise PredictionError(
                f"{path}: prediction {key!r}: ragged lengths t {len(t)}, x {len(x)}, y {len(y)}, yaw {len(yaw)}"
            )
        probability = row.get("probability")
        try:
            predictions.append(
                Prediction(
                    key=key,
                    dataset=row["dataset"] or "",
                    t=t,
                    xy=np.stack([x, y], axis=-1),
                    yaw=yaw,
                    probability=1.0 if probability is None else float(probability),
                    inference=int(row.get("inference") or 0),
                )
            )
        except PredictionError as err:
            raise PredictionError(f"{path}: {err}") from None
    _check_unique(predictions)
    if "probability" not in table.column_names:
        multi = [key for key, group in group_by_key(predictions).items() if len(group) > 1]
        if multi:
            raise PredictionError(f"{path}: several inferences for {multi[0]!r} but no 'probability' column")
    return predictions


def _check_unique(predictions: Sequence[Prediction]) -> None:
    seen = set()
    for p in predictions:
        if (p.key, p.inference) in seen:
            raise PredictionError(f"prediction {p.key!r}: inference {p.inference} appears twice")
        seen.add((p.key, p.inference))


def drop_repeats(predictions: Iterable[Prediction]) -> list[Prediction]:
    """The first prediction of every (key, inference), in first-seen order: a distributed sampler pads the last
    batches with samples it already gave out, so gathered predictions may repeat."""
    unique: dict[tuple[str, int], Prediction] = {}
    for p in predictions:
        unique.setdefault((p.key, p.inference), p)
    return list(unique.values())


def group_by_key(predictions: Iterable[Prediction]) -> dict[str, list[Prediction]]:
    """Inferences of each sample key, ordered by ``inference``; keys in first-seen order."""
    groups: dict[str, list[Prediction]] = defaultdict(list)
    for p in predictions:
        groups[p.key].append(p)
    return {key: sorted(group, key=lambda p: p.inference) for key, group in groups.items()}


def most_probable(inferences: Sequence[Prediction]) -> Prediction:
    """The highest-probability inference of one sample (the lowest ``inference`` on ties): the one trajectory a
    scorer scores, a leaderboard takes and a report draws when a planner predicts several."""
    return min(inferences, key=lambda p: (-p.probability, p.inference))


@lru_cache(maxsize=256)
def _interpolation_matrix(t_source: bytes, t_target: bytes) -> np.ndarray:
    """(len(target), len(source) + 1) weights over [origin at t = 0, source points]; cached per grid pair."""
    source = np.concatenate([[0.0], np.frombuffer(t_source, np.float64)])
    target = np.frombuffer(t_target, np.float64)
    if len(source) == len(target) + 1 and np.abs(source[1:] - target).max() <= TIME_TOLERANCE:
        return np.eye(len(target), len(source), k=1)
    index = np.clip(np.searchsorted(source, target, side="right") - 1, 0, len(source) - 2)
    weight = (target - source[index]) / (source[index + 1] - source[index])
    matrix = np.zeros((len(target), len(source)))
    rows = np.arange(len(target))
    matrix[rows, index] = 1.0 - weight
    matrix[rows, index + 1] += weight
    return matrix


def on_grid(frames: Sequence[Sequence[Prediction]], t_target: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Trajectories of B frames on the time grid ``t_target``: xy (B, I, T, 2) float64 and probabilities (B, I).

    Frames with fewer inferences than the widest are padded with copies of their last one at probability 0, which
    leaves any probability-weighted sum unchanged; a prediction that ends early is a :class:`PredictionError`."""
    t_target = np.asarray(t_target, np.float64)
    width = max((len(frame) for frame in frames), default=1)
    xy = np.empty((len(frames), width, len(t_target), 2))
    probabilities = np.zeros((len(frames), width))
    groups: dict[bytes, list[tuple[int, int, Prediction]]] = defaultdict(list)
    for b, frame in enumerate(frames):
        for i in range(width):
            p = frame[min(i, len(frame) - 1)]
            if i < len(frame):
                probabilities[b, i] = p.probability
            groups[np.asarray(p.t, np.float64).tobytes()].append((b, i, p))
    target_bytes = t_target.tobytes()
    for t_bytes, members in groups.items():
        horizon = np.frombuffer(t_bytes, np.float64)[-1]
        if horizon < t_target[-1] - TIME_TOLERANCE:
            key = members[0][2].key
            raise PredictionError(
                f"prediction {key!r}: horizon {horizon:g} s ends before the scored {t_target[-1]:g} s "
                f"(predictions are never extrapolated; {len(members)} trajectory(ies) on this grid)"
            )
        matrix = _interpolation_matrix(t_bytes, target_bytes)
        source = np.stack([p.xy for _, _, p in members]).astype(np.float64)
        padded = np.concatenate([np.zeros((len(members), 1, 2)), source], axis=1)
        b_index = np.fromiter((b for b, _, _ in members), np.intp, len(members))
        i_index = np.fromiter((i for _, i, _ in members), np.intp, len(members))
        xy[b_index, i_index] = np.einsum("ts,nsc->ntc", matrix, padded)
    return xy, probabilities


def regular_grid(frequency: float, length_seconds: float) -> np.ndarray:
    """Times 1/f, 2/f, ..., length_seconds: the grid WOD-E2E futures and RFS use (4 Hz x 5 s = 20 points)."""
    count = round(frequency * length_seconds)
    return np.arange(1, count + 1, dtype=np.float64) / frequency
