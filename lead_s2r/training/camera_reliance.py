"""How much a model's plan depends on its cameras: the mean distance (m) its waypoints move when every sample of a
batch is given another sample's camera images, its ego status, route and LiDAR left as they are.

Why: a camera model that scores like the Ego MLP has either learned to drive from the ego status alone or failed to
learn at all, and its scores cannot tell which. A shift near 0 m says the plan ignores the cameras (what the
quickstart's toy LTFv6 does after a few dozen steps, docs/training.md, "Does LTFv6 look at its cameras?"); a shift of
metres says the cameras steer it. Each sample takes the images of the next one in its batch (the last one the
first's), so a batch of one sample has nothing to swap and is left out.

:class:`CameraReliance` measures it during ``lead-s2r predict`` (``camera_reliance.json`` beside the predictions); a
dataset without camera images in its batches (the Ego MLP's) gets no entry.
"""

import json
from pathlib import Path
from typing import Any

import lightning as L
import torch
from torch import Tensor

from lead_s2r.files import write_text
from lead_s2r.models.inputs import Batch
from lead_s2r.training.distributed import gather_lists

FILENAME = "camera_reliance.json"


def with_swapped_cameras(batch: Batch) -> Batch:
    """A shallow copy of ``batch`` in which sample i has sample i+1's camera images (the last has the first's)."""
    swapped = dict(batch)
    if "rgb" in batch:
        swapped["rgb"] = torch.roll(batch["rgb"], shifts=-1, dims=0)
    return swapped  # type: ignore[return-value]


def camera_shift(model: torch.nn.Module, batch: Batch, source: str, waypoints: Tensor | None = None) -> Tensor:
    """Per sample (B,), the mean distance (m) between the waypoints ``model`` plans for ``batch`` and those it plans
    with the cameras swapped (:func:`with_swapped_cameras`); ``waypoints``: the former, when already computed."""
    with torch.no_grad():
        if waypoints is None:
            waypoints = model(batch, source, {"waypoints"})["waypoints"]
        moved = model(with_swapped_cameras(batch), source, {"waypoints"})["waypoints"]
    return (moved.float() - waypoints.float()).norm(dim=-1).mean(dim=-1)


class CameraReliance(L.Callback):
    """During ``predict``, the camera shift (:func:`camera_shift`) of every sample whose batch has camera images and
    at least two samples; at the end, ``<trainer.default_root_dir>/camera_reliance.json`` on rank 0:
    ``{dataset: {"mean_m": float, "samples": int}}``. Expects :meth:`DrivingModule.predict_step`'s outputs."""

    def __init__(self) -> None:
        self._shifts: list[tuple[str, str, float]] = []  # (dataset, sample key, shift)

    def on_predict_batch_end(
        self,
        trainer: L.Trainer,
        pl_module: L.LightningModule,
        outputs: Any,
        batch: Any,
        batch_idx: int,
        dataloader_idx: int = 0,
    ) -> None:
        for source, output in (outputs or {}).items():
            source_batch = batch[source]
            if len(output["xy"]) < 2 or "rgb" not in source_batch:
                continue
            # predict_step's xy is the model's waypoints, frame and all: the distance is the same in either
            shifts = camera_shift(pl_module.model, source_batch, source, output["xy"])
            self._shifts.extend(zip(output["dataset"], output["key"], shifts.tolist(), strict=True))

    def on_predict_epoch_end(self, trainer: L.Trainer, pl_module: L.LightningModule) -> None:
        # keyed by sample: a padding sampler may give a rank a sample another one had
        shifts = {(dataset, key): shift for dataset, key, shift in gather_lists(self._shifts)}
        self._shifts = []
        if not trainer.is_global_zero or not shifts:
            return
        summary: dict[str, dict[str, float | int]] = {}
        for dataset in sorted({dataset for dataset, _ in shifts}):
            mine = [shift for (name, _), shift in shifts.items() if name == dataset]
            summary[dataset] = {"mean_m": sum(mine) / len(mine), "samples": len(mine)}
        write_text(Path(trainer.default_root_dir) / FILENAME, json.dumps(summary, indent=2))
