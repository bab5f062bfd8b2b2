"""The LightningModule: per-source forward passes and loss masks, ADE/FDE validation, ISO-frame predictions.

A checkpoint rebuilds its module alone (``DrivingModule.load_from_checkpoint(path)``, the CARLA agent): the network is
left out of ``save_hyperparameters`` (an ``nn.Module`` there would be pickled whole, and its weights are in the state
dict anyway), and :meth:`DrivingModule.on_save_checkpoint` writes it back into the checkpoint's hyper-parameters as
plain data, its class path and typed config (:func:`model_spec`), with LightningCLI's trusted instantiator, which
rebuilds a class path the way ``lead-s2r fit`` did from the YAML.
"""

import inspect
import json
import math
import warnings
from collections.abc import Mapping
from dataclasses import asdict, is_dataclass
from typing import Any, Literal, Protocol, runtime_checkable

import lightning as L
import torch
from lightning.pytorch.utilities import rank_zero_info, rank_zero_warn
from torch import Tensor, nn
from torch.optim.lr_scheduler import LRScheduler
from torchmetrics import MeanMetric

from lead_s2r.data.lead_origin import centre_waypoints_to_rear_axle
from lead_s2r.models.inputs import PLANNING_TASKS, Batch
from lead_s2r.models.lead_driver import LeadDriver
from lead_s2r.models.lead_loss import adamw, cosine_schedule, training_layout
from lead_s2r.training.loss_table import TASK_TARGETS, task_loss
from lead_s2r.training.losses import valid_mask
from lead_s2r.training.masking import SIM_TO_REAL, active_tasks
from lead_s2r.training.prediction_writer import to_predictions
from lead_s2r.training.weights import LoadReport, load_matching

#: Unnormalised weights (all 1 except depth, as LEAD's table before it divides by the sum); a LEAD network uses LEAD's
#: normalised weights (``LeadDriver.loss_weights``).
DEFAULT_LOSS_WEIGHTS: dict[str, float] = {task: 1.0 for task in TASK_TARGETS} | {"depth": 1e-5}

#: Lightning's allow-listed instantiator (LightningCLI's); ``load_from_checkpoint`` builds the module with it.
INSTANTIATOR = "lightning.pytorch.cli.instantiate_module"


@runtime_checkable
class TrainingData(Protocol):
    """What :class:`DrivingModule` reads from its data module (``DrivingModule(data=...)``, linked by ``lead-s2r fit``;
    :class:`~lead_s2r.data.datamodule.DriveDataModule` provides all of it). LightningCLI checks the linked data module
    against these signatures, return types included; methods only, so checking it evaluates nothing."""

    def current_batch_sizes(self) -> dict[str, int]:
        """Per-rank batch size of each training source in the trainer's current epoch."""
        ...

    def epoch_steps(self) -> int:
        """Batches per training epoch, the same on every rank."""
        ...

    def validation_sources(self) -> list[str]:
        """The names of the validation sources (every rank makes their metrics, data or not)."""
        ...


def model_spec(model: nn.Module) -> dict[str, Any] | None:
    """``{"class_path", "init_args": {"config"}}`` that rebuilds ``model``, in JSON types (a ``weights_only`` load
    reads them); None for a network not built from one dataclass ``config`` argument."""
    config = getattr(model, "config", None)
    if not is_dataclass(config) or "config" not in inspect.signature(type(model)).parameters:
        return None
    cls = type(model)
    return {
        "class_path": f"{cls.__module__}.{cls.__qualname__}",
        "init_args": {"config": json.loads(json.dumps(asdict(config)))},
    }


