"""NAVSIM leaderboard ``submission.pkl`` (v1.1, and v2's two-stage navhard format), written without NAVSIM or nuPlan.

What the server loads (``run_create_submission_pickle.py``; shared/research/closed_loop_and_submissions.md §3.1): a
dict with exactly the keys ``team_name``, ``authors``, ``email``, ``institution``, ``"country / region"`` (spaces
and slash: the config field is ``country``, the key is not), and either ``predictions`` (v1.1: a list with one
``{token: Trajectory}`` dict per seed; NAVSIM's merge script asserts every dict covers every token of the split)
or ``first_stage_predictions`` / ``second_stage_predictions`` (v2). A ``Trajectory`` is NAVSIM's dataclass
``navsim.common.dataclasses.Trajectory(poses, trajectory_sampling)``: ``poses`` (8, 3) float32 (x, y, heading) in
the rear-axle frame at t0, sampled by nuPlan's ``TrajectorySampling(time_horizon=4, interval_length=0.5)``
(``num_poses`` 8). The server unpickles with both packages installed, so the file names their classes by module
path (:mod:`lead_s2r.formats.foreign_pickle`: written as the real dataclasses pickle, ``__post_init__`` not run on load)
and holds arrays in numpy 1.x's layout (NAVSIM pins numpy 1.23.4, which cannot import numpy 2's ``numpy._core``).

Two-stage (navhard): the first stage is every original scene of the split (NAVSIM's ``tokens_stage_one``, here
the converted non-synthetic samples); the second stage is the reactive synthetic scenes (``reactive_tokens_stage_two``,
here the converted mapping's ``stage_two_tokens`` in info.json). v2 scores one seed: its scoring script asserts
one dict per stage list. Poses come from our predictions by :func:`lead_s2r.scoring.navsim_grid.navsim_poses` (the ego
at the origin at t = 0 is the first knot; never extrapolated).
"""

import io
import math
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from lead_s2r.files import write_bytes
from lead_s2r.formats import restricted_pickle
from lead_s2r.formats.foreign_pickle import ForeignClass, ForeignObject, dumps, numpy1_array
from lead_s2r.predictions import PredictionError
from lead_s2r.scoring.navsim_grid import INTERVAL, NUM_POSES, navsim_poses
from lead_s2r.shards import load_info
from lead_s2r.submit.common import (
    SubmissionError,
    best_inferences,
    listing,
    require_coverage,
    require_text,
    split_metas,
)

TRAJECTORY = ForeignClass("navsim.common.dataclasses", "Trajectory")
TRAJECTORY_SAMPLING = ForeignClass("nuplan.planning.simulation.trajectory.trajectory_sampling", "TrajectorySampling")
#: The file name the leaderboard looks for in the uploaded Hugging Face model repo.
UPLOAD_NAME = "submission.pkl"
SAMPLING = {"num_poses": NUM_POSES, "time_horizon": NUM_POSES * INTERVAL, "interval_length": INTERVAL}
#: Server key -> our metadata field.
METADATA_KEYS = {
    "team_name": "team_name",
    "authors": "authors",
    "email": "email",
    "institution": "institution",
    "country / region": "country",
}
#: Our metadata field -> the ``lead-s2r submit navsim`` option that sets it.
OPTIONS = {field: f"--{field}" for field in METADATA_KEYS.values()} | {"team_name": "--team"}
V1_LISTS = ("predictions",)
V2_LISTS = ("first_stage_predictions", "second_stage_predictions")
#: NAVSIM v2's ``run_pdm_score_from_submission.py`` asserts one dict per stage.
V2_ONE_SEED = "NAVSIM v2 scores exactly one seed (one dict per stage): pass one predictions file"
LABELS = {
    "predictions": "token",
    "first_stage_predictions": "first-stage token",
    "second_stage_predictions": "second-stage token",
}


@dataclass(frozen=True)
class NavsimMetadata:
    """Who submits; every field is required by the server (NAVSIM's scripts refuse to run without them)."""

    team_name: str
    authors: str
    email: str
    institution: str
    country: str

    def __post_init__(self) -> None:
        for field in METADATA_KEYS.values():
            object.__setattr__(self, field, require_text(getattr(self, field), field, OPTIONS[field]))

    def as_keys(self) -> dict[str, str]:
        """The metadata under the server's key names."""
        return {key: getattr(self, field) for key, field in METADATA_KEYS.items()}


@dataclass(frozen=True)
class Split:
    """The tokens a submission must cover, per predictions list, and which sample key holds each token."""

    tokens: dict[str, list[str]]  # list key ("predictions", ...) -> scene tokens
    keys: dict[str, str]  # scene token -> sample key


