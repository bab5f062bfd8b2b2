"""One converted log (and a run's predictions on it) as a Rerun recording: a scene scrubbed in time, in 3D.

Each sample of the log is one step of the ``frame`` timeline (the sample's ``frame_idx``) and of the ``time``
timeline (its ``timestamp_us``). Every entity is in the ego frame of the step shown (ISO 8855, origin at the rear
axle on the ground), so the view follows the car:

========================  ======================================================================================
``/ego``                  the ego vehicle's box
``/cameras/<id>``         each camera: its pose (``cam_to_ego``), pinhole (``K``) and the JPEG as stored
``/lidar``                the LiDAR points (x, y, z)
``/boxes``                3D boxes with class (``BoxClass``) and track id (the source's track token) as labels
``/map/lanes``            lane centrelines of the PDMS context (``scoring``); ``/map/areas``: polygon outlines
``/plan/logged``          the logged future
``/plan/predicted``       the run's most probable plan for the sample (with a run)
``/scores/<metric>/<c>``  the headline and each sub-score ``c`` of each metric family the run scored (``pdms``, ...)
========================  ======================================================================================

Rerun (``rerun-sdk``, the ``viewer`` extra) writes the ``.rrd`` file with a default layout (the scene in 3D, the front
cameras, the sub-scores' curves); its viewer opens it (``rerun FILE.rrd``).
"""

import subprocess
import sys
from pathlib import Path
from typing import Any

import numpy as np

from lead_s2r.errors import UserError
from lead_s2r.files import write_atomically
from lead_s2r.report.bev import pieces
from lead_s2r.report.camera import on_ground
from lead_s2r.report.run_outputs import HEADLINES, RunOutputs, load_run, load_samples
from lead_s2r.report.sample_page import is_score, sub_scores, top_xy
from lead_s2r.schema import BoxClass
from lead_s2r.shards import MANIFEST, listed_samples, load_manifest

APPLICATION = "lead_s2r"
#: the extras fields that name each box's track, by source (the first one present is used)
TRACK_FIELDS = ("track_tokens", "track_ids", "object_ids")


def find_log(target: Path, log: str | None) -> tuple[Path, str, RunOutputs | None]:
    """The converted folder holding ``log``, the log, and the run when ``target`` is a run folder (its scores.json
    name the converted folders) rather than a converted folder; a log not there is a :class:`UserError`."""
    run = None if (target / MANIFEST).is_file() else load_run(target)
    folders = [target] if run is None else run.data_folders()
    logs: dict[str, Path] = {}
    for folder in folders:
        logs.update(dict.fromkeys(load_manifest(folder)["log"].to_pylist(), folder))
    if log is None:
        if len(logs) != 1:
            raise UserError(f"{target}: holds {len(logs)} logs; choose one with --log (e.g. {min(logs, default='-')})")
        log = next(iter(logs))
    if log not in logs:
        raise UserError(
            f"--log {log}: no such log in {', '.join(map(str, folders))}; it holds {len(logs)} logs, "
            f"e.g. {min(logs, default='-')}"
        )
    return logs[log], log, run


def write_recording(target: str | Path, rrd: str | Path, log: str | None = None, spawn: bool = False) -> Path:
    """Write the recording of ``log`` of converted folder or run ``target`` to ``rrd``; with ``spawn``, also open
    it in the Rerun viewer. Returns ``rrd``."""
    try:
        import rerun as rr
    except ImportError:
        raise UserError("lead-s2r view needs Rerun: pip install 'lead-s2r[viewer]'") from None
    rrd = Path(rrd)
    if rrd.suffix != ".rrd":
        raise UserError(f"--rrd {rrd}: a Rerun recording file ends in .rrd")
    folder, log, run = find_log(Path(target), log)
    keys = [row["key"] for row in listed_samples(folder, ("log",)) if row["log"] == log]
    samples = sorted(load_samples([folder], keys).values(), key=lambda s: s["meta"]["frame_idx"])
    recording = rr.RecordingStream(APPLICATION, recording_id=log)

    def record(partial: Path) -> None:
        recording.save(partial, default_blueprint=layout(samples))
        for sample in samples:
            log_frame(rr, recording, sample, run)
        recording.flush()
        recording.disconnect()

    write_atomically(rrd, record)
    if spawn:  # the viewer ships in the rerun-sdk wheel; `python -m rerun FILE` is its `rerun FILE`
        subprocess.Popen([sys.executable, "-m", "rerun", str(rrd)], start_new_session=True)
    return rrd


def layout(samples: list[dict[str, Any]]) -> Any:
    """The view the viewer opens with: the scene in 3D beside the front camera(s) over the sub-scores' curves."""
    import rerun.blueprint as rrb

    cameras = [c["id"] for c in (samples[0]["meta"].get("cameras", []) if samples else [])]
    shown = [c for c in cameras if c.startswith("front")][:3] or cameras[:1]
    views = [rrb.Spatial2DView(origin=f"/cameras/{camera}", name=camera) for camera in shown]
    side = rrb.Vertical(rrb.Horizontal(*views), rrb.TimeSeriesView(origin="/scores", name="sub-scores"))
    return rrb.Blueprint(rrb.Horizontal(rrb.Spatial3DView(origin="/", name="scene (ego frame)"), side),
                         collapse_panels=True)  # fmt: skip


