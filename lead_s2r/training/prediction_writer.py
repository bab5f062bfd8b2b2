"""Write ``predict`` outputs to ``predictions.parquet`` (the format every scorer reads)."""

from pathlib import Path
from typing import Any

import lightning as L
import numpy as np
from lightning.pytorch.callbacks import BasePredictionWriter

from lead_s2r.predictions import Prediction, drop_repeats, write_predictions
from lead_s2r.training.distributed import gather_lists


def to_predictions(output: dict[str, dict[str, Any]]) -> list[Prediction]:
    """``DrivingModule.predict_step`` output (per source: key, dataset, t, xy, yaw) -> one Prediction per sample."""
    predictions = []
    for source_output in output.values():
        t = source_output["t"].cpu().numpy()
        xy, yaw = source_output["xy"].cpu().numpy(), source_output["yaw"].cpu().numpy()
        for i, (key, dataset) in enumerate(zip(source_output["key"], source_output["dataset"], strict=True)):
            predictions.append(Prediction(key, dataset, t, xy[i].astype(np.float64), yaw[i]))
    return predictions


class PredictionWriter(BasePredictionWriter):
    """Collects every rank's predictions and writes one ``predictions.parquet`` on rank 0 at the end.

    Args:
        output: the parquet file to write; by default ``<trainer.default_root_dir>/predictions.parquet``, so the
            predictions follow the run's other outputs.
    """

    def __init__(self, output: str | None = None) -> None:
        super().__init__(write_interval="batch")
        self.output = None if output is None else Path(output)
        self._predictions: list[Prediction] = []

    def write_on_batch_end(
        self,
        trainer: L.Trainer,
        pl_module: L.LightningModule,
        prediction: Any,
        batch_indices: Any,
        batch: Any,
        batch_idx: int,
        dataloader_idx: int,
    ) -> None:
        self._predictions.extend(to_predictions(prediction))

    def on_predict_epoch_end(self, trainer: L.Trainer, pl_module: L.LightningModule) -> None:
        predictions = gather_lists(self._predictions)
        if trainer.is_global_zero:
            output = self.output or Path(trainer.default_root_dir) / "predictions.parquet"
            write_predictions(output, drop_repeats(predictions))  # a padding sampler may repeat samples
        self._predictions = []
