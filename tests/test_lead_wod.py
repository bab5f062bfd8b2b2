"""LEAD's CARLA TFv6 fine-tuned on WOD-E2E: a LEAD checkpoint folder as ``init_from`` of the WOD-E2E recipe loads every
tensor whose name and shape match, reports the heads that are new, dropped or reshaped and the config fields behind
them, then trains and predicts WOD-E2E's 10 waypoints at 2 Hz."""

import logging
import sys
from pathlib import Path

import numpy as np
import pytest
import torch
import yaml

from lead_s2r.convert import convert
from lead_s2r.errors import UserError
from lead_s2r.models import lead
from lead_s2r.models.lead_config import LeadConfig
from lead_s2r.models.lead_driver import LeadDriver
from lead_s2r.models.lead_frame import command_one_hot
from lead_s2r.predictions import read_predictions
from lead_s2r.schema import Command
from lead_s2r.synthetic import wod_e2e
from lead_s2r.training.cli import run_lightning_cli
from lead_s2r.training.weights import load_matching
from lead_s2r_adapters.wod_e2e import WodE2EAdapter

pytestmark = pytest.mark.usefixtures("one_thread")

RECIPES = Path(__file__).parents[1] / "recipes"
RECIPE = RECIPES / "wod" / "ltfv6.yaml"
OVERLAYS = [RECIPES / "smoke" / "twin.yaml", RECIPES / "smoke" / "twin_lead.yaml"]


def model_fields(path: Path) -> dict:
    return yaml.safe_load(path.read_text())["model"]["model"]["init_args"]["config"]


#: The smoke overlay's toy sizes, shared by the CARLA checkpoint and the WOD-E2E network as by LEAD's real pair.
TINY = model_fields(OVERLAYS[1])