def log_frame(rr: Any, recording: Any, sample: dict[str, Any], run: RunOutputs | None) -> None:
    """Every entity of one sample at its step of the timelines."""
    meta = sample["meta"]
    recording.set_time("frame", sequence=int(meta["frame_idx"]))
    recording.set_time("time", timestamp=np.datetime64(int(meta["timestamp_us"]), "us"))
    vehicle = meta["vehicle"]
    recording.log(
        "/ego",
        rr.Boxes3D(
            centers=[[vehicle["rear_axle_to_center"], 0.0, 0.8]],
            half_sizes=[[vehicle["length"] / 2, vehicle["width"] / 2, 0.8]],
            labels=["ego"],
        ),
    )
    for camera in meta.get("cameras", []):
        _camera(rr, recording, sample, camera)
    if "lidar" in sample:
        recording.log("/lidar", rr.Points3D(np.asarray(sample["lidar"])[:, :3], radii=0.03))
    if "boxes" in sample:
        _boxes(rr, recording, np.asarray(sample["boxes"], np.float64).reshape(-1, 10), meta)
    if "scoring" in sample:
        _map(rr, recording, sample["scoring"])
    if "future" in sample:
        recording.log(
            "/plan/logged", rr.LineStrips3D([on_ground(np.asarray(sample["future"])[:, 1:3])], colors=[[0, 166, 81]])
        )
    if run is not None:
        _run(rr, recording, sample["__key__"], run)


def _camera(rr: Any, recording: Any, sample: dict[str, Any], camera: dict[str, Any]) -> None:
    path = f"/cameras/{camera['id']}"
    pose = np.asarray(camera["cam_to_ego"], np.float64)
    recording.log(path, rr.Transform3D(translation=pose[:3, 3], mat3x3=pose[:3, :3]))
    recording.log(
        path,
        rr.Pinhole(
            image_from_camera=np.asarray(camera["K"], np.float64),
            resolution=[camera["width"], camera["height"]],
            camera_xyz=rr.ViewCoordinates.RDF,
        ),
    )
    image = sample.get(f"cam_{camera['id']}")
    if image is not None:
        recording.log(path, rr.EncodedImage(contents=bytes(image), media_type="image/jpeg"))


def track_ids(meta: dict[str, Any], count: int) -> list[str]:
    """Each box's track id: the source's (``extras.<dataset>.track_tokens``), else its row number."""
    for fields in meta.get("extras", {}).values():
        for name in TRACK_FIELDS:
            ids = fields.get(name) if isinstance(fields, dict) else None
            if isinstance(ids, list) and len(ids) == count:
                return [str(i) for i in ids]
    return [str(i) for i in range(count)]


def _boxes(rr: Any, recording: Any, boxes: np.ndarray, meta: dict[str, Any]) -> None:
    classes = boxes[:, 9].astype(int)
    names = [BoxClass(c).name if c in BoxClass._value2member_map_ else str(c) for c in classes]
    labels = [f"{name} {track}" for name, track in zip(names, track_ids(meta, len(boxes)), strict=True)]
    rotations = [rr.RotationAxisAngle(axis=[0.0, 0.0, 1.0], radians=float(yaw)) for yaw in boxes[:, 6]]
    recording.log(
        "/boxes",
        rr.Boxes3D(
            centers=boxes[:, :3],
            half_sizes=boxes[:, 3:6] / 2,
            rotation_axis_angles=rotations,
            class_ids=classes,
            labels=labels,
        ),
    )


def _map(rr: Any, recording: Any, scoring: dict[str, Any]) -> None:
    lanes = [on_ground(p) for p in pieces(scoring["centerline_xy"], scoring["centerline_offsets"])]
    polygons = pieces(scoring["polygon_xy"], scoring["polygon_offsets"])
    areas = [on_ground(np.vstack([p, p[:1]])) for p in polygons if len(p)]
    recording.log("/map/lanes", rr.LineStrips3D(lanes, colors=[[150, 150, 150]]))
    recording.log("/map/areas", rr.LineStrips3D(areas, colors=[[90, 90, 90]]))


def _run(rr: Any, recording: Any, key: str, run: RunOutputs) -> None:
    if key in run.predictions:
        recording.log(
            "/plan/predicted", rr.LineStrips3D([on_ground(top_xy(run.predictions[key]))], colors=[[228, 0, 124]])
        )
    for scores in run.scores:
        row = scores.rows.get(key) or {}
        for name in dict.fromkeys([*HEADLINES.get(scores.family, ())[:1], *sub_scores(scores.family)]):
            value = row.get(name)
            if is_score(name, value) and value is not None and np.isfinite(value):
                recording.log(f"/scores/{scores.family}/{name}", rr.Scalars(float(value)))
