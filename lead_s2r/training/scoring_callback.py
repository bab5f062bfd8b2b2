"""Run the open-loop scorers (RFS, ADE, PDMS...) on validation predictions during training, per dataset.

Contract with the LightningModule: ``validation_step`` returns a dict whose ``"predictions"`` entry is a list of
:class:`~lead_s2r.predictions.Prediction` (one per sample and inference, in the sample's ego frame). The callback
collects them over the epoch (from every rank), joins them by key with the converted validation folders, and logs
each scorer's float aggregates as ``<prefix>/<dataset>/<name>`` (e.g. ``val/wod_e2e/rfs``, ``val/navsim/ade``).

Under DDP each rank predicts its own share of the samples (the data module splits by sample); rank 0 gathers them,
scores every sample once and broadcasts the aggregates, so every rank logs the numbers a single process would
(a metric monitored by a checkpoint callback must exist on every rank).

A scorer runs only on the datasets it declares (``pdms@navsim-1.1``: NAVSIM only). PDMS keeps PDM-Closed's references in
memory across epochs; ``metric_config={"pdms@navsim-1.1": {"reference_cache": DIR}}`` keeps them across runs too.
"""

from collections import defaultdict
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import lightning as L

from lead_s2r.predictions import Prediction, drop_repeats
from lead_s2r.scoring.run import make_scorer
from lead_s2r.shards import read_samples
from lead_s2r.training.distributed import gather_lists


class ScoringCallback(L.Callback):
    """Score validation predictions with registered scorers at the end of every validation epoch."""

    def __init__(
        self,
        data: str | Path | Sequence[str | Path],
        metrics: Sequence[str] = ("rfs@wod-e2e-2025", "ade"),
        metric_config: dict[str, dict[str, Any]] | None = None,
        prefix: str = "val",
        output_key: str = "predictions",
    ) -> None:
        """``data``: converted folder(s) holding the validation samples; ``metric_config``: per-metric options."""
        super().__init__()
        self.folders = [Path(data)] if isinstance(data, str | Path) else [Path(folder) for folder in data]
        metric_config = metric_config or {}
        self.scorers = [make_scorer(metric, **metric_config.get(metric, {})) for metric in metrics]
        self.prefix = prefix
        self.output_key = output_key
        self._samples: dict[str, dict[str, Any]] | None = None
        self._predictions: list[Prediction] = []

    def samples(self) -> dict[str, dict[str, Any]]:
        """The validation samples by key, read once with only the fields the scorers need."""
        if self._samples is None:
            fields = sorted({name for scorer in self.scorers for name in scorer.fields})
            self._samples = {s["__key__"]: s for folder in self.folders for s in read_samples(folder, fields=fields)}
        return self._samples

    def on_validation_epoch_start(self, trainer: L.Trainer, pl_module: L.LightningModule) -> None:
        self._predictions = []

    def on_validation_batch_end(
        self,
        trainer: L.Trainer,
        pl_module: L.LightningModule,
        outputs: Any,
        batch: Any,
        batch_idx: int,
        dataloader_idx: int = 0,
    ) -> None:
        if isinstance(outputs, dict) and self.output_key in outputs:
            self._predictions.extend(outputs[self.output_key])

    def on_validation_epoch_end(self, trainer: L.Trainer, pl_module: L.LightningModule) -> None:
        if trainer.sanity_checking:
            return
        predictions = gather_lists(self._predictions)
        metrics = self.compute(predictions) if trainer.is_global_zero else None
        for name, value in trainer.strategy.broadcast(metrics, src=0).items():
            pl_module.log(name, value, sync_dist=True)  # the same value on every rank: the reduction keeps it
        self._predictions = []

    def compute(self, predictions: list[Prediction]) -> dict[str, float]:
        """Float aggregates of every scorer for every dataset present in ``predictions``."""
        by_dataset: dict[str, list[Prediction]] = defaultdict(list)
        for p in drop_repeats(predictions):
            by_dataset[p.dataset].append(p)
        samples = self.samples()
        metrics = {}
        for dataset, group in sorted(by_dataset.items()):
            keys = dict.fromkeys(p.key for p in group)
            data = [samples[key] for key in keys if key in samples]
            for scorer in self.scorers:
                if not scorer.scores_any(data):
                    continue
                for name, value in scorer.score(group, data).aggregates.items():
                    if isinstance(value, float):
                        metrics[f"{self.prefix}/{dataset}/{name}"] = value
        return metrics