def read_split(data: Sequence[Path], two_stage: bool) -> Split:
    """Tokens of the converted split(s): every scene (v1.1), or stage one and stage two (v2, navhard)."""
    metas = split_metas(data, "navsim")
    keys = {meta["extras"]["navsim"]["scene_token"]: key for key, meta in metas.items()}
    synthetic = {meta["extras"]["navsim"]["scene_token"] for meta in metas.values() if meta["is_synthetic"]}
    if not two_stage:
        if synthetic:
            raise SubmissionError(
                f"{', '.join(map(str, data))}: holds {len(synthetic)} synthetic (stage-two) scenes; a two-stage split "
                "is submitted with --two-stage"
            )
        return Split({"predictions": sorted(keys)}, keys)
    stage_two: list[str] = []
    for folder in data:
        mapping = load_info(folder).get("two_stage")
        if not mapping:
            raise SubmissionError(
                f"{folder}/info.json: no 'two_stage' tokens; convert the split with --two-stage-mapping"
            )
        stage_two += mapping["stage_two_tokens"]
    absent = set(stage_two) - synthetic
    if absent:
        raise SubmissionError(f"{data[0]}: stage-two tokens of the mapping with no converted scene: {listing(absent)}")
    stage_one = sorted(set(keys) - synthetic)
    return Split({"first_stage_predictions": stage_one, "second_stage_predictions": sorted(set(stage_two))}, keys)


def seed_lists(split: Split, predictions: Sequence[Path]) -> dict[str, list[dict[str, np.ndarray]]]:
    """One ``{token: poses}`` dict per predictions file (seed) for each list of the split; all tokens covered."""
    lists: dict[str, list[dict[str, np.ndarray]]] = {name: [] for name in split.tokens}
    for path in predictions:
        best = best_inferences(path)
        by_token = {token: best[key] for token, key in split.keys.items() if key in best}
        for name, tokens in split.tokens.items():
            require_coverage(LABELS[name], tokens, by_token, str(path))
            try:
                lists[name].append({token: navsim_poses(by_token[token]).astype(np.float32) for token in tokens})
            except PredictionError as err:  # no heading or a horizon short of 4 s: name the file too
                raise SubmissionError(f"{path}: {err}") from None
    return lists


def validate(submission: dict[str, Any], expected: dict[str, list[str]] | None = None) -> None:
    """Raise naming the key, seed or token if ``submission`` (metadata + ``{token: poses}`` lists) is not what the
    server reads. ``expected``: the tokens each list must hold; None = every seed of a list holds the same tokens."""
    lists = tuple(name for name in (*V1_LISTS, *V2_LISTS) if name in submission)
    if lists not in (V1_LISTS, V2_LISTS):
        raise SubmissionError(
            f"prediction lists {list(lists)}: expected 'predictions' (v1.1) or 'first_stage_predictions' and "
            "'second_stage_predictions' (v2)"
        )
    keys = set(submission)
    wanted = set(METADATA_KEYS) | set(lists)
    if keys != wanted:
        raise SubmissionError(f"keys {sorted(keys - wanted)} unexpected, {sorted(wanted - keys)} missing")
    for key, field in METADATA_KEYS.items():
        require_text(submission[key], key, OPTIONS[field])
    for name in lists:
        seeds = submission[name]
        if not isinstance(seeds, list) or not seeds:
            raise SubmissionError(f"{name!r} must be a non-empty list with one {{token: Trajectory}} dict per seed")
        if name in V2_LISTS and len(seeds) != 1:
            raise SubmissionError(f"{name!r} holds {len(seeds)} seeds; {V2_ONE_SEED}")
        tokens = expected[name] if expected is not None else list(seeds[0])
        for seed, trajectories in enumerate(seeds):
            require_coverage("token", tokens, trajectories, f"{name}[{seed}]", exact=True)
            for token, array in trajectories.items():
                _check_poses(array, f"{name}[{seed}][{token!r}]")


def _check_poses(array: Any, where: str) -> None:
    if not isinstance(array, np.ndarray) or array.dtype != np.float32 or array.shape != (NUM_POSES, 3):
        kind = f"{array.dtype} {array.shape}" if isinstance(array, np.ndarray) else type(array).__name__
        raise SubmissionError(f"{where}: poses must be float32 ({NUM_POSES}, 3) at {INTERVAL} s, got {kind}")
    if not np.isfinite(array).all():
        raise SubmissionError(f"{where}: poses hold NaN or inf")


