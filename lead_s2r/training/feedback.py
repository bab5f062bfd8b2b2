"""What a training run tells the person who started it: where its logs go and, at the end, what it produced.

Lightning logs to TensorBoard when it is installed and to CSV otherwise; we want the CSV always (the table builder
and scripts read it without extra packages) and TensorBoard beside it when the ``[tensorboard]`` extra is installed,
both in one ``lightning_logs/version_N`` folder. A fit that ends silently leaves the user hunting for the checkpoint;
:func:`fit_summary` names the checkpoints, the final metrics and the log folder.
"""

import importlib.util
from pathlib import Path
from typing import Any

from lightning import Trainer
from lightning.pytorch.loggers import CSVLogger, Logger, TensorBoardLogger

LOG_FOLDER = "lightning_logs"
#: metrics shown at the end of a fit, at most (the full set is in metrics.csv)
SUMMARY_METRICS = 12


def tensorboard_installed() -> bool:
    return importlib.util.find_spec("tensorboard") is not None


def run_loggers(configured: Any, root: str | Path) -> Any:
    """The trainer's ``logger``: CSV logs in ``<root>/lightning_logs/version_N`` and, when tensorboard is installed, its
    event files in the same folder (one version number for both) first, then any logger a config adds (the W&B overlay,
    ``recipes/logging/wandb.yaml``); ``False`` keeps logging off, and a config's own CSV logger is kept."""
    if configured is False:
        return False
    added = [] if configured in (None, True) else list(configured) if isinstance(configured, list) else [configured]
    if any(isinstance(logger, CSVLogger) for logger in added):
        return added
    defaults: list[Logger] = [CSVLogger(root, name=LOG_FOLDER)]
    if tensorboard_installed():
        defaults.append(TensorBoardLogger(root, name=LOG_FOLDER, version=defaults[0].version, default_hp_metric=False))
    return [d for d in defaults if not any(type(a) is type(d) for a in added)] + added


def _metric_order(name: str) -> tuple[int, str]:
    """The loss first, then validation and scores; bookkeeping (batch sizes, learning rates) last."""
    for rank, prefix in enumerate(("train/loss", "val/", "score/", "train/")):
        if name.startswith(prefix) and "batch_size" not in name:
            return rank, name
    return 4, name


def fit_summary(trainer: Trainer, log_dir: str | None) -> list[str]:
    """Lines that end a fit: epochs and steps done, the last and best checkpoints, the final logged metrics and
    where the logs are, ``log_dir`` (``trainer.log_dir``, which every rank must ask for: it is a broadcast under
    DDP), with the TensorBoard command when it logged there."""
    lines = [f"fit done: {trainer.current_epoch} epoch(s), {trainer.global_step} optimizer step(s)"]
    checkpoint = trainer.checkpoint_callback
    if checkpoint is not None:
        if getattr(checkpoint, "last_model_path", ""):
            lines.append(f"  last checkpoint: {checkpoint.last_model_path}")
        if checkpoint.best_model_path:
            monitored = (
                f" ({checkpoint.monitor} {float(checkpoint.best_model_score):.4g})" if checkpoint.monitor else ""
            )
            lines.append(f"  best checkpoint: {checkpoint.best_model_path}{monitored}")
    metrics = {name: float(value) for name, value in trainer.callback_metrics.items() if value.numel() == 1}
    if metrics:
        shown = sorted(metrics, key=_metric_order)[:SUMMARY_METRICS]
        more = f" ({len(metrics) - len(shown)} more in metrics.csv)" if len(metrics) > len(shown) else ""
        lines.append(f"  final metrics{more}:")
        lines += [f"    {name:32s} {metrics[name]:.4g}" for name in shown]
    if log_dir:
        lines.append(f"  logs: {log_dir} (metrics.csv, config.yaml)")
        if any(isinstance(logger, TensorBoardLogger) for logger in trainer.loggers):
            lines.append(f"  TensorBoard: tensorboard --logdir {Path(log_dir).parent}")
    return lines
