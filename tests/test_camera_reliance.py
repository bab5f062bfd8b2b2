"""Camera reliance: how far a model's plan moves when the samples of a batch trade camera images."""

import json
import sys

import pytest
import torch
import yaml
from batches import random_batch
from tiny_models import LTFV6_SWITCHES, TOY_LTFV6

from lead_s2r.models.ego_mlp import EgoStatusMLP
from lead_s2r.models.lead_driver import ltfv6_navsim
from lead_s2r.predictions import read_predictions
from lead_s2r.training import camera_reliance
from lead_s2r.training.cli import run_lightning_cli

pytestmark = pytest.mark.usefixtures("one_thread")


@pytest.fixture(scope="module")
def tfv6():
    torch.manual_seed(0)
    driver = ltfv6_navsim(**TOY_LTFV6).eval()
    return driver, random_batch(driver, 4, "navsim")


def test_each_sample_takes_the_next_samples_cameras_and_keeps_everything_else(tfv6):
    _, batch = tfv6
    swapped = camera_reliance.with_swapped_cameras(batch)
    assert torch.equal(swapped["rgb"], batch["rgb"][[1, 2, 3, 0]])
    assert all(swapped[key] is batch[key] for key in batch if key != "rgb")


def test_a_camera_model_moves_with_its_images_and_not_when_they_are_all_the_same(tfv6):
    model, batch = tfv6
    shifts = camera_reliance.camera_shift(model, batch, "navsim")
    assert shifts.shape == (4,) and (shifts > 1e-3).all()  # an untrained LTFv6 reads its cameras
    same = dict(batch, rgb=batch["rgb"][:1].expand_as(batch["rgb"]).clone())
    assert camera_reliance.camera_shift(model, same, "navsim").abs().max() == 0  # nothing to trade


def test_a_status_model_does_not_move(tfv6):
    _, batch = tfv6
    assert camera_reliance.camera_shift(EgoStatusMLP().eval(), batch, "navsim").abs().max() == 0


def test_predict_writes_the_mean_shift_of_every_camera_sample_beside_the_predictions(toy_data, tmp_path, monkeypatch):
    monkeypatch.setattr(sys, "argv", ["lead-s2r"])  # LightningCLI warns when the process has other arguments
    spec = {"paths": [toy_data], "cameras": ["front"]}
    callbacks = [
        {"class_path": "lead_s2r.training.prediction_writer.PredictionWriter"},
        {"class_path": "lead_s2r.training.camera_reliance.CameraReliance"},
    ]
    config = {**TOY_LTFV6, **LTFV6_SWITCHES}
    model = {"class_path": "lead_s2r.models.lead_driver.LeadDriver", "init_args": {"config": config}}
    config = {
        "trainer": {"accelerator": "cpu", "enable_progress_bar": False, "callbacks": callbacks},
        "model": {"model": model},
        "data": {"train": {"navsim": spec}, "predict": {"navsim": spec}, "eval_batch_size": 5},
    }
    recipe = tmp_path / "recipe.yaml"
    recipe.write_text(yaml.safe_dump(config))
    run_lightning_cli(["predict", "--config", str(recipe), "--trainer.default_root_dir", str(tmp_path), "--untrained"])
    predicted = read_predictions(tmp_path / "predictions.parquet")
    summary = json.loads((tmp_path / camera_reliance.FILENAME).read_text())
    assert list(summary) == ["toy"]  # keyed by the samples' dataset, not the source name
    # 24 samples in batches of 5: the last batch holds 4, so every sample has another's images to take
    assert summary["toy"]["samples"] == len(predicted) == 24
    assert summary["toy"]["mean_m"] > 1e-3
