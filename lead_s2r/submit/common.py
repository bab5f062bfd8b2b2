"""What both submission writers share: the error type, the split's samples, one trajectory per sample, writing.

Leaderboards reject a malformed file with no reason given ("Invalid Submission File", "Missing 961 sequence
names"), so every check runs before a byte is written, and a failure is a :class:`SubmissionError` (a ValueError)
whose one-line message names the file, token or field. Files are written to a temporary name and renamed, so a
failed run never leaves a half-written submission behind.
"""

from collections.abc import Iterable, Sequence
from pathlib import Path
from typing import Any

from lead_s2r.errors import UserError, listing
from lead_s2r.predictions import Prediction, group_by_key, most_probable, read_predictions
from lead_s2r.shards import read_samples


class SubmissionError(UserError, ValueError):
    """A submission the server would reject; the message names the file, token/frame or field."""


def require_coverage(
    what: str, expected: Iterable[str], given: Iterable[str], source: str, exact: bool = False
) -> None:
    """Raise naming every expected ``what`` (token, frame) that ``source`` has no prediction for; with ``exact``, also
    every one it has that the split does not."""
    expected, given = set(expected), set(given)
    missing = expected - given
    if missing:
        raise SubmissionError(
            f"{source}: {len(missing)} of {len(expected)} {what}s have no prediction: {listing(missing)}"
        )
    if exact and given - expected:
        raise SubmissionError(f"{source}: {what}s not in the split: {listing(given - expected)}")


def split_metas(data: Sequence[Path], dataset: str) -> dict[str, dict[str, Any]]:
    """``meta`` of every ``dataset`` sample in the converted folders, by sample key."""
    metas: dict[str, dict[str, Any]] = {}
    for folder in data:
        if not Path(folder).is_dir():
            raise SubmissionError(f"{folder}: no such converted folder (--data)")
        found = {
            s["__key__"]: s["meta"] for s in read_samples(folder, fields=("meta",)) if s["meta"]["dataset"] == dataset
        }
        if not found:
            raise SubmissionError(f"{folder}: no {dataset} samples; pass the folder `lead-s2r convert {dataset}` wrote")
        metas.update(found)
    return metas


def best_inferences(path: Path) -> dict[str, Prediction]:
    """The most probable inference of every key in a predictions file: both leaderboards take exactly one trajectory
    per token / frame."""
    if not Path(path).is_file():
        raise SubmissionError(f"{path}: no such predictions file (--predictions)")
    groups = group_by_key(read_predictions(path))
    return {key: most_probable(group) for key, group in groups.items()}


def require_text(value: str | None, field: str, option: str) -> str:
    """A non-empty metadata string, or an error naming the field and the option that sets it."""
    if value is None or not str(value).strip():
        raise SubmissionError(f"metadata field {field!r} is missing or empty; set it with {option}")
    return str(value).strip()