class DrivingModule(L.LightningModule):
    """Trains any model with the driving interface (``tasks(source)``, ``grid(source)``, ``forward(batch, source,
    tasks)``) on ``{source: batch}`` inputs.

    A planning term is the mean over the samples of every source that supervises it, so a source's influence grows
    with its share of the batch (the mixing schedule's knob); a perception term is one per source (each source has
    its own head, as in LEAD); terms are weighted and summed. A LEAD network (:class:`LeadDriver`) trains as LEAD's
    Trainer does (docs/training.md, "Training as LEAD trains"): LEAD's term definitions, its weights normalised over
    its whole table, channels-last weights, and LEAD's optimizer and schedule from :mod:`lead_s2r.models.lead_loss`.

    Args:
        model: the network, e.g. ``LeadDriver(LeadConfig(use_navsim_data=True, LTF=True, use_planning_decoder=True))``
            or ``EgoStatusMLP()``.
        supervise: per source, task groups ("planning", "perception") or task names it supervises; default
            sim-to-real (CARLA perception only, NAVSIM planning + perception, WOD planning).
        loss_weights: per-task weights over :data:`DEFAULT_LOSS_WEIGHTS` (a LEAD network's: LEAD's normalised
            weights, ``LeadDriver.loss_weights``).
        lr, weight_decay, betas, amsgrad: AdamW settings (LEAD: 3e-4, 0.01, AMSGrad).
        lr_schedule: stepped every optimizer step. "cosine_restarts" is LEAD's CARLA/NAVSIM schedule (warm
            restarts after 1, 2, 4, 8... epochs, so cycles end at epochs 1, 3, 7, 15, 31, the mixing anchors);
            "cosine" decays once over the whole run (LEAD's WOD-E2E schedule).
        warmup_steps: the learning rate rises linearly over these first optimizer steps, then follows ``lr_schedule``
            (a cosine then decays over the steps left). 0 (LEAD's): none. The smoke twins use a few, so the first
            steps of a freshly initialised model, whose gradients are the largest, cannot throw it far.
        compile: wrap the model with ``torch.compile`` (parameter names stay the same).
        init_from: checkpoint whose matching tensors initialise the model (fine-tuning); new heads are reported.
        log_val_losses: also log every loss term on the validation data (``val/<source>/<task>``), for loss curves.
            Under DDP each is the mean of the ranks' means, not the exact mean over samples that ADE/FDE are.
        data: the data module it trains on, for its side of :class:`TrainingData` (per-epoch batch sizes logged,
            steps per epoch, validation sources); ``lead-s2r fit`` links it. None (plain dataloaders): no batch-size
            log, no ADE/FDE metrics made ahead of validation, Lightning's estimate of the steps per epoch. Not a
            hyper-parameter: a checkpoint rebuilds the module without it.
    """

    def __init__(
        self,
        model: nn.Module,
        supervise: dict[str, list[str]] | None = None,
        loss_weights: dict[str, float] | None = None,
        lr: float = 3e-4,
        weight_decay: float = 0.01,
        betas: tuple[float, float] = (0.9, 0.999),
        amsgrad: bool = True,
        lr_schedule: Literal["constant", "cosine_restarts", "cosine"] = "constant",
        warmup_steps: int = 0,
        compile: bool = False,
        init_from: str | None = None,
        log_val_losses: bool = False,
        data: TrainingData | None = None,
    ) -> None:
        super().__init__()
        self.save_hyperparameters(ignore=["model", "data"])
        self.data = data
        self.model = model
        self.supervise = {k: list(v) for k, v in (SIM_TO_REAL if supervise is None else supervise).items()}
        model_weights = model.loss_weights if isinstance(model, LeadDriver) else {}
        self.loss_weights = DEFAULT_LOSS_WEIGHTS | model_weights | (loss_weights or {})
        unknown = set(self.loss_weights) - set(TASK_TARGETS)
        if unknown:
            raise ValueError(f"loss_weights: unknown tasks {sorted(unknown)}; known: {sorted(TASK_TARGETS)}")
        self.val_means = nn.ModuleDict()  # per "<source>/<metric>"; metric states stay out of checkpoints
        self.init_report: LoadReport | None = None
        if init_from is not None:
            self.init_report = load_matching(self.model, init_from)
            rank_zero_info(self.init_report.summary())
        if compile:
            self.model.compile()

    def on_save_checkpoint(self, checkpoint: dict[str, Any]) -> None:
        """Describe the network in the checkpoint's hyper-parameters (see the module docstring).

        ``init_from`` is dropped there: the weights it loaded are in the state dict, and a rebuilt module must not read
        a file that may be gone. A network :func:`model_spec` cannot describe needs ``model=`` when loaded."""
        spec = model_spec(self.model)
        if spec is None:
            return
        hparams = checkpoint.setdefault(self.CHECKPOINT_HYPER_PARAMS_KEY, {})
        hparams.update(model=spec, init_from=None)
        hparams.setdefault("_instantiator", INSTANTIATOR)

    def setup(self, stage: str) -> None:
        """At the start of a fit, put a LEAD network's weights in LEAD's channels-last layout (prediction keeps the
        loaded layout)."""
        if stage == "fit" and isinstance(self.model, LeadDriver):
            training_layout(self.model)

    def compute_losses(self, batch: Mapping[str, Batch]) -> tuple[Tensor | None, dict[str, tuple[Tensor, int]]]:
        """Weighted total (None when nothing is supervised) and every per-source term with its batch size."""
        per_term: dict[str, list[tuple[Tensor, int]]] = {}
        terms: dict[str, tuple[Tensor, int]] = {}
        for source, source_batch in batch.items():
            tasks = active_tasks(source, source_batch, self.model.tasks(source), self.supervise)
            if not tasks:
                continue
            n = len(source_batch["speed"])
            pred = self.model(source_batch, source, tasks)
            for task in sorted(tasks):
                value = task_loss(task, pred, source_batch, self.model)
                terms[f"{source}/{task}"] = (value, n)
                term = task if task in PLANNING_TASKS else f"{source}/{task}"
                per_term.setdefault(term, []).append((value, n))
        if not per_term:
            return None, terms
        total = sum(
            self.loss_weights[term.split("/")[-1]] * sum(v * n for v, n in values) / sum(n for _, n in values)
            for term, values in per_term.items()
        )
        return total, terms

    def on_train_epoch_start(self) -> None:
        """Log this epoch's per-rank batch size of each source (``train/batch_size/<source>``), zeros included."""
        for source, size in (self.data.current_batch_sizes() if self.data else {}).items():
            self.log(f"train/batch_size/{source}", float(size), on_epoch=True, sync_dist=True)

    def training_step(self, batch: Mapping[str, Batch], batch_idx: int) -> Tensor | None:
        total, terms = self.compute_losses(batch)
        for name, (value, n) in terms.items():
            self.log(f"train/{name}", value, batch_size=n)
        if total is None:
            rank_zero_warn(f"step {batch_idx}: no source in {sorted(batch)} supervises anything; step skipped")
            return None
        self.log("train/loss", total, prog_bar=True, batch_size=sum(len(b["speed"]) for b in batch.values()))
        return total

    def on_validation_epoch_start(self) -> None:
        """One running mean per (validation source with a planner, ADE/FDE), made on every rank before any batch.

        Under DDP a rank may hold no sample of a source; its metric must still exist and be computed at the epoch's
        end, since computing syncs the ranks and one rank missing from that sync would hang the others."""
        for source in self.data.validation_sources() if self.data else {}:
            if "waypoints" in self.model.tasks(source):
                for metric in ("ade", "fde"):
                    self._val_mean(f"{source}/{metric}")

    def validation_step(self, batch: Mapping[str, Batch], batch_idx: int, dataloader_idx: int = 0) -> dict[str, Any]:
        """ADE / FDE per source on its own grid (``val/<source>/ade``, ``.../fde``); with ``log_val_losses``, every loss
        term as ``val/<source>/<task>`` too (the loss curves' validation side; no weighted total, since each source's
        batch comes from its own dataloader). Returns ``{"predictions": [Prediction, ...]}`` so scoring callbacks
        (RFS...) can use the same forward pass."""
        if self.hparams.log_val_losses:
            _, terms = self.compute_losses(batch)
            for name, (value, n) in terms.items():
                self.log(f"val/{name}", value, batch_size=n, add_dataloader_idx=False, sync_dist=True)
        outputs = self.predict_step(batch, batch_idx)
        for source, output in outputs.items():
            source_batch = batch[source]
            if "waypoints" not in source_batch:
                continue
            target = source_batch["waypoints"]
            valid = valid_mask(source_batch, "waypoints", target)
            has = valid.any(1)
            if not has.any():
                continue
            err = (output["xy"] - target).norm(dim=-1)
            last = valid.long().cumsum(1).argmax(1)
            fde = err[torch.arange(len(err), device=err.device), last]
            self._val_mean(f"{source}/ade").update(err[valid])
            self._val_mean(f"{source}/fde").update(fde[has])
        return {"predictions": to_predictions(outputs)}

    def _val_mean(self, key: str) -> MeanMetric:
        """The running mean logged as ``val/<key>`` (key ``<source>/<metric>``) at the epoch's end.

        A metric object over every waypoint (ADE) or sample (FDE) of every rank, not a logged batch mean: Lightning's
        batch-size-weighted mean truncates the summed batch sizes to an integer when it averages them over ranks,
        so 18 + 17 samples would count as 34."""
        if key not in self.val_means:
            self.val_means[key] = MeanMetric().to(self.device)
        return self.val_means[key]

    def on_validation_epoch_end(self) -> None:
        """Compute every running mean on every rank (each computation syncs the ranks); log those that saw data."""
        for key, mean in self.val_means.items():
            with warnings.catch_warnings():  # a rank without a sample of this source has not updated it
                warnings.filterwarnings("ignore", message=".*was called before the ``update`` method.*")
                value = mean.compute()
            mean.reset()
            if torch.isfinite(value):
                self.log(f"val/{key}", value, add_dataloader_idx=False, sync_dist=True)  # equal on every rank

    def predict_step(self, batch: Mapping[str, Batch], batch_idx: int, dataloader_idx: int = 0) -> dict[str, Any]:
        """Per source that has a planner: sample keys and datasets, time grid ``t`` (T,) in seconds, and poses in
        the ISO ego frame: ``xy`` (B, T, 2) metres and ``yaw`` (B, T) radians (NaN where no headings are predicted)."""
        result = {}
        for source, source_batch in batch.items():
            tasks = {"waypoints", "headings"} & self.model.tasks(source)
            if "waypoints" not in tasks:
                continue
            pred = self.model(source_batch, source, tasks)
            xy = pred["waypoints"].float()
            if "origin_x" in source_batch:  # LEAD's CARLA frame (vehicle centre) back to our rear axle
                xy = centre_waypoints_to_rear_axle(xy, source_batch["origin_x"])
            yaw = (
                pred["headings"].float()
                if "headings" in pred
                else torch.full(xy.shape[:2], float("nan"), device=xy.device)
            )
            keys = list(source_batch.get("__key__", [f"{source}-{batch_idx}-{i}" for i in range(len(xy))]))
            result[source] = {
                "key": keys,
                "dataset": list(source_batch.get("__dataset__", [source] * len(xy))),
                "t": torch.tensor(self.model.grid(source).times, dtype=torch.float32),
                "xy": xy,
                "yaw": yaw,
            }
        return result

    def configure_optimizers(self) -> Any:
        """AdamW, and ``lr_schedule`` (none for a constant rate) behind a linear warm-up of ``warmup_steps`` (lr / n on
        the first step, lr on the n-th)."""
        hp, lr = self.hparams, torch.optim.lr_scheduler
        optimizer = adamw(
            self.model.parameters(), lr=hp.lr, weight_decay=hp.weight_decay, betas=tuple(hp.betas), amsgrad=hp.amsgrad
        )
        scheduler: LRScheduler | None = None
        if hp.lr_schedule != "constant":
            epochs = max(1, self.trainer.max_epochs or 1)
            restarts = hp.lr_schedule == "cosine_restarts"
            scheduler = cosine_schedule(
                optimizer, self._steps_per_epoch(), epochs, restarts, skipped_steps=hp.warmup_steps
            )
        n = hp.warmup_steps
        if n > 0:
            warmup = lr.LinearLR(optimizer, start_factor=1.0 / n, end_factor=1.0, total_iters=n - 1)
            scheduler = warmup if scheduler is None else lr.SequentialLR(optimizer, [warmup, scheduler], milestones=[n])
        if scheduler is None:
            return optimizer
        return {"optimizer": optimizer, "lr_scheduler": {"scheduler": scheduler, "interval": "step"}}

    def _steps_per_epoch(self) -> int:
        """Optimizer steps per epoch: the data module's fixed epoch length, else Lightning's estimate."""
        steps = self.data.epoch_steps() if self.data else None
        if steps is None:
            total = self.trainer.estimated_stepping_batches
            if not math.isfinite(total):
                raise ValueError(f"lr_schedule {self.hparams.lr_schedule!r} needs a finite number of steps per epoch")
            steps = int(total) // max(1, self.trainer.max_epochs or 1)
        return max(1, int(steps) // self.trainer.accumulate_grad_batches)
