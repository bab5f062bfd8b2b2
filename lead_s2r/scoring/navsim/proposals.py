"""What every NAVSIM scorer does per sample before scoring: the scene token, the most probable inference put on
NAVSIM's input grid, the scene (or why there is none), PDM-Closed's reference (planned once per scene and
cached), and the frame before it that EPDMS's EC compares with."""

import io
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from lead_s2r.files import write_bytes
from lead_s2r.geometry import resample
from lead_s2r.predictions import TIME_TOLERANCE, Prediction, most_probable
from lead_s2r.scoring.navsim_grid import INTERVAL, navsim_poses, require_headings
from lead_s2r.scoring.pdm.pdm_closed import plan_reference
from lead_s2r.scoring.pdm.route import RouteError
from lead_s2r.scoring.pdm.sample import scene_from_sample
from lead_s2r.scoring.pdm.scene import PDMScene, PreviousFrame

#: PDM-Closed's output: 51 poses at 0.1 s from t = 0.
REFERENCE_SHAPE = (51, 3)


@dataclass
class Frame:
    """One predicted sample on its way to a row: the scene (None if it cannot be built) and the plan."""

    sample: dict[str, Any]
    scene: PDMScene | None
    poses: np.ndarray
    interval: float
    error: str | None

    @property
    def time_s(self) -> float:
        return int(self.sample["meta"]["timestamp_us"]) * 1e-6

    @property
    def log(self) -> str:
        return str(self.sample["meta"]["log_id"])


def frame_of(sample: dict[str, Any], predictions: list[Prediction]) -> Frame:
    """The most probable inference of ``predictions`` on NAVSIM's grid, and the sample's scene; a scene without a
    route PDM-Closed can follow is None with the error, an invalid row (NAVSIM isolates a failing token)."""
    poses, interval = proposal_of(most_probable(predictions))
    try:
        return Frame(sample, scene_from_sample(sample), poses, interval, None)
    except RouteError as err:
        return Frame(sample, None, poses, interval, str(err))


def proposal_of(prediction: Prediction) -> tuple[np.ndarray, float]:
    """A prediction as score_proposals' input: poses (K, 3) at ``interval * (k + 1)`` and the interval; one off
    such a grid is resampled to NAVSIM's."""
    t = np.asarray(prediction.t, np.float64)
    interval = float(t[0])
    if np.abs(t - interval * np.arange(1, len(t) + 1)).max() <= TIME_TOLERANCE:
        require_headings(prediction)
        return np.column_stack([prediction.xy, prediction.yaw]).astype(np.float64), interval
    return navsim_poses(prediction), INTERVAL


def previous_frame(current: Frame, earlier: Frame) -> PreviousFrame:
    """The earlier frame as seen from the current one: its rear-axle pose from the current sample's ``past``."""
    gap = current.time_s - earlier.time_s
    past = np.asarray(current.sample["past"], np.float64)
    pose, inside = resample(past[:, 0], past[:, 1:4], np.array([-gap]), angle_columns=(2,))
    if not inside.all():
        raise ValueError(
            f"sample {current.sample['__key__']!r}: field 'past' does not reach {-gap:.2f} s, where the frame "
            f"{earlier.sample['__key__']!r} paired with it for EC was; re-convert with a longer history"
        )
    ego = earlier.sample["meta"]["ego"]
    return PreviousFrame(
        ego_pose=pose[0],
        ego_velocity=np.asarray(ego["velocity"], np.float64),
        ego_acceleration=np.asarray(ego["acceleration"], np.float64),
        poses=earlier.poses,
        interval=earlier.interval,
        frame_gap=gap,
    )


def first_row(result: dict[str, np.ndarray], scores: tuple[str, ...], steps: tuple[str, ...] = ()) -> dict[str, Any]:
    """Row 0 of ``score_proposals``' columns: ``scores`` as floats, ``steps`` (failure steps) as ints."""
    return {name: float(np.asarray(result[name])[0]) for name in scores} | {
        name: int(np.asarray(result[name])[0]) for name in steps
    }


class ReferenceCache:
    """PDM-Closed references per sample key: in memory, and in ``folder`` (``<key>.npy``) when given.

    A reference depends on the scene only, so one cache serves every model scored on the same data, and every
    worker of one run (``score --workers`` / ``--executor ray`` on a shared folder): a file is written under a name of
    its own and renamed into place, so a reader sees a whole reference or none, and two workers planning the same
    scene write the same bytes."""

    def __init__(self, folder: str | Path | None = None) -> None:
        self.folder = Path(folder) if folder else None
        self.memory: dict[str, np.ndarray] = {}

    def get(self, scene: PDMScene) -> np.ndarray:
        """The scene's reference: cached, else planned (and stored)."""
        key = scene.key
        if key in self.memory:
            return self.memory[key]
        path = self.folder / f"{key}.npy" if self.folder else None
        if path is not None and path.is_file():
            reference = np.load(path)
            if reference.shape != REFERENCE_SHAPE or not np.isfinite(reference).all():
                raise ValueError(f"{path}: a reference must be {REFERENCE_SHAPE} finite poses; delete the file")
        else:
            reference = plan_reference(scene)
            if path is not None:
                buffer = io.BytesIO()
                np.save(buffer, reference)
                write_bytes(path, buffer.getvalue())
        self.memory[key] = reference
        return reference
