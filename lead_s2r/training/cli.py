"""``lead-s2r fit|validate|test|predict``: LightningCLI over :class:`DrivingModule` and :class:`DriveDataModule`.

Recipes under ``recipes/`` are plain LightningCLI YAML; every value can be overridden on the command line
(``--trainer.max_epochs=31``) and the resolved config is saved next to each run.

A run's outputs share one root, ``trainer.default_root_dir``: checkpoints in ``<root>/checkpoints`` (a
``ModelCheckpoint`` without ``dirpath``; Lightning alone would bury them in the logger's version folder), logs and
the resolved config in ``<root>/lightning_logs/version_N``, predictions in ``<root>/predictions.parquet`` (a
``PredictionWriter`` without ``output``). So ``--trainer.default_root_dir`` moves all of them together.
"""

from pathlib import Path

from lightning.pytorch.cli import LightningCLI

from lead_s2r.data.datamodule import DriveDataModule
from lead_s2r.training.module import DrivingModule

#: The mixing schedule changes batch composition per epoch, and webdataset splits data over ranks itself.
TRAINER_DEFAULTS = {"reload_dataloaders_every_n_epochs": 1, "use_distributed_sampler": False}


class DrivingCLI(LightningCLI):
    """LightningCLI that roots checkpoints without a ``dirpath`` at ``<default_root_dir>/checkpoints``."""

    def after_instantiate_classes(self) -> None:
        super().after_instantiate_classes()
        for callback in self.trainer.checkpoint_callbacks:
            if callback.dirpath is None:
                callback.dirpath = str(Path(self.trainer.default_root_dir) / "checkpoints")


def run_lightning_cli(args: list[str] | None = None) -> None:
    """Run a LightningCLI subcommand with ``args`` (e.g. ``["fit", "--config", "recipes/..."]``; None: sys.argv)."""
    DrivingCLI(
        DrivingModule,
        DriveDataModule,
        args=args,
        trainer_defaults=TRAINER_DEFAULTS,
        save_config_kwargs={"overwrite": True},
    )
