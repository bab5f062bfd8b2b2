"""LEAD's networks through our pipeline: the y flip at the one frame boundary, a LEAD checkpoint folder predicting on
converted NAVSIM data that PDMS scores, and a smoke-recipe run exported back to LEAD's format."""

import json
import math
import sys
from pathlib import Path

import numpy as np
import pytest
import torch
import yaml

from lead_s2r.cli import main as cli_main
from lead_s2r.convert import convert
from lead_s2r.data.collate import collate
from lead_s2r.data.lead_centernet import lead_centernet_targets
from lead_s2r.data.lidar import rasterize_lidar
from lead_s2r.models import lead
from lead_s2r.models.input_spec import input_spec
from lead_s2r.models.lead_config import LeadConfig
from lead_s2r.models.lead_driver import LeadDriver
from lead_s2r.models.lead_frame import bev_map_from_lead, from_lead_outputs, to_lead_inputs
from lead_s2r.predictions import read_predictions
from lead_s2r.schema import Command
from lead_s2r.synthetic import navsim as synth
from lead_s2r.synthetic import navsim_map as synth_map
from lead_s2r.training.cli import run_lightning_cli
from lead_s2r.training.module import DrivingModule
from lead_s2r.training.weights import load_matching
from lead_s2r_adapters.navsim import NavsimAdapter

pytestmark = pytest.mark.usefixtures("one_thread")

DATA = Path(__file__).parent / "data" / "lead_tfv6"
TINY = DATA / "tiny_ltfv6_navsim"
RECIPE = Path(__file__).parents[1] / "recipes" / "smoke" / "navsim_lead_ltfv6.yaml"
CARLA = {"use_planning_decoder": True}


def test_a_left_point_arrives_where_lead_puts_left() -> None:
    config = LeadConfig.from_json(CARLA)  # BEV x -32..64, y -40..40 m at 4 px/m: LEAD's raster is 320 x 384
    ours = input_spec(config).bev
    point = np.array([[10.1, 5.1, 0.0]], np.float32)  # 10.1 m ahead, 5.1 m to the LEFT (ISO)
    batch = {
        "rgb": torch.zeros(1, 3, 384, 1152, dtype=torch.uint8),
        "lidar_bev": torch.from_numpy(rasterize_lidar(point, ours))[None, None],
        "speed": torch.tensor([3.0]),
        "acceleration": torch.tensor([[3.0, -4.0]]),
        "command": torch.tensor([int(Command.LEFT)]),
        "target_points": torch.tensor([[[1.0, 0.5], [20.0, 5.0], [40.0, -6.0]]]),
    }
    inputs = to_lead_inputs(batch, config)
    raster = inputs["rasterized_lidar"][0, 0]
    assert raster.shape == (config.lidar_height_pixel, config.lidar_width_pixel) == (320, 384)
    rows, cols = torch.nonzero(raster, as_tuple=True)
    # LEAD: rows run along its y from min_y (left) to max_y (right): y_right = -5.1 -> row floor((40 - 5.1) * 4)
    assert rows.tolist() == [139] and cols.tolist() == [168] and raster[139, 168] == 1 / 5
    assert torch.equal(bev_map_from_lead(inputs["rasterized_lidar"]), batch["lidar_bev"] / 5)  # LEAD maps come back
    assert inputs["target_point"].tolist() == [[20.0, -5.0]]  # LEAD's left is negative y
    assert inputs["target_point_previous"].tolist() == [[1.0, -0.5]]
    assert inputs["target_point_next"].tolist() == [[40.0, 6.0]]
    assert inputs["command"].tolist() == [[1, 0, 0, 0, 0, 0]]  # CARLA RoadOption - 1: LEFT first
    assert inputs["acceleration"].tolist() == [5.0]
    navsim = LeadConfig.from_json(json.loads((TINY / "config.json").read_text()))
    right = to_lead_inputs({**batch, "command": torch.tensor([int(Command.RIGHT)])}, navsim)
    assert right["command"].tolist() == [[0, 0, 1, 0]]  # NAVSIM order: left, straight, right, unknown
    back = from_lead_outputs(
        {"pred_future_waypoints": torch.tensor([[[2.0, 1.5]]]), "pred_headings": torch.tensor([[0.25]])}, "navsim"
    )
    assert back["waypoints"].tolist() == [[[2.0, -1.5]]] and back["headings"].tolist() == [[-0.25]]


