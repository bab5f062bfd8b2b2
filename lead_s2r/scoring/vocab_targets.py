"""Vocabulary targets on converted NAVSIM data: the bodies of ``lead-s2r vocab score`` and ``lead-s2r vocab build``.

``score_data`` scores every entry of a vocabulary in every scene (:func:`~lead_s2r.scoring.pdm.score_vocabulary`,
PDM-Closed planned per scene as ``score`` plans it) and writes, in ``out``:

- ``vocab_scores.pkl``: GTRS's targets, ``{token: {metric: float16[V]}}`` with GTRS's metric names
  (:data:`GTRS_NAMES`; ``pdm_score`` is the final score), keyed by NAVSIM's scene token, in data order, so GTRS's
  training code loads it as it is;
- ``vocab_scores.parquet``: one row per scene (``key``, ``token``), one list column per metric (float32 holding the
  float16 values, so both files carry the same numbers);
- ``vocab_manifest.json``: what was scored with what (vocabulary file and SHA-256, shape, interval, metric, EP
  normalisation, human filter, data folders, split, package version), the scenes scored and those that failed (no route
  PDM-Closed can follow), with their error.

Deterministic and resumable like ``convert``: scenes are scored in jobs of :data:`SCENES_PER_JOB` consecutive
samples of a shard, on any executor, each job reading its own samples (the driver decodes none); each finished job
is written to ``parts/<job>.npz`` (renamed into place whole) and the files are assembled from the parts in data
order, so any number of workers, Ray or a rerun after a kill write the same bytes. A rerun with the same inputs
scores only the jobs without a part; a folder holding another run's manifest (another vocabulary, metric, EP mode,
human filter, data or split) is refused, as is a ``vocab_scores.pkl`` without our manifest.

``build_vocabulary`` clusters the logged futures of converted samples (resampled to GTRS's 40 poses at 0.1 s) with
scipy's k-means (``kmeans2``, k-means++ start, seeded): the same data, size and seed give the same array.
"""

import hashlib
import io
import json
import zipfile
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa

from lead_s2r import __version__
from lead_s2r.errors import UserError, listing
from lead_s2r.files import write_bytes, write_parquet
from lead_s2r.geometry import resample
from lead_s2r.gtrs_targets import EPDMS_NAMES, PDMS_NAMES, targets_bytes
from lead_s2r.processes import Executor, InlineExecutor
from lead_s2r.schema import navsim_scene_token
from lead_s2r.scoring.pdm.pdm_closed import plan_reference
from lead_s2r.scoring.pdm.route import RouteError
from lead_s2r.scoring.pdm.sample import NEEDS_MAPS, scene_from_sample
from lead_s2r.scoring.pdm.score import EPDMS_METRIC, METRIC, METRICS
from lead_s2r.scoring.pdm.vocabulary import GTRS_INTERVAL_S, GTRS_POSES, PROGRESS_MODES, check_vocabulary
from lead_s2r.scoring.pdm.vocabulary import score_vocabulary as score_entries
from lead_s2r.scoring.run import choose_samples, sample_listing
from lead_s2r.shards import load_manifest, read_part, shard_parts

PICKLE = "vocab_scores.pkl"
PARQUET = "vocab_scores.parquet"
MANIFEST = "vocab_manifest.json"
PARTS = "parts"
#: the member of a part holding its scenes' tokens and failures
PART_LISTING = "listing.json"
#: scenes per job: one scene of 8,192 entries takes about a second, a job's messages (the vocabulary) a few ms
SCENES_PER_JOB = 4
#: the sample fields a scene is built from
FIELDS = ("scoring", "boxes", "agents_future", "future")
#: our column -> GTRS's metric name, per metric (SimScale's ``pdm_score_full_v2`` keys; ``pdm_score`` = final score)
GTRS_NAMES = {
    METRIC: {name: name for name in PDMS_NAMES[:-1]} | {"score": "pdm_score"},
    EPDMS_METRIC: {name: name for name in EPDMS_NAMES[:-1]} | {"score": "pdm_score"},
}


