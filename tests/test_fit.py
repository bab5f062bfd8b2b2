"""A real Lightning fit over converted shards: the mixing schedule and the LR schedule act per epoch."""

import csv
import math
import sys
from typing import Any

import lightning as L
import pytest
import torch
import yaml
from tiny_models import LTFV6_SWITCHES, TOY_LTFV6

from lead_s2r.data.datamodule import DriveDataModule, SourceSpec
from lead_s2r.data.mixing import MixingSchedule
from lead_s2r.models.input_spec import input_spec
from lead_s2r.models.lead_driver import LeadDriver, ltfv6_navsim
from lead_s2r.predictions import read_predictions
from lead_s2r.training.cli import TRAINER_DEFAULTS, run_lightning_cli
from lead_s2r.training.feedback import tensorboard_installed
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


def mixed_ltfv6() -> LeadDriver:
    """LTFv6 with CARLA heads (LTFv6 + LEAD): the network of a CARLA + NAVSIM mix."""
    return ltfv6_navsim(**TOY_LTFV6, use_carla_data=True)


def wired(network: LeadDriver, **data: Any) -> DriveDataModule:
    """``DriveDataModule(**data)`` building what ``network`` reads, wired as ``lead-s2r fit`` links them."""
    return DriveDataModule(**data, inputs=input_spec(network.config))


def fit_recording(module: DrivingModule, data: DriveDataModule, epochs: int) -> Recorder:
    """Fit ``module`` on ``data`` for ``epochs`` on the CPU, recording every step."""
    recorder = Recorder()
    trainer = L.Trainer(
        max_epochs=epochs,
        accelerator="cpu",
        logger=False,
        enable_checkpointing=False,
        enable_progress_bar=False,
        enable_model_summary=False,
        callbacks=[recorder],
        **TRAINER_DEFAULTS,
    )
    trainer.fit(module, datamodule=data)
    return recorder


def test_fit_follows_the_mixing_and_lr_schedules(toy_data):
    spec = SourceSpec([toy_data], cameras=["front"])
    schedule = MixingSchedule(
        {0: {"carla": 3, "navsim": 1}, 1: {"carla": 1, "navsim": 1}, 3: {"carla": 0, "navsim": 1}}, 4
    )
    network = mixed_ltfv6()
    data = wired(network, train={"carla": spec, "navsim": spec}, schedule=schedule, steps_per_epoch=2)
    recorder = fit_recording(DrivingModule(network, lr=1e-3, lr_schedule="cosine_restarts", data=data), data, 4)
    assert recorder.sizes == [{"carla": 3, "navsim": 1}] * 2 + [{"carla": 2, "navsim": 2}] * 4 + [{"navsim": 4}] * 2
    lrs = torch.tensor(recorder.lrs)
    restarts = [step for step in range(1, len(lrs)) if lrs[step] > lrs[step - 1]]
    assert restarts == [2, 6]  # warm restarts after 1 and 2 more epochs (T_0 = one epoch, T_mult = 2)
    assert lrs[0] == pytest.approx(1e-3) and lrs[2] == pytest.approx(1e-3)


@pytest.mark.parametrize("schedule", ["constant", "cosine"])
def test_warmup_rises_linearly_then_hands_over_to_the_schedule(toy_data, schedule):
    spec = SourceSpec([toy_data], cameras=["front"])
    network = ltfv6_navsim(**TOY_LTFV6)
    data = wired(network, train={"navsim": spec}, schedule=MixingSchedule({0: {"navsim": 2}}, 2), steps_per_epoch=4)
    module = DrivingModule(network, lr=1e-3, lr_schedule=schedule, warmup_steps=4, data=data)
    lrs = fit_recording(module, data, 2).lrs
    assert lrs[:4] == pytest.approx([2.5e-4, 5e-4, 7.5e-4, 1e-3])  # lr / 4 on the first step, lr on the 4th
    if schedule == "constant":
        assert lrs[4:] == pytest.approx([1e-3] * 4)
    else:  # one cosine over the 4 steps left, from lr towards 0
        assert lrs[4:] == pytest.approx([1e-3 * (1 + math.cos(math.pi * k / 4)) / 2 for k in range(4)])


class KeyRecorder(L.Callback):
    """The sample keys of every training batch, per epoch: ``keys[epoch][step]`` is a sorted list."""

    def __init__(self) -> None:
        self.keys: dict[int, list[list[str]]] = {}

    def on_train_batch_start(self, trainer, pl_module, batch, batch_idx) -> None:
        keys = sorted(key for b in batch.values() for key in b["__key__"])
        self.keys.setdefault(trainer.current_epoch, []).append(keys)


def fit_keys(data: str, epochs: int, root=None, resume: str | None = None) -> dict[int, list[list[str]]]:
    """Fit a tiny model and return the keys it trained on; ``root`` keeps a last.ckpt, ``resume`` restarts from one."""
    spec = SourceSpec([data], cameras=["front"])
    network = mixed_ltfv6()
    datamodule = wired(
        network,
        train={"carla": spec, "navsim": spec},
        schedule=MixingSchedule.constant({"carla": 1, "navsim": 1}, 4),
        steps_per_epoch=3,
        shuffle_buffer=8,
    )
    recorder = KeyRecorder()
    callbacks: list[L.Callback] = [recorder]
    if root is not None:
        callbacks.append(L.pytorch.callbacks.ModelCheckpoint(dirpath=root, save_last=True))
    trainer = L.Trainer(
        max_epochs=epochs,
        accelerator="cpu",
        logger=False,
        enable_checkpointing=root is not None,
        enable_progress_bar=False,
        enable_model_summary=False,
        callbacks=callbacks,
        **TRAINER_DEFAULTS,
    )
    trainer.fit(DrivingModule(network, lr=1e-3, data=datamodule), datamodule=datamodule, ckpt_path=resume)
    return recorder.keys