@pytest.fixture(scope="module")
def navsim_data(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """One synthetic NAVSIM log, converted (the recipe reads it with every split)."""
    raw = tmp_path_factory.mktemp("lead_navsim_raw")
    synth_map.write_map(raw / "maps")
    logs = {synth.LOGS[0].name: synth.write_log(raw, synth.LOGS[0], np.random.default_rng(0))}
    synth.write_scene_filter(raw / "scene_filters" / "navmini.yaml", logs)
    out = tmp_path_factory.mktemp("lead_navsim")
    adapter = NavsimAdapter(scene_filter=str(raw / "scene_filters" / "navmini.yaml"), maps=str(raw / "maps"))
    assert convert(adapter, raw, out).ok
    return out


def recipe_args(data: Path, root: Path) -> list[str]:
    """The smoke recipe on ``data`` (every split), rooted at ``root``."""
    spec = json.dumps({"paths": [str(data)], "splits": None, "cameras": ["front"]})
    return [
        "--config",
        str(RECIPE),
        "--trainer.default_root_dir",
        str(root),
        f"--data.train.navsim={spec}",
        f"--data.predict.navsim={spec}",
    ]


def test_lead_checkpoint_predicts_in_our_frame_and_pdms_scores_it(navsim_data: Path, tmp_path, monkeypatch) -> None:
    monkeypatch.setattr(sys, "argv", ["lead-s2r"])
    folder = tmp_path / "lead"
    folder.mkdir()
    (folder / "config.json").write_text((TINY / "config.json").read_text())
    state = torch.load(TINY / "model_0000.pth", weights_only=True)
    # every waypoint step 1 m ahead and 0.5 m to LEAD's right; headings step 0.1 rad in LEAD's sign
    state["planning_decoder.wp_decoder.weight"].zero_()
    state["planning_decoder.wp_decoder.bias"].copy_(torch.tensor([1.0, 0.5]))
    state["planning_decoder.heading_decoder.weight"].zero_()
    state["planning_decoder.heading_decoder.bias"].fill_(0.1)
    torch.save(state, folder / "model_0030_0.pth")
    output = tmp_path / "predictions.parquet"
    run_lightning_cli(
        [
            "predict",
            *recipe_args(navsim_data, tmp_path / "run"),
            "--model.model.init_args.config=null",
            f"--model.model.init_args.checkpoint={folder}",
            f"--trainer.callbacks.output={output}",
        ]
    )
    predictions = read_predictions(output)
    assert predictions
    steps = np.arange(1, 9)
    for p in predictions:
        np.testing.assert_allclose(p.t, 0.5 * steps)
        np.testing.assert_allclose(p.xy, np.stack([steps, -0.5 * steps], 1), atol=1e-5)  # LEAD's right: y < 0
        np.testing.assert_allclose(p.yaw, -0.1 * steps, atol=1e-5)
    out = tmp_path / "scores"
    args = ["score", "--metric", "pdms@navsim-1.1", "--predictions", str(output), "--data", str(navsim_data)]
    assert cli_main([*args, "--out", str(out)]) == 0
    aggregates = json.loads((out / "scores.json").read_text())["aggregates"]
    assert aggregates["frames_valid"] == len(predictions) and math.isfinite(aggregates["pdms"])


def test_smoke_recipe_run_exports_to_leads_format(navsim_data: Path, tmp_path, monkeypatch) -> None:
    monkeypatch.setattr(sys, "argv", ["lead-s2r"])
    root = tmp_path / "run"
    run_lightning_cli(["fit", *recipe_args(navsim_data, root)])
    assert cli_main(["export-lead", str(root), "--out", str(tmp_path / "lead")]) == 0
    written = json.loads((tmp_path / "lead" / "config.json").read_text())
    spec = yaml.safe_load(RECIPE.read_text())["model"]["model"]["init_args"]["config"]
    assert {k: written[k] for k in spec} == spec
    assert written["img_vert_anchors"] == 8 and written["lidar_width_pixel"] == 128  # derived values, for LEAD's file
    last = root / "checkpoints" / "last.ckpt"
    assert torch.load(last, map_location="cpu", weights_only=False)["global_step"] == 2  # the recipe's 2 steps ran
    trained = DrivingModule.load_from_checkpoint(last, map_location="cpu").model.network.eval()
    loaded = lead.load_checkpoint(tmp_path / "lead")
    inputs = torch.load(TINY / "inputs.pt", weights_only=True)
    expected, got = lead.forward(trained, inputs), lead.forward(loaded, inputs)
    assert set(got) == set(expected) and all(torch.equal(got[k], expected[k]) for k in expected)
    assert cli_main(["export-lead", str(tmp_path / "nothing"), "--out", str(tmp_path / "x")]) == 2


def test_init_from_a_lead_checkpoint_file() -> None:
    driver = LeadDriver(LeadConfig.from_json(json.loads((TINY / "config.json").read_text())))
    report = load_matching(driver, TINY / "model_0000.pth")
    assert len(report.loaded) == len(driver.state_dict()) == 364
    assert not (report.missing or report.unexpected or report.mismatched)
    inputs = torch.load(TINY / "inputs.pt", weights_only=True)
    expected = lead.forward(lead.load_checkpoint(TINY), inputs)
    got = lead.forward(driver.network.eval(), inputs)
    assert all(torch.equal(got[k], expected[k]) for k in expected)


def test_radar_rows_are_sensor_major_as_lead_lays_them_out() -> None:
    config = LeadConfig.from_json(CARLA)
    radar = torch.tensor([[[10.0, 3.0, 0.5, 2.0, 1.0], [5.0, -1.0, 0.5, -1.0, 3.0], [90.0, 0.0, 0.5, 1.0, 0.0]]])
    valid = torch.tensor([[True, True, True]])
    inputs = to_lead_inputs({"rgb": torch.zeros(1, 3, 4, 4), "speed": torch.zeros(1), "command": torch.zeros(1),
                             "radar": radar, "radar_valid": valid}, config)  # fmt: skip
    lead_radar = inputs["radar"][0]
    assert lead_radar.shape == (300, 5)
    assert lead_radar[:, 4].tolist() == [float(s) for s in range(4) for _ in range(75)]
    assert lead_radar[75].tolist() == [10.0, -3.0, 0.5, 2.0, 1.0]  # sensor 1's first row; left -> negative y
    assert lead_radar[225].tolist() == [5.0, 1.0, 0.5, -1.0, 3.0]
    assert lead_radar[0].tolist() == [0.0, 0.0, 0.0, 0.0, 0.0]  # x = 90 m is off LEAD's BEV: dropped
    assert int((lead_radar[:, :4] != 0).any(1).sum()) == 2


def test_converted_carla_samples_train_every_carla_head_of_a_lead_tfv6(carla_samples) -> None:
    """Converted CARLA samples reach LEAD's TFv6 (LiDAR + radar): planning with target speed, radar detection against
    our radar targets, LEAD's 13-class BEV semantics and 8-class boxes, each loss finite, non-zero and reaching its
    head."""
    from lead_reference import TINY_CARLA

    from lead_s2r.data.transforms import SourceTransform

    driver = LeadDriver(LeadConfig.from_json({**TINY_CARLA, "use_bev_semantic": True}))
    transform = SourceTransform("carla", input_spec(driver.config), cameras=["carla_mosaic"])
    batch = collate([transform(sample) for sample in carla_samples])
    assert batch["rgb"].shape[-2:] == (384, 1152) and batch["lidar_bev"].shape[-2:] == (192, 160)
    tasks = {"waypoints", "route", "target_speed", "radar", "bev_semantic", "lead_boxes"}
    assert driver.tasks("carla") == tasks and driver.grid("carla").dt == 0.25
    assert batch["radar_targets_valid"].any() and batch["target_speed_valid"].all()
    assert batch["bev_semantic"].shape == (3, 192, 160) and int(batch["bev_semantic"].max()) < 13
    assert batch["lead_box_heatmap"].shape == (3, 8, 48, 40) and batch["lead_box_weight"].any()
    module = DrivingModule(driver, supervise={"carla": ["planning", "perception"]})
    total, terms = module.compute_losses({"carla": batch})
    assert set(terms) == {f"carla/{task}" for task in tasks}
    assert all(torch.isfinite(value) and value > 0 for value, _ in terms.values())
    total.backward()
    network = driver.network
    heads = (network.bev_semantic_decoder, network.center_net_decoder.heatmap_head, network.center_net_decoder.wh_head)
    for head in (network.planning_decoder.target_speed_decoder, network.radar_detector.state_decoder, *heads):
        assert any(p.grad is not None and p.grad.abs().sum() > 0 for p in head.parameters())
    with torch.inference_mode():
        out = driver.eval()(batch, "carla")
        lead_out = network(to_lead_inputs(batch, driver.config))
    assert out["waypoints"].shape == (3, 8, 2) and out["route"].shape == (3, 10, 2)
    assert out["bev_semantic"].shape == (3, 13, 192, 160) and out["box_heatmap"].shape == (3, 8, 48, 40)
    radar = lead_out["pred_radar_predictions"]
    assert torch.equal(out["radar_xy"][..., 1], -radar[..., 1]) and torch.equal(out["radar_logit"], radar[..., 3])


def test_a_lead_network_on_some_mosaic_cameras_reads_the_whole_mosaic_and_keeps_its_tiles() -> None:
    from lead_reference import TINY_CARLA

    config = LeadConfig.from_json(
        {**TINY_CARLA, "carla_root": "data/carla_leaderboad2_v10", "used_cameras": [True, True, True] + [False] * 3}
    )
    spec = input_spec(config)
    assert spec.image_size == (384, 2304) and spec.equal_tiles and config.final_image_width == 1152
    driver = LeadDriver(config).eval()
    mosaic = torch.arange(6.0).repeat_interleave(384).expand(1, 3, 384, 2304)  # each pixel holds its tile's id
    assert torch.equal(driver.camera_select(mosaic)[0, 0, 0, ::384], torch.tensor([0.0, 1.0, 2.0]))
    batch = {"rgb": mosaic, "speed": torch.zeros(1), "command": torch.zeros(1), "target_points": torch.zeros(1, 3, 2),
             "lidar_bev": torch.zeros(1, 1, 192, 160), "radar": torch.zeros(1, 0, 5)}  # fmt: skip
    with torch.inference_mode():
        assert driver(batch, "carla")["waypoints"].shape == (1, 8, 2)


def test_mixed_lead_network_trains_navsim_planning_and_carla_perception() -> None:
    """LEAD's mixed training (NAVSIM target + CARLA heads): each source's losses reach the heads LEAD has for it."""
    spec = {**json.loads((TINY / "config.json").read_text()), "use_carla_data": True}
    driver = LeadDriver(LeadConfig.from_json(spec))
    assert driver.tasks("navsim") == {"waypoints", "headings", "bev_semantic", "lead_boxes"}
    # LEAD trains a mixed source's planner outputs on its target's grid; the sim-to-real supervision leaves them out
    carla = {"waypoints", "headings", "semantic", "bev_semantic", "lead_boxes"}
    assert driver.tasks("carla") == carla and driver.tasks("wod") == set()
    assert input_spec(driver.config).trajectory_grids == {"navsim": (8, 0.5), "carla": (8, 0.5)}
    module = DrivingModule(driver, supervise={"navsim": ["planning", "perception"], "carla": ["perception"]})
    g = torch.Generator().manual_seed(0)
    grid = input_spec(driver.config).bev
    boxes = [np.array([[5.0, -3.0, 0, 4.5, 2.0, 1.5, 0.3, 0, 0, 0], [-20.0, 10.0, 0, 5.0, 2.2, 1.5, -2.0, 0, 0, 0]])]
    boxes.append(np.zeros((0, 10)))

    def status(n: int) -> dict[str, torch.Tensor]:
        return {
            "rgb": torch.randint(0, 256, (n, 3, 270, 480), dtype=torch.uint8, generator=g),
            "speed": torch.rand(n, generator=g) * 10,
            "acceleration": torch.randn(n, 2, generator=g),
            "command": torch.tensor([1, 3][:n]),
        }

    batch = {
        "navsim": {
            **status(2),
            "waypoints": torch.randn(2, 8, 2, generator=g),
            "headings": torch.randn(2, 8, generator=g) * 0.1,
            "bev_semantic": torch.randint(0, 7, (2, 128, 128), dtype=torch.uint8, generator=g),
            **collate([lead_centernet_targets(b, np.zeros(len(b)), grid, 1, 12, velocity=False) for b in boxes]),
        },
        "carla": {**status(1), "semantic": torch.randint(0, 10, (1, 270, 480), dtype=torch.uint8, generator=g)},
    }
    total, terms = module.compute_losses(batch)
    assert set(terms) == {
        "navsim/waypoints",
        "navsim/headings",
        "navsim/bev_semantic",
        "navsim/lead_boxes",
        "carla/semantic",
    }
    total.backward()
    network = driver.network
    heads = (network.bev_semantic_decoder_navsim, network.center_net_decoder_navsim, network.semantic_decoder)
    for head in (*heads, network.planning_decoder):
        assert any(p.grad is not None and p.grad.abs().sum() > 0 for p in head.parameters())
    assert all(p.grad is None for p in network.center_net_decoder.parameters())  # no CARLA box labels in this batch
