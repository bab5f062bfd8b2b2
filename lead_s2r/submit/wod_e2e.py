"""WOD-E2E leaderboard submission: ``E2EDChallengeSubmission`` shards and the tar.gz to upload, without TensorFlow.

What the server reads (Waymo's submission proto and tutorial; shared/research/closed_loop_and_submissions.md §3.2,
wod_e2e.md §1.4): each shard is one serialized ``E2EDChallengeSubmission`` (raw protobuf bytes, no TFRecord framing)
carrying every metadata field again and ``submission_type = E2ED_SUBMISSION``; frames are split evenly over the shards.
Shards must be named ``<stem>.binproto-00000-of-0000N``: the tutorial's ``part0`` naming gives "No shards found". Each
frame gets one trajectory of 20 (x, y) points at 0.25 ... 5 s (4 Hz) in the rear-axle frame at t0, and ``frame_name``
must equal the record's ``frame.context.name``; a frame left out gives "Missing N sequence names". Required metadata:
``account_name`` (the email registered at waymo.com/open), ``unique_method_name``, ``num_model_parameters`` (an integer
and a suffix, e.g. "60M") and ``uses_public_model_pretraining`` (set even when false). Trajectories are resampled with
:func:`lead_s2r.predictions.on_grid`, as the RFS scorer reads them, taking a model's highest-probability inference.
"""

import io
import re
import tarfile
from collections.abc import Sequence
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from google.protobuf.message import DecodeError

from lead_s2r.files import staged_folder, write_bytes
from lead_s2r.predictions import PredictionError, on_grid, regular_grid
from lead_s2r.submit.common import (
    SubmissionError,
    best_inferences,
    listing,
    require_coverage,
    require_text,
    split_metas,
)
from lead_s2r.submit.wod_e2e_proto import E2ED_SUBMISSION, E2EDChallengeSubmission

FREQUENCY = 4
LENGTH_SECONDS = 5
NUM_POINTS = FREQUENCY * LENGTH_SECONDS
SHARD_STEM = "submission"
SHARD_PATTERN = re.compile(r"^(?P<stem>[^/]+)\.binproto-(?P<index>\d{5})-of-(?P<count>\d{5})$")
PARAMETERS_PATTERN = re.compile(r"^[1-9][0-9]*[KMBTPE]$")
#: Metadata fields copied into every shard (the predictions differ per shard).
METADATA_FIELDS = (
    "submission_type", "account_name", "unique_method_name", "authors", "affiliation", "description",
    "method_link", "uses_public_model_pretraining", "num_model_parameters", "public_model_names",
)  # fmt: skip


@dataclass(frozen=True)
class WodMetadata:
    """Who submits and what the model is; checked on construction (the CLI option of each field is named)."""

    account_name: str
    unique_method_name: str
    authors: Sequence[str]
    num_model_parameters: str
    uses_public_model_pretraining: bool | None
    affiliation: str = ""
    description: str = ""
    method_link: str = ""
    public_model_names: Sequence[str] = field(default_factory=tuple)

    def __post_init__(self) -> None:
        check_metadata(self.__dict__)

    def message(self) -> Any:
        """A new ``E2EDChallengeSubmission`` holding every metadata field (an empty optional text left unset)."""
        fields = {name: value for name, value in asdict(self).items() if value != ""}
        return E2EDChallengeSubmission(submission_type=E2ED_SUBMISSION, **fields)


def check_metadata(values: dict[str, Any]) -> None:
    """Raise naming the field (and its CLI option) if a required metadata field is missing or malformed."""
    account = require_text(values.get("account_name"), "account_name", "--account")
    if "@" not in account:
        raise SubmissionError(
            f"metadata field 'account_name' is {account!r}; use the email registered at waymo.com/open"
        )
    require_text(values.get("unique_method_name"), "unique_method_name", "--method")
    if not [a for a in values.get("authors") or () if str(a).strip()]:
        raise SubmissionError("metadata field 'authors' is empty; give at least one --authors")
    parameters = require_text(values.get("num_model_parameters"), "num_model_parameters", "--num-params")
    if not PARAMETERS_PATTERN.match(parameters):
        raise SubmissionError(
            f"metadata field 'num_model_parameters' is {parameters!r}; write an integer and a suffix K/M/B/T (e.g. 60M)"
        )
    pretraining = values.get("uses_public_model_pretraining")
    if not isinstance(pretraining, bool):
        raise SubmissionError("metadata field 'uses_public_model_pretraining' is required; set --pretrained true|false")
    if pretraining and not list(values.get("public_model_names") or ()):
        raise SubmissionError(
            "uses_public_model_pretraining is true but 'public_model_names' is empty; name the models"
        )