def test_same_seed_same_batches_and_a_resumed_fit_goes_on_with_the_same_stream(toy_data, tmp_path, monkeypatch):
    monkeypatch.setenv("PL_GLOBAL_SEED", "7")  # what seed_everything(7) leaves for the data module
    whole = fit_keys(toy_data, epochs=2)
    first = fit_keys(toy_data, epochs=1, root=tmp_path)
    assert first[0] == whole[0]  # the same first 3 batches
    assert whole[1] != whole[0]  # the epoch is part of the seed
    resumed = fit_keys(toy_data, epochs=2, resume=str(tmp_path / "last.ckpt"))
    assert list(resumed) == [1] and resumed[1] == whole[1]
    monkeypatch.setenv("PL_GLOBAL_SEED", "8")
    assert fit_keys(toy_data, epochs=1)[0] != whole[0]


def test_default_root_dir_moves_checkpoints_logs_and_predictions_together(toy_data, tmp_path, monkeypatch, capsys):
    monkeypatch.setattr(sys, "argv", ["lead-s2r"])  # LightningCLI warns when the process has other arguments
    spec = {"paths": [toy_data], "cameras": ["front"]}
    config = {
        "trainer": {
            "accelerator": "cpu",
            "max_epochs": 1,
            "enable_progress_bar": False,
            "enable_model_summary": False,
            "default_root_dir": str(tmp_path / "elsewhere"),
            "callbacks": [
                {"class_path": "lightning.pytorch.callbacks.ModelCheckpoint", "init_args": {"save_last": True}},
                {"class_path": "lead_s2r.training.prediction_writer.PredictionWriter"},
            ],
        },
        "model": {
            "model": {
                "class_path": "lead_s2r.models.lead_driver.LeadDriver",
                "init_args": {"config": {**TOY_LTFV6, **LTFV6_SWITCHES}},
            }
        },
        "data": {"train": {"navsim": spec}, "predict": {"navsim": spec}, "steps_per_epoch": 1, "shuffle_buffer": 4},
    }
    recipe = tmp_path / "recipe.yaml"
    recipe.write_text(yaml.safe_dump(config))
    root = tmp_path / "root"
    root_option = ["--config", str(recipe), "--trainer.default_root_dir", str(root)]
    run_lightning_cli(["fit", *root_option])
    last = root / "checkpoints" / "last.ckpt"
    assert last.exists()
    summary = capsys.readouterr().out.split("fit done: ")[1].splitlines()  # the end-of-fit summary
    assert summary[0] == "1 epoch(s), 1 optimizer step(s)" and summary[1] == f"  last checkpoint: {last}"
    at = summary.index("  final metrics:")
    assert summary[at + 1].split()[0] == "train/loss"  # the loss first
    version_0 = root / "lightning_logs" / "version_0"
    assert f"  logs: {version_0} (metrics.csv, config.yaml)" in summary
    assert bool(list(version_0.glob("events.out.tfevents.*"))) == tensorboard_installed()  # beside metrics.csv
    run_lightning_cli(["predict", *root_option, "--ckpt_path", str(last)])
    assert (root / "lightning_logs" / "version_1" / "predict_config.yaml").exists()  # fit's config.yaml stays alone
    assert not (root / "lightning_logs" / "version_1" / "config.yaml").exists()
    assert len(read_predictions(root / "predictions.parquet")) == 24
    loaded = DrivingModule.load_from_checkpoint(last, map_location="cpu")  # no recipe needed
    assert type(loaded.model) is LeadDriver and loaded.model.config == ltfv6_navsim(**TOY_LTFV6).config
    with (root / "lightning_logs" / "version_0" / "metrics.csv").open() as file:
        logged = [row["train/batch_size/navsim"] for row in csv.DictReader(file)]
    assert [size for size in logged if size] == ["8.0"]  # the epoch's per-rank batch size of the source
    assert not (tmp_path / "elsewhere").exists()


def test_a_configured_logger_comes_after_the_csv_logs_and_false_keeps_logging_off(tmp_path):
    from lightning.pytorch.loggers import CSVLogger, TensorBoardLogger

    from lead_s2r.training.feedback import run_loggers

    assert run_loggers(False, tmp_path) is False
    defaults = run_loggers(True, tmp_path)
    assert [type(logger) for logger in defaults] == [CSVLogger] + [TensorBoardLogger] * tensorboard_installed()
    board = TensorBoardLogger(tmp_path / "elsewhere")  # as an overlay would add W&B's
    added = run_loggers(board, tmp_path)
    assert isinstance(added[0], CSVLogger) and added[-1] is board and len(added) == 2
    own = CSVLogger(tmp_path / "own")
    assert run_loggers([own], tmp_path) == [own]