def load_vocabulary(path: Path) -> np.ndarray:
    """The ``(V, K, 3)`` vocabulary in ``path`` (a .npy file), or a UserError naming the file and what is wrong."""
    if not path.is_file():
        raise UserError(f"--vocab {path}: no such file; give a (V, 40, 3) .npy (lead-s2r vocab build makes one)")
    try:
        array = np.load(path, allow_pickle=False)
    except (ValueError, OSError, EOFError) as err:
        raise UserError(f"--vocab {path}: not a .npy array ({err})") from None
    try:
        return check_vocabulary(array, f"--vocab {path}")
    except ValueError as err:
        raise UserError(str(err)) from None


def _write_manifest(out: Path, manifest: dict[str, Any]) -> None:
    """Written twice per run, ``complete: false`` first, so a killed run's folder says it is unfinished."""
    write_bytes(out / MANIFEST, (json.dumps(manifest, indent=2) + "\n").encode())


def score_scenes(
    source: list[dict[str, Any]] | tuple[str, list[str], int],
    vocabulary: np.ndarray,
    interval: float,
    metric: str,
    progress: str,
    human_filter: bool = True,
) -> dict[str, Any]:
    """One job, on samples given decoded (a folder without a manifest) or as ``(shard, keys, offset)``: every scene's
    GTRS columns as float16 ``(V,)`` arrays by sample key, the scenes' NAVSIM tokens and the scenes that failed."""
    if isinstance(source, tuple):  # the job reads its own samples: the driver holds no scene, a worker only its own
        shard, keys, offset = source
        source = read_part(shard, keys, FIELDS, offset)
    scores, tokens, failed = {}, {}, {}
    for sample in source:
        key = sample["__key__"]
        tokens[key] = navsim_scene_token(sample)
        try:
            scene = scene_from_sample(sample)
        except RouteError as err:
            failed[key] = str(err)
            continue
        reference = plan_reference(scene)
        columns = score_entries(
            scene, vocabulary, interval, reference, metric, progress=progress, human_filter=human_filter
        )
        scores[key] = {gtrs: columns[ours].astype(np.float16) for ours, gtrs in GTRS_NAMES[metric].items()}
    return {"scores": scores, "tokens": tokens, "failed": failed}


def _part_bytes(result: dict[str, Any]) -> bytes:
    """A job's result as a .npz (arrays ``<key>/<metric>``) with tokens and failures as JSON: no pickle on disk."""
    arrays = {f"{key}/{name}": values for key, columns in result["scores"].items() for name, values in columns.items()}
    listed = {"tokens": result["tokens"], "failed": result["failed"]}
    arrays[PART_LISTING] = np.frombuffer(json.dumps(listed).encode(), np.uint8)
    buffer = io.BytesIO()
    np.savez(buffer, **arrays)
    return buffer.getvalue()


def _read_part(path: Path) -> dict[str, Any]:
    with np.load(path, allow_pickle=False) as npz:
        listing = json.loads(npz[PART_LISTING].tobytes())
        scores: dict[str, dict[str, np.ndarray]] = {}
        for name in npz.files:
            if name != PART_LISTING:
                key, metric = name.rsplit("/", 1)
                scores.setdefault(key, {})[metric] = npz[name]
    return {"scores": scores, **listing}


def _check_folder(out: Path, identity: dict[str, Any]) -> None:
    """``out`` is new, or holds parts of this same run (resume); anything else is another run's and is refused."""
    manifest = out / MANIFEST
    if manifest.is_file():
        try:
            held = json.loads(manifest.read_text()).get("identity")
        except (json.JSONDecodeError, AttributeError):
            held = None
        if held != identity:
            raise UserError(
                f"--out {out}: {MANIFEST} records another run (vocabulary, metric, progress, human filter, data or "
                "split differ); choose another --out or delete it"
            )
    elif (out / PICKLE).exists():
        raise UserError(f"--out {out}: {PICKLE} is not ours (no {MANIFEST} beside it); choose another --out")