def frame_names(data: Sequence[Path], split: str) -> dict[str, str]:
    """Sample key -> ``frame.context.name`` of every converted sample of ``split``."""
    metas = {key: meta for key, meta in split_metas(data, "wod_e2e").items() if meta["split"] == split}
    if not metas:
        raise SubmissionError(f"{', '.join(map(str, data))}: no {split!r} samples; convert the {split} shards")
    return {key: meta["extras"]["wod_e2e"]["frame_name"] for key, meta in metas.items()}


def trajectories(predictions: Path, frames: dict[str, str]) -> dict[str, np.ndarray]:
    """Frame name -> (20, 2) float32 xy at 0.25 ... 5 s, one per frame; every frame must have a prediction."""
    best = best_inferences(predictions)
    require_coverage("frame", frames.values(), [name for key, name in frames.items() if key in best], str(predictions))
    keys = sorted(frames)
    try:
        xy, _ = on_grid([[best[key]] for key in keys], regular_grid(FREQUENCY, LENGTH_SECONDS))
    except PredictionError as err:  # a horizon short of 5 s: name the file too
        raise SubmissionError(f"{predictions}: {err}") from None
    return {frames[key]: xy[i, 0].astype(np.float32) for i, key in enumerate(keys)}


def build_shards(metadata: WodMetadata, trajectories: dict[str, np.ndarray], count: int) -> list[Any]:
    """``count`` shards, each a full ``E2EDChallengeSubmission`` with ceil(frames / count) frames (tutorial split)."""
    if count < 1 or count > len(trajectories):
        raise SubmissionError(f"--shards {count}: must be between 1 and the number of frames ({len(trajectories)})")
    names = sorted(trajectories)
    per_shard = -(-len(names) // count)
    shards = []
    for index in range(count):
        shard = metadata.message()
        for name in names[index * per_shard : (index + 1) * per_shard]:
            x, y = trajectories[name].T.tolist()
            shard.predictions.add(frame_name=name, trajectory={"pos_x": x, "pos_y": y})
        shards.append(shard)
    return shards


def shard_names(count: int, stem: str = SHARD_STEM) -> list[str]:
    return [f"{stem}.binproto-{index:05d}-of-{count:05d}" for index in range(count)]


def validate(shards: dict[str, Any], expected: Sequence[str] | None = None) -> int:
    """Raise naming the shard, frame or field if the shards are not what the server reads; returns the frame count.
    ``shards``: file name -> parsed message. ``expected``: the frame names to cover exactly (None: no check)."""
    check_shard_names(list(shards))
    reference = None
    seen: dict[str, str] = {}
    for name, shard in shards.items():
        if shard.submission_type != E2ED_SUBMISSION:
            raise SubmissionError(f"{name}: submission_type is {shard.submission_type}, not E2ED_SUBMISSION (1)")
        metadata = {f: _value(shard, f) for f in METADATA_FIELDS}
        try:
            check_metadata(metadata)
        except SubmissionError as err:
            raise SubmissionError(f"{name}: {err}") from None
        if reference is not None and metadata != reference:
            raise SubmissionError(f"{name}: metadata differs from the first shard's; every shard repeats it")
        reference = metadata
        for entry in shard.predictions:
            _check_frame(name, entry, seen)
            seen[entry.frame_name] = name
    if expected is not None:
        require_coverage("frame", expected, seen, "submission", exact=True)
    return len(seen)


def _value(shard: Any, name: str) -> Any:
    value = getattr(shard, name)
    if name in ("authors", "public_model_names"):
        return list(value)
    return value if name == "submission_type" or shard.HasField(name) else None


def _check_frame(shard: str, entry: Any, seen: dict[str, str]) -> None:
    frame = entry.frame_name
    if not frame:
        raise SubmissionError(f"{shard}: a prediction has no frame_name")
    if frame in seen:
        raise SubmissionError(f"{shard}: frame {frame!r} appears twice (also in {seen[frame]})")
    x, y = np.asarray(entry.trajectory.pos_x), np.asarray(entry.trajectory.pos_y)
    if len(x) != NUM_POINTS or len(y) != NUM_POINTS:
        raise SubmissionError(f"{shard}: frame {frame!r} has {len(x)} x / {len(y)} y points, not {NUM_POINTS} at 4 Hz")
    if not (np.isfinite(x).all() and np.isfinite(y).all()):
        raise SubmissionError(f"{shard}: frame {frame!r}: trajectory holds NaN or inf")


def check_shard_names(names: list[str]) -> None:
    """Names must be ``<stem>.binproto-<i>-of-<n>`` for i = 0 ... n-1 of one stem and one n."""
    if not names:
        raise SubmissionError("no shards found (files named <stem>.binproto-00000-of-0000N)")
    matches = [SHARD_PATTERN.match(Path(name).name) for name in names]
    bad = [name for name, match in zip(names, matches, strict=True) if match is None]
    if bad:
        raise SubmissionError(
            f"shard names {listing(bad)} are not <stem>.binproto-00000-of-0000N; the server skips them"
        )
    stems = {m["stem"] for m in matches}
    count = int(matches[0]["count"])
    if len(stems) != 1 or sorted(int(m["index"]) for m in matches) != list(range(count)) or len(names) != count:
        raise SubmissionError(
            f"shards {listing(names)} are not one complete set 00000 ... {count - 1:05d} of {count:05d}"
        )


def write_wod(
    out: Path, metadata: WodMetadata, predictions: Path, data: Sequence[Path], split: str = "test", shards: int = 1
) -> dict[str, Any]:
    """Validate, then write the shards into ``out`` and ``out.tar.gz`` (what to upload); returns the check report."""
    out = Path(out)
    if out.exists() and any(out.iterdir()):
        raise SubmissionError(
            f"{out}: already holds files; remove it or pick another --out (stale shards would be uploaded)"
        )
    frames = frame_names(data, split)
    messages = dict(
        zip(shard_names(shards), build_shards(metadata, trajectories(predictions, frames), shards), strict=True)
    )
    validate(messages, list(frames.values()))
    payloads = {name: message.SerializeToString() for name, message in messages.items()}
    with staged_folder(out) as staging:
        for name, payload in payloads.items():
            (staging / name).write_bytes(payload)
        write_bytes(tar_path(out), tar_gz(out.name, payloads))
    return check_wod(tar_path(out))


def tar_path(out: Path) -> Path:
    return out.with_name(out.name + ".tar.gz")


def tar_gz(folder: str, payloads: dict[str, bytes]) -> bytes:
    """``tar cvf <folder>.tar <folder>; gzip`` as the tutorial does: the folder entry, then its shards."""
    buffer = io.BytesIO()
    with tarfile.open(fileobj=buffer, mode="w:gz") as tar:
        entry = tarfile.TarInfo(folder)
        entry.type, entry.mode = tarfile.DIRTYPE, 0o755
        tar.addfile(entry)
        for name, payload in payloads.items():
            info = tarfile.TarInfo(f"{folder}/{name}")
            info.size, info.mode = len(payload), 0o644
            tar.addfile(info, io.BytesIO(payload))
    return buffer.getvalue()


def read_shards(path: Path) -> dict[str, bytes]:
    """Shard bytes by file name from a tar.gz, a folder of shards or one shard; any other file is an error."""
    path = Path(path)
    if path.is_dir():
        return {p.name: p.read_bytes() for p in sorted(path.iterdir())}
    if path.name.endswith((".tar.gz", ".tgz", ".tar")):
        with tarfile.open(path) as tar:
            members = [m for m in tar.getmembers() if not m.isdir()]
            odd = [m.name for m in members if not m.isfile()]
            if odd:
                raise SubmissionError(f"{path}: holds {listing(odd)}, which are not plain files")
            return {Path(m.name).name: tar.extractfile(m).read() for m in members}
    return {path.name: path.read_bytes()}


def check_wod(path: Path) -> dict[str, Any]:
    """Re-read a written submission (tar.gz, folder or shard), validate it, and report what it holds."""
    messages = {}
    for name, payload in read_shards(path).items():
        try:
            messages[name] = E2EDChallengeSubmission.FromString(payload)
        except DecodeError as err:
            raise SubmissionError(f"{path}: {name} is not an E2EDChallengeSubmission ({err})") from None
    try:
        frames = validate(messages)
    except SubmissionError as err:
        raise SubmissionError(f"{path}: {err}") from None
    first = next(iter(messages.values()))
    return {
        "file": str(path),
        "format": "wod-e2e",
        "shards": {name: len(message.predictions) for name, message in messages.items()},
        "frames": frames,
        "points": [NUM_POINTS, 2],
        "metadata": {f: _value(first, f) for f in METADATA_FIELDS if f != "submission_type"},
    }