def encode(submission: dict[str, Any]) -> bytes:
    """The pickle bytes: each poses array wrapped in NAVSIM's ``Trajectory`` with one shared sampling object (as
    the dataclass's default ``TrajectorySampling`` is one object shared by every Trajectory)."""
    sampling = ForeignObject(TRAJECTORY_SAMPLING, (), dict(SAMPLING))

    def trajectory(array: np.ndarray) -> ForeignObject:
        return ForeignObject(TRAJECTORY, (), {"poses": numpy1_array(array), "trajectory_sampling": sampling})

    out = {key: value for key, value in submission.items() if key in METADATA_KEYS}
    for name in (*V1_LISTS, *V2_LISTS):
        if name in submission:
            out[name] = [{token: trajectory(a) for token, a in seed.items()} for seed in submission[name]]
    return dumps(out)


def write_navsim(
    out: Path, metadata: NavsimMetadata, predictions: Sequence[Path], data: Sequence[Path], two_stage: bool = False
) -> dict[str, Any]:
    """Validate, then write ``out``; returns what :func:`check_navsim` reports of the written file."""
    if not predictions:
        raise SubmissionError("no --predictions given; pass one predictions.parquet per seed")
    if two_stage and len(predictions) != 1:
        raise SubmissionError(f"--two-stage with {len(predictions)} --predictions files; {V2_ONE_SEED}")
    split = read_split(data, two_stage)
    submission: dict[str, Any] = {**metadata.as_keys(), **seed_lists(split, predictions)}
    validate(submission, split.tokens)
    write_bytes(Path(out), encode(submission))
    report = check_navsim(Path(out))
    if Path(out).name != UPLOAD_NAME:
        report["note"] = f"rename the file to {UPLOAD_NAME}: the leaderboard reads that name from your HF repo"
    return report


def load_navsim(path: Path) -> dict[str, Any]:
    """A written submission as plain data (``{token: poses}`` lists), read with the restricted unpickler (no NAVSIM
    needed); an error if a Trajectory's sampling is not 8 poses at 0.5 s."""
    records = {(TRAJECTORY.module, TRAJECTORY.name), (TRAJECTORY_SAMPLING.module, TRAJECTORY_SAMPLING.name)}
    try:
        raw = restricted_pickle.load(io.BytesIO(Path(path).read_bytes()), records)
    except (OSError, *restricted_pickle.DAMAGED) as err:  # any unreadable pickle is a bad submission; name it
        raise SubmissionError(f"{path}: not a readable NAVSIM submission pickle ({err})") from None
    if not isinstance(raw, dict):
        raise SubmissionError(f"{path}: holds a {type(raw).__name__}, not a dict")
    plain = dict(raw)
    for name in (*V1_LISTS, *V2_LISTS):
        if isinstance(raw.get(name), list):
            plain[name] = [
                {
                    token: _trajectory_poses(trajectory, f"{path}: {name}[{seed}][{token!r}]")
                    for token, trajectory in d.items()
                }
                for seed, d in enumerate(raw[name])
            ]
    return plain


def _trajectory_poses(trajectory: Any, where: str) -> np.ndarray:
    if getattr(trajectory, "path", None) != TRAJECTORY.path:
        raise SubmissionError(f"{where}: is a {type(trajectory).__name__}, not {TRAJECTORY.path}")
    sampling = trajectory.state.get("trajectory_sampling")
    if getattr(sampling, "path", None) != TRAJECTORY_SAMPLING.path:
        raise SubmissionError(f"{where}: trajectory_sampling is not {TRAJECTORY_SAMPLING.path}")
    values = sampling.state
    if values.get("num_poses") != NUM_POSES or not all(
        math.isclose(float(values.get(k) or 0), SAMPLING[k]) for k in ("time_horizon", "interval_length")
    ):
        raise SubmissionError(f"{where}: sampling {values}; the leaderboard scores {SAMPLING}")
    return trajectory.state.get("poses")


def check_navsim(path: Path) -> dict[str, Any]:
    """Re-read a written submission, validate it, and report what it holds."""
    submission = load_navsim(path)
    try:
        validate(submission)
    except SubmissionError as err:
        raise SubmissionError(f"{path}: {err}") from None
    lists = {name: seeds for name, seeds in submission.items() if name in (*V1_LISTS, *V2_LISTS)}
    return {
        "file": str(path),
        "format": "navsim-v1.1" if "predictions" in lists else "navsim-v2 two-stage",
        "metadata": {key: submission[key] for key in METADATA_KEYS},
        "lists": {name: {"seeds": len(seeds), "tokens": len(seeds[0])} for name, seeds in lists.items()},
        "poses": {"shape": [NUM_POSES, 3], "dtype": "float32", "interval_s": INTERVAL},
        "classes": [TRAJECTORY.path, TRAJECTORY_SAMPLING.path],
    }
