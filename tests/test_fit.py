"""A real Lightning fit over converted shards: the mixing schedule and the LR schedule act per epoch."""

import lightning as L
import pytest
import torch
from tiny_models import TINY

from lead_s2r.data.datamodule import DriveDataModule, SourceSpec
from lead_s2r.data.mixing import MixingSchedule
from lead_s2r.models.config import TrajectoryGrid, tfv6_config
from lead_s2r.models.tfv6 import TFv6
from lead_s2r.training.cli import TRAINER_DEFAULTS
from lead_s2r.training.module import DrivingModule

pytestmark = pytest.mark.usefixtures("one_thread")


class Recorder(L.Callback):
    """Per training step: the learning rate and how many samples each source contributed."""

    def __init__(self) -> None:
        self.lrs: list[float] = []
        self.sizes: list[dict[str, int]] = []

    def on_train_batch_start(self, trainer, pl_module, batch, batch_idx) -> None:
        self.lrs.append(trainer.optimizers[0].param_groups[0]["lr"])
        self.sizes.append({source: len(b["__key__"]) for source, b in batch.items()})


def test_fit_follows_the_mixing_and_lr_schedules(toy_data):
    grids = {"carla": TrajectoryGrid(4, 0.5), "navsim": TrajectoryGrid(4, 0.5)}
    config = tfv6_config(**{**TINY, "trajectory_grids": grids, "use_radar": False})
    spec = SourceSpec([toy_data], cameras=["front"])
    schedule = MixingSchedule(
        {0: {"carla": 3, "navsim": 1}, 1: {"carla": 1, "navsim": 1}, 3: {"carla": 0, "navsim": 1}}, 4
    )
    data = DriveDataModule(train={"carla": spec, "navsim": spec}, schedule=schedule, steps_per_epoch=2)
    module = DrivingModule(TFv6(config), lr=1e-3, lr_schedule="cosine_restarts")
    recorder = Recorder()
    trainer = L.Trainer(
        max_epochs=4,
        accelerator="cpu",
        logger=False,
        enable_checkpointing=False,
        enable_progress_bar=False,
        enable_model_summary=False,
        callbacks=[recorder],
        **TRAINER_DEFAULTS,
    )
    trainer.fit(module, datamodule=data)
    assert recorder.sizes == [{"carla": 3, "navsim": 1}] * 2 + [{"carla": 2, "navsim": 2}] * 4 + [{"navsim": 4}] * 2
    lrs = torch.tensor(recorder.lrs)
    restarts = [step for step in range(1, len(lrs)) if lrs[step] > lrs[step - 1]]
    assert restarts == [2, 6]  # warm restarts after 1 and 2 more epochs (T_0 = one epoch, T_mult = 2)
    assert lrs[0] == pytest.approx(1e-3) and lrs[2] == pytest.approx(1e-3)