@pytest.fixture(scope="module")
def carla_checkpoint(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """A LEAD CARLA TFv6 folder (config.json + model_0000.pth) as LEAD's training writes it, at toy size."""
    torch.manual_seed(0)
    return lead.export_checkpoint(
        lead.model_from_config({**TINY, "use_planning_decoder": True}), tmp_path_factory.mktemp("tfv6")
    )


def wod_driver() -> LeadDriver:
    return LeadDriver(LeadConfig.from_json(model_fields(RECIPE) | TINY))


def test_wod_intent_is_one_hot_in_wods_enum_order_when_the_command_token_is_on() -> None:
    config = LeadConfig.from_json(model_fields(RECIPE) | {"use_discrete_command": True})
    commands = torch.tensor([int(c) for c in (Command.LEFT, Command.UNKNOWN, Command.STRAIGHT, Command.RIGHT)])
    assert command_one_hot(commands, config).tolist() == [[0, 0, 1, 0], [1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 0, 1]]
    assert not LeadConfig.from_json(model_fields(RECIPE)).use_discrete_command  # LEAD's WOD-E2E default: no token


def test_init_from_a_lead_folder_loads_every_matching_tensor_and_names_the_rest(carla_checkpoint: Path) -> None:
    source = torch.load(carla_checkpoint / "model_0000.pth", weights_only=True)
    driver = wod_driver()
    target = {k.removeprefix("network."): v.shape for k, v in driver.state_dict().items()}
    report = load_matching(driver, carla_checkpoint)
    matching = [k for k, v in source.items() if k in target and target[k] == v.shape]
    assert sorted(k.removeprefix("network.") for k in report.loaded) == sorted(matching)
    state = driver.network.state_dict()
    assert all(torch.equal(state[k], source[k]) for k in matching)
    assert any(k.startswith("backbone.image_encoder.") for k in matching)  # the encoders and the planner's body carry
    assert "planning_decoder.transformer_decoder.layers.0.linear1.weight" in matching
    mismatched = {k.removeprefix("network.") for k in report.mismatched}
    assert "planning_decoder.query" in mismatched  # route 10 + waypoints 8 + speed 1 -> waypoints 10
    assert "planning_decoder.planning_context_encoder.status_pos_embedding" in mismatched  # speed token only
    assert any(k.startswith("backbone.lidar_encoder.") for k in mismatched)  # LTF: a 2-channel coordinate grid
    unexpected = {k.removeprefix("network.").split(".")[0] for k in report.unexpected}
    assert {"radar_detector", "center_net_decoder", "semantic_decoder", "depth_decoder"} <= unexpected
    assert {k.removeprefix("network.planning_decoder.").split(".")[0] for k in report.unexpected} >= {
        "route_decoder",
        "target_speed_decoder",
    }
    assert report.missing == []  # nothing in the WOD network is new: its other tensors are reshaped (mismatched)
    changes = report.config_changes
    assert changes["LTF"] == (False, True) and changes["use_waymo_e2e_data"] == (False, True)
    assert changes["target_dataset"] == ("CARLA_LEADERBOARD2_3CAMERAS", "WAYMO_E2E_2025_3CAMERAS")
    assert changes["num_way_points_prediction"] == (8, 10) and changes["use_discrete_command"] == (True, False)
    assert "LEAD config changes: " in report.summary() and "planning_decoder.query" in report.summary()


def test_an_ensemble_folder_asks_for_one_member(carla_checkpoint: Path, tmp_path: Path) -> None:
    folder = tmp_path / "ensemble"
    folder.mkdir()
    (folder / "config.json").write_text((carla_checkpoint / "config.json").read_text())
    for seed in (0, 1):
        (folder / f"model_0030_{seed}.pth").write_bytes((carla_checkpoint / "model_0000.pth").read_bytes())
    with pytest.raises(UserError, match=r"2 weight files.*model_0030_0\.pth"):
        load_matching(wod_driver(), folder)
    report = load_matching(wod_driver(), folder / "model_0030_1.pth")  # one member, named: the folder's config too
    assert report.loaded and report.config_changes["LTF"] == (False, True)


@pytest.fixture(scope="module")
def wod_data(tmp_path_factory: pytest.TempPathFactory) -> Path:
    raw, out = tmp_path_factory.mktemp("wod_raw"), tmp_path_factory.mktemp("wod")
    wod_e2e.generate(raw, count=1, seed=3)
    assert convert(WodE2EAdapter(), raw, out).ok
    return out


def test_fine_tuning_leads_carla_tfv6_on_wod_trains_and_predicts_ten_waypoints_at_2_hz(
    carla_checkpoint: Path, wod_data: Path, tmp_path: Path, monkeypatch: pytest.MonkeyPatch, caplog
) -> None:
    monkeypatch.setattr(sys, "argv", ["lead-s2r"])
    data = [f"--data.{stage}.wod.paths=[{wod_data}]" for stage in ("train", "val", "predict")]
    args = ["--config", str(RECIPE), *(arg for overlay in OVERLAYS for arg in ("--config", str(overlay))), *data]
    args += ["--trainer.default_root_dir", str(tmp_path / "run"), "--trainer.logger=false"]
    args += ["--trainer.callbacks=[]", "--data.val=null"]  # no ScoringCallback: the toy data has few rated frames
    with caplog.at_level(logging.INFO):
        run_lightning_cli(["fit", *args, f"--model.init_from={carla_checkpoint}"])
    assert "LEAD config changes: " in caplog.text and "mismatched" in caplog.text
    checkpoint = next((tmp_path / "run").rglob("*.ckpt"))
    trained = torch.load(checkpoint, map_location="cpu", weights_only=True)
    assert trained["global_step"] == 4  # the smoke overlay's 2 epochs of 2 steps
    output = tmp_path / "predictions.parquet"
    writer = "lead_s2r.training.prediction_writer.PredictionWriter"
    predict = ["predict", *args, "--ckpt_path", str(checkpoint), f"--trainer.callbacks+={writer}"]
    run_lightning_cli([*predict, f"--trainer.callbacks.output={output}"])
    predictions = read_predictions(output)
    assert predictions and all(p.xy.shape == (10, 2) and np.isfinite(p.xy).all() for p in predictions)
    np.testing.assert_allclose(predictions[0].t, 0.5 * np.arange(1, 11))