def score_data(
    vocab_path: Path,
    data: list[Path],
    out: Path,
    metric: str = METRIC,
    interval: float = GTRS_INTERVAL_S,
    progress: str = "pair",
    human_filter: bool = True,
    split: str | None = None,
    executor: Executor | None = None,
    on_job: Callable[[int, int, int], None] | None = None,
) -> dict[str, Any]:
    """Score ``vocab_path``'s vocabulary on ``data``, write the files of the module docstring, return the manifest.
    ``on_job(scenes, entries, total_scenes)`` is called as each job ends (a progress bar)."""
    if metric not in METRICS:
        raise UserError(f"--metric {metric}: choose {' or '.join(METRICS)}")
    if progress not in PROGRESS_MODES:
        raise UserError(f"--progress {progress}: choose {' or '.join(PROGRESS_MODES)}")
    if not interval > 0:
        raise UserError(f"--interval {interval}: give the seconds between two poses of an entry (GTRS: 0.1)")
    vocabulary = load_vocabulary(vocab_path)
    for folder in data:
        if not folder.is_dir():
            raise UserError(f"--data {folder}: no such folder; give a converted NAVSIM folder")
    jobs = _jobs(data, split)
    executor = executor or InlineExecutor()
    identity = {  # what a rerun must match: all but the vocabulary's path (a copy elsewhere is the same vocabulary)
        "vocabulary_sha256": hashlib.sha256(vocab_path.read_bytes()).hexdigest(),
        "shape": list(vocabulary.shape),
        "interval": interval,
        "metric": metric,
        "progress": progress,
        "human_filter": human_filter,
        "data": [str(folder.resolve()) for folder in data],
        "split": split,
    }
    _check_folder(out, identity)
    manifest: dict[str, Any] = {"identity": identity, "vocabulary": str(vocab_path), "complete": False}
    manifest |= {"package_version": __version__, "gtrs_metrics": list(GTRS_NAMES[metric].values())}
    _write_manifest(out, manifest)
    parts = [out / PARTS / f"{index:06d}.npz" for index in range(len(jobs))]
    for partial in (out / PARTS).glob(".*.partial"):  # a killed run's unfinished writes
        partial.unlink()
    todo = [index for index, path in enumerate(parts) if not _readable(path)]
    sizes = [len(job[1]) if isinstance(job, tuple) else len(job) for job in jobs]  # a job read: (shard, keys, offset)
    for index in set(range(len(jobs))) - set(todo):
        if on_job is not None:
            on_job(sizes[index], sizes[index] * len(vocabulary), sum(sizes))
    arguments = [(jobs[index], vocabulary, interval, metric, progress, human_filter) for index in todo]
    with executor.session():
        for position, result in executor.run(score_scenes, arguments):
            write_bytes(parts[todo[position]], _part_bytes(result))
            if on_job is not None:
                on_job(sizes[todo[position]], sizes[todo[position]] * len(vocabulary), sum(sizes))
    return _assemble(out, parts, manifest)


def _jobs(data: list[Path], split: str | None) -> list[list[dict[str, Any]] | tuple[str, list[str], int]]:
    """The jobs of :func:`score_scenes` in data order: up to :data:`SCENES_PER_JOB` consecutive samples of one shard
    (read by the job), or decoded samples of a folder without a manifest. Data converted without maps (no
    ``scoring``) is a UserError here, before anything is written."""
    jobs: list[list[dict[str, Any]] | tuple[str, list[str], int]] = []
    for folder in data:
        entries = [entry for entry in sample_listing(folder, FIELDS) if split is None or entry["split"] == split]
        if entries and "sample" in entries[0]:
            without = [entry["key"] for entry in entries if "scoring" not in entry["sample"]]
            samples = [entry["sample"] for entry in entries]
            jobs += [samples[start : start + SCENES_PER_JOB] for start in range(0, len(samples), SCENES_PER_JOB)]
        else:
            table = load_manifest(folder)  # a dataset without the field has no has_scoring column
            flags = table["has_scoring"].to_pylist() if "has_scoring" in table.column_names else [False] * len(table)
            scoring = dict(zip(table["key"].to_pylist(), flags, strict=True))
            without = [entry["key"] for entry in entries if not scoring.get(entry["key"])]
            jobs += shard_parts(entries, SCENES_PER_JOB)
        if without:
            raise UserError(f"--data {folder}: no field 'scoring' in samples {listing(without)}; {NEEDS_MAPS}")
    if not jobs:
        raise UserError(f"--split {split}: {', '.join(map(str, data))} holds no sample of it")
    return jobs


