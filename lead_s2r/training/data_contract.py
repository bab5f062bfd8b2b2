"""What :class:`~lead_s2r.training.module.DrivingModule` reads from its data module (``DrivingModule(data=...)``,
linked by ``lead-s2r fit``), declared.

:class:`~lead_s2r.data.datamodule.DriveDataModule` provides all of it. LightningCLI checks the linked data module
against these signatures, return types included, so an implementation returns exactly these types. A run on plain
dataloaders (no ``data``) trains too: with no per-source batch-size log, no ADE/FDE metrics made ahead of validation,
and Lightning's estimate of the steps per epoch.
"""

from typing import Protocol, runtime_checkable


@runtime_checkable
class TrainingData(Protocol):
    """The data module's side of the contract (methods only, so checking it evaluates nothing)."""

    def current_batch_sizes(self) -> dict[str, int]:
        """Per-rank batch size of each training source in the trainer's current epoch."""
        ...

    def epoch_steps(self) -> int:
        """Batches per training epoch, the same on every rank."""
        ...

    def validation_sources(self) -> list[str]:
        """The names of the validation sources (every rank makes their metrics, data or not)."""
        ...
