"""Summarise a converted folder: counts, a schema check of every sample (or the first few), statistics, a picture.

Every sample is read and validated by default: reading them all is also what holds each tar against the manifest
(:class:`~lead_s2r.shards.ManifestCheck`), so a folder that lost a tar or a sample cannot pass as whole.
"""

import itertools
from collections import Counter
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import cv2
import numpy as np
import pyarrow as pa
import pyarrow.compute as pc
from matplotlib.figure import Figure

from lead_s2r.errors import UserError
from lead_s2r.report.bev import draw_bev, save_figure
from lead_s2r.report.camera import decode
from lead_s2r.schema import SchemaError, validate
from lead_s2r.shards import MANIFEST, SHARD_DIR, load_info, load_manifest, read_samples, value_range

#: the picture's width and the height of its BEV [inches, at 100 dpi]
PICTURE_INCHES, BEV_INCHES = 9.6, 6.4
#: Manifest columns the report reads.
_READ = ("key", "shard", "dataset", "split", "log", "speed", "command", "tp_x", "tp_y")


def inspect_dataset(
    path: str | Path,
    quick: int | None = None,
    png: str | Path | None = None,
    key: str | None = None,
    progress: bool = False,
) -> dict:
    """Counts per dataset/split, validation of every sample (the first ``quick`` with ``quick``), statistics; draws
    one sample to ``png``: ``key``, or by default the checked sample whose future turns most (:func:`heading_change`).
    ``progress`` shows a bar on stderr."""
    path = Path(path)
    if png is not None:
        _check_png(Path(png))
    manifest = _manifest(path)
    info = load_info(path)
    pairs = zip(manifest["dataset"].to_pylist(), manifest["split"].to_pylist(), strict=True)
    counts = dict(Counter(f"{dataset}/{split}" for dataset, split in pairs))
    has = {name[4:]: int(pc.sum(manifest[name]).as_py() or 0) for name in manifest.column_names if name[:4] == "has_"}
    stats: dict[str, Any] = {}
    for column in ("speed", "tp_x", "tp_y"):
        stats[column] = value_range(manifest[column].to_numpy(zero_copy_only=False).astype(np.float64))
    commands = manifest["command"].to_pylist()
    stats["command"] = {str(c): commands.count(c) for c in sorted(set(commands))}
    invalid: list[str] = []
    lengths: dict[str, list[float]] = {"past_s": [], "future_s": []}
    samples = read_samples(path)  # read to the end unless quick: the end is where the last tar's count is checked
    total = len(manifest) if quick is None else min(max(quick, 1), len(manifest))
    checked, turning, turn = 0, None, -1.0
    for sample in _with_bar(samples if quick is None else itertools.islice(samples, total), total, progress):
        checked += 1
        if heading_change(sample) > turn:  # the picture's default: a turn shows whether y is left at a glance
            turning, turn = sample, heading_change(sample)
        try:
            validate(sample)
        except SchemaError as err:
            invalid.append(str(err))
            continue
        lengths["past_s"].append(-float(sample["past"][0, 0]))
        if "future" in sample:
            lengths["future_s"].append(float(sample["future"][-1, 0]))
    stats.update({name: value_range(np.array(v)) for name, v in lengths.items()})
    report = {
        "path": str(path),
        "adapter": f"{info.get('adapter')} {info.get('adapter_version')}",
        "samples": len(manifest),
        "logs": len(set(manifest["log"].to_pylist())),
        "by_dataset_split": counts,
        "fields_present": has,
        "statistics": stats,
        "checked": checked,
        "invalid": invalid,
        "failed_logs": info.get("failed_logs", 0),
    }
    if png is not None:
        drawn = turning if key is None else find_sample(path, manifest, key)
        try:
            save_figure(sample_figure(drawn), png)
        except OSError:
            raise UserError(f"--png {png}: cannot be written there; choose a writable folder") from None
        report["png"] = str(png)
        report["png_key"] = drawn["__key__"]
    return report


def heading_change(sample: dict[str, Any]) -> float:
    """How far the logged future turns (absolute, rad): its last yaw, else its last point's bearing; 0 without one."""
    future = sample.get("future")
    if future is None or not len(future):
        return 0.0
    x, y, yaw = (float(v) for v in future[-1, 1:])
    return abs(yaw) if np.isfinite(yaw) else abs(float(np.arctan2(y, x)))


def sample_figure(sample: dict[str, Any]) -> Figure:
    """The picture a person checks a sample by: its cameras side by side above the BEV (the report's, with the
    model's inputs drawn; past and logged future on top), the key and ego state as the title."""
    images = [decode(sample, name) for name in sorted(sample) if name.startswith("cam_")]
    images = [image for image in images if image is not None]
    height = min((image.shape[0] for image in images), default=0)
    strip = [cv2.resize(image, (image.shape[1] * height // image.shape[0], height)) for image in images]
    strip_inches = PICTURE_INCHES * height / sum(image.shape[1] for image in strip) if strip else 0.0
    figure = Figure(figsize=(PICTURE_INCHES, strip_inches + BEV_INCHES), dpi=100, layout="constrained")
    if strip:
        cameras, bev = figure.subplots(2, 1, height_ratios=(strip_inches, BEV_INCHES))
        cameras.imshow(np.hstack(strip))
        cameras.set_axis_off()
    else:
        bev = figure.add_subplot()
    trajectories = {"past": sample["past"][:, 1:3]} | (
        {"logged": sample["future"][:, 1:3]} if "future" in sample else {}
    )
    draw_bev(bev, sample, trajectories, inputs=True)
    ego = sample["meta"]["ego"]
    figure.suptitle(f"{sample['__key__']}\nspeed {ego['speed']:.2f} m/s, command {ego['command']} (raw "
                    f"{ego['command_raw']})", fontsize=9)  # fmt: skip
    return figure


def list_keys(path: str | Path) -> list[str]:
    """One line per sample: key, dataset/split, log, frame, speed (from the manifest; no shard is read)."""
    manifest = _manifest(Path(path)).to_pydict()
    columns = ("key", "dataset", "split", "log", "frame", "speed")
    rows = zip(*(manifest[c] for c in columns), strict=True)
    return [f"{key}  {data}/{split}  {log}  {frame}  {speed:.2f} m/s" for key, data, split, log, frame, speed in rows]


def _check_png(png: Path) -> None:
    """Refuse a picture path that cannot be written before reading anything."""
    if png.suffix.lower() != ".png":
        raise UserError(f"--png {png}: the picture is a PNG; give a file name ending in .png")
    if not png.parent.is_dir():
        raise UserError(f"--png {png}: folder {png.parent} does not exist; create it or choose another path")


def _with_bar(samples: Iterator[dict[str, Any]], total: int, progress: bool) -> Iterator[dict[str, Any]]:
    """``samples`` passed through, advancing a rich progress bar on stderr when ``progress`` and stderr is a terminal
    (in a log or a pipe the bar's last frame would be a second line beside an error's one)."""
    from rich.console import Console
    from rich.progress import Progress

    console = Console(stderr=True)
    with Progress(console=console, disable=not (progress and console.is_terminal)) as bar:
        yield from bar.track(samples, total=total, description="checking samples")


def _manifest(path: Path) -> pa.Table:
    """The manifest of a converted folder; a missing, unconverted or empty folder is a :class:`UserError`."""
    if not path.is_dir():
        raise UserError(f"{path} is not a folder; give a folder written by lead-s2r convert")
    manifest = load_manifest(path, required=_READ)
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