def _readable(path: Path) -> bool:
    """A part written whole (a kill leaves only ``.partial`` files, but a damaged disk may leave worse)."""
    try:
        with zipfile.ZipFile(path) as archive:
            return archive.testzip() is None
    except (OSError, zipfile.BadZipFile):
        return False


def _assemble(out: Path, parts: list[Path], manifest: dict[str, Any]) -> dict[str, Any]:
    """The pickle, the Parquet table and the finished manifest, from the parts, in data order."""
    scores: dict[str, dict[str, np.ndarray]] = {}
    tokens: dict[str, str] = {}
    failed: dict[str, str] = {}
    for path in parts:
        part = _read_part(path)
        scores |= part["scores"]
        tokens |= part["tokens"]
        failed |= part["failed"]
    names = manifest["gtrs_metrics"]
    keys = [key for key in tokens if key in scores]
    targets = {tokens[key]: {name: scores[key][name] for name in names} for key in keys}
    write_bytes(out / PICKLE, targets_bytes(targets))
    columns = {"key": pa.array(keys, pa.string()), "token": pa.array([tokens[key] for key in keys], pa.string())}
    for name in names:
        columns[name] = pa.array([scores[key][name].astype(np.float32) for key in keys], pa.list_(pa.float32()))
    write_parquet(out / PARQUET, pa.table(columns))
    manifest = manifest | {"complete": True, "scenes": len(keys), "entries": int(manifest["identity"]["shape"][0])}
    manifest["failed"] = [{"key": key, "error": failed[key]} for key in tokens if key in failed]
    _write_manifest(out, manifest)
    return manifest


def logged_futures(samples: list[dict[str, Any]]) -> np.ndarray:
    """The logged futures reaching 4 s, resampled to GTRS's layout: ``(N, 40, 3)`` at 0.1 s (x, y, heading)."""
    grid = GTRS_INTERVAL_S * np.arange(1, GTRS_POSES + 1)
    out = []
    for sample in samples:
        future = np.asarray(sample.get("future", np.zeros((0, 4))), np.float64)
        if len(future) == 0 or np.isnan(future[:, 3]).any():
            continue
        knots = np.vstack([np.zeros(4), future])
        values, inside = resample(knots[:, 0], knots[:, 1:4], grid, angle_columns=(2,))
        if inside.all():
            out.append(values)
    return np.asarray(out, np.float64).reshape(-1, GTRS_POSES, 3)


def build_vocabulary(
    data: list[Path], size: int, out: Path, seed: int = 0, split: str | None = None, iterations: int = 25
) -> np.ndarray:
    """k-means centres of the logged futures of ``data`` as a float32 ``(size, 40, 3)`` .npy at ``out``."""
    from scipy.cluster.vq import kmeans2

    if size < 1:
        raise UserError(f"--size {size}: give at least 1 entry")
    for folder in data:
        if not folder.is_dir():
            raise UserError(f"--data {folder}: no such folder; give a converted folder")
    futures = logged_futures(choose_samples(data, ("future",), split)[0])
    if len(futures) < size:
        raise UserError(
            f"--data {', '.join(map(str, data))}: {len(futures)} logged futures reach 4 s, fewer than --size {size}; "
            "ask for fewer entries or give more data"
        )
    points = futures.reshape(len(futures), -1)
    centres, _ = kmeans2(points, size, iter=iterations, minit="++", seed=np.random.default_rng(seed))
    vocabulary = centres.reshape(size, GTRS_POSES, 3).astype(np.float32)
    buffer = io.BytesIO()
    np.save(buffer, vocabulary)
    write_bytes(out, buffer.getvalue())
    return vocabulary
