"""Summarise a converted folder: counts, a schema check of some samples, field statistics, an optional picture."""

import itertools
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import pyarrow as pa
import pyarrow.compute as pc

from lead_s2r.errors import UserError
from lead_s2r.report.render import render_sample
from lead_s2r.schema import SchemaError, validate
from lead_s2r.shards import MANIFEST, SHARD_DIR, load_info, load_manifest, read_samples


def _range(values: np.ndarray) -> dict[str, float] | None:
    values = values[np.isfinite(values)]
    if not len(values):
        return None
    return {"min": float(values.min()), "max": float(values.max()), "mean": float(values.mean())}


def inspect_dataset(path: str | Path, n: int = 32, png: str | Path | None = None, key: str | None = None) -> dict:
    """Counts per dataset/split, validation of the first ``n`` samples, statistics; draws one sample to ``png``:
    ``key``, or by default the one of those ``n`` whose future turns most (:func:`most_turning`)."""
    path = Path(path)
    manifest = _manifest(path)
    info = load_info(path)
    counts: dict[str, int] = {}
    for dataset, split in zip(manifest["dataset"].to_pylist(), manifest["split"].to_pylist(), strict=True):
        counts[f"{dataset}/{split}"] = counts.get(f"{dataset}/{split}", 0) + 1
    has = {name[4:]: int(pc.sum(manifest[name]).as_py() or 0) for name in manifest.column_names if name[:4] == "has_"}
    stats: dict[str, Any] = {}
    for column in ("speed", "tp_x", "tp_y"):
        stats[column] = _range(manifest[column].to_numpy(zero_copy_only=False).astype(np.float64))
    commands = manifest["command"].to_pylist()
    stats["command"] = {str(c): commands.count(c) for c in sorted(set(commands))}
    invalid: list[str] = []
    lengths: dict[str, list[float]] = {"past_s": [], "future_s": []}
    samples = list(itertools.islice(read_samples(path), max(n, 1)))
    for sample in samples:
        try:
            validate(sample)
        except SchemaError as err:
            invalid.append(str(err))
        lengths["past_s"].append(-float(sample["past"][0, 0]))
        if "future" in sample:
            lengths["future_s"].append(float(sample["future"][-1, 0]))
    stats.update({name: _range(np.array(v)) for name, v in lengths.items()})
    report = {
        "path": str(path),
        "adapter": f"{info.get('adapter')} {info.get('adapter_version')}",
        "samples": len(manifest),
        "logs": len(set(manifest["log"].to_pylist())),
        "by_dataset_split": counts,
        "fields_present": has,
        "statistics": stats,
        "checked": len(samples),
        "invalid": invalid,
        "failed_logs": info.get("failed_logs", 0),
    }
    if png is not None:
        drawn = most_turning(samples) if key is None else find_sample(path, manifest, key)
        cv2.imwrite(str(png), render_sample(drawn))
        report["png"] = str(png)
        report["png_key"] = drawn["__key__"]
    return report


def heading_change(sample: dict[str, Any]) -> float:
    """How far the logged future turns (rad, absolute): its last yaw, or the bearing of its last point where the
    source has no yaw; 0 without a future."""
    future = sample.get("future")
    if future is None or not len(future):
        return 0.0
    x, y, yaw = (float(v) for v in future[-1, 1:])
    return abs(yaw) if np.isfinite(yaw) else abs(float(np.arctan2(y, x)))


def most_turning(samples: list[dict[str, Any]]) -> dict[str, Any]:
    """The sample whose future turns most: a turn shows at a glance whether y is left (a straight frame does not)."""
    return max(samples, key=heading_change)


def list_keys(path: str | Path) -> list[str]:
    """One line per sample: key, dataset/split, log, frame, speed (from the manifest; no shard is read)."""
    manifest = _manifest(Path(path)).to_pydict()
    columns = ("key", "dataset", "split", "log", "frame", "speed")
    rows = zip(*(manifest[c] for c in columns), strict=True)
    return [f"{key}  {data}/{split}  {log}  {frame}  {speed:.2f} m/s" for key, data, split, log, frame, speed in rows]


def _manifest(path: Path) -> pa.Table:
    """The manifest of a converted folder; a missing, unconverted or empty folder is a :class:`UserError`."""
    if not path.is_dir():
        raise UserError(f"{path} is not a folder; give a folder written by lead-s2r convert")
    if not (path / MANIFEST).is_file():
        raise UserError(f"{path} holds no {MANIFEST}: not a converted folder (or its conversion did not finish)")
    manifest = load_manifest(path)
    if not len(manifest):
        raise UserError(f"{path}: {MANIFEST} lists no sample; convert again and check its errors.jsonl")
    return manifest


def find_sample(path: Path, manifest: pa.Table, key: str) -> dict[str, Any]:
    """One sample by key, reading only the shard the manifest puts it in."""
    rows = manifest.filter(pc.equal(manifest["key"], key))
    if not len(rows):
        raise UserError(f"--key {key!r}: no sample with that key in {path} (see its manifest.parquet)")
    shard = path / SHARD_DIR / rows["shard"][0].as_py()
    return next(sample for sample in read_samples(shard) if sample["__key__"] == key)
