"""LightningModule: loss masking per source, overfitting, init_from, bf16 fit, validation ADE/FDE, predictions."""

import itertools
import json
import shutil
from dataclasses import replace

import lightning as L
import numpy as np
import pytest
import torch
from batches import random_batch
from tiny_models import TINY
from torch.utils.data import DataLoader

from lead_s2r.data.datamodule import DriveDataModule, SourceSpec
from lead_s2r.data.mixing import MixingSchedule
from lead_s2r.errors import UserError
from lead_s2r.models.config import TrajectoryGrid, ltfv6_config, tfv6_config
from lead_s2r.models.input_spec import input_spec
from lead_s2r.models.tfv6 import TFv6
from lead_s2r.training import losses
from lead_s2r.training.cli import TRAINER_DEFAULTS
from lead_s2r.training.loss_table import task_loss
from lead_s2r.training.masking import SIM_TO_REAL, active_tasks
from lead_s2r.training.module import DrivingModule, model_spec

PERCEPTION_MODULES = ("bev_semantic", "boxes", "perspective", "radar.out")
EVERYTHING = {"carla": ["planning", "perception"], "navsim": ["planning", "perception"], "wod": ["planning"]}


pytestmark = pytest.mark.usefixtures("one_thread")


def grad_norm(module: torch.nn.Module) -> float:
    return sum(float(p.grad.abs().sum()) for p in module.parameters() if p.grad is not None)


def step(module: DrivingModule, batch: dict) -> dict:
    module.model.zero_grad()
    total, terms = module.compute_losses(batch)
    total.backward()
    return terms


def test_sim_to_real_carla_batch_gives_no_planning_gradient():
    config = tfv6_config(**TINY)
    module = DrivingModule(TFv6(config))  # default supervise = sim-to-real
    terms = step(module, {"carla": random_batch(config, 2, "carla")})
    assert {t.split("/")[1] for t in terms} == {"bev_semantic", "boxes", "depth", "semantic", "radar"}
    assert grad_norm(module.model.planner) == 0.0
    assert all(grad_norm(module.model.get_submodule(m)) > 0 for m in PERCEPTION_MODULES)


def test_sim_to_real_wod_batch_gives_no_perception_gradient():
    config = tfv6_config(**TINY)
    module = DrivingModule(TFv6(config))
    terms = step(module, {"wod": random_batch(config, 2, "wod")})
    assert set(terms) == {"wod/waypoints"}
    assert all(grad_norm(module.model.get_submodule(m)) == 0.0 for m in PERCEPTION_MODULES)
    assert grad_norm(module.model.planner) > 0


@pytest.mark.parametrize(
    "sources", [s for n in (1, 2, 3) for s in itertools.combinations(("carla", "navsim", "wod"), n)]
)
def test_every_source_mix_trains(sources):
    config = tfv6_config(**TINY)
    module = DrivingModule(TFv6(config), supervise=EVERYTHING)
    terms = step(module, {s: random_batch(config, 2, s) for s in sources})
    assert {t.split("/")[0] for t in terms} == set(sources)
    assert all(torch.isfinite(v) for v, _ in terms.values())
    assert grad_norm(module.model.backbone) > 0


def test_loss_term_is_sample_weighted_mean_over_sources():
    config = tfv6_config(**TINY, decoder_dropout=0.0, fusion_dropout=0.0)
    module = DrivingModule(TFv6(config), supervise={"navsim": ["waypoints"], "wod": ["waypoints"]}).eval()
    batch = {"navsim": random_batch(config, 1, "navsim"), "wod": random_batch(config, 3, "wod")}
    total, terms = module.compute_losses(batch)
    expected = (terms["navsim/waypoints"][0] * 1 + terms["wod/waypoints"][0] * 3) / 4
    torch.testing.assert_close(total, expected)


def test_supervise_errors_name_the_problem():
    config = tfv6_config(**TINY)
    model = TFv6(config)
    batch = random_batch(config, 1, "wod")
    with pytest.raises(ValueError, match="'flying'"):
        active_tasks("wod", batch, model.tasks("wod"), {"wod": ["flying"]})
    with pytest.raises(ValueError, match="'depth'"):
        active_tasks("wod", batch, model.tasks("wod"), {"wod": ["depth"]})
    with pytest.raises(KeyError, match="'route'"):
        active_tasks("wod", batch, model.tasks("wod"), {"wod": ["route"]})
    assert active_tasks("wod", batch, model.tasks("wod"), SIM_TO_REAL) == {"waypoints"}
    with pytest.raises(ValueError, match="unknown tasks"):
        DrivingModule(model, loss_weights={"wayponts": 1.0})


def test_overfits_eight_samples():
    torch.manual_seed(0)
    config = ltfv6_config(**TINY, decoder_dropout=0.0, fusion_dropout=0.0)
    module = DrivingModule(TFv6(config), supervise={"navsim": ["waypoints"]}, lr=2e-3, weight_decay=0.0)
    batch = {"navsim": random_batch(config, 8, "navsim")}
    optimizer = module.configure_optimizers()
    losses = []
    for _ in range(400):
        optimizer.zero_grad()
        total, _ = module.compute_losses(batch)
        total.backward()
        optimizer.step()
        losses.append(total.item())
    print(f"planning loss {losses[0]:.3f} -> {losses[-1]:.4f}")
    assert losses[-1] < 0.1 * losses[0]


def loader(batches: list[dict]) -> DataLoader:
    return DataLoader(batches, batch_size=None, collate_fn=lambda b: b)


def trainer(**kwargs) -> L.Trainer:
    return L.Trainer(
        accelerator="cpu",
        logger=False,
        enable_checkpointing=False,
        enable_progress_bar=False,
        enable_model_summary=False,
        **kwargs,
    )


def test_bf16_fit_init_from_round_trip_validate_predict(tmp_path):
    # pre-train: CARLA + NAVSIM perception and planning, bf16-mixed
    pre_config = tfv6_config(**TINY)
    pre = DrivingModule(TFv6(pre_config), supervise=EVERYTHING)
    batches = [{s: random_batch(pre_config, 2, s) for s in ("carla", "navsim")} for _ in range(2)]
    fit = trainer(max_steps=2, precision="bf16-mixed")
    fit.fit(pre, loader(batches))
    ckpt = tmp_path / "pre.ckpt"
    fit.save_checkpoint(ckpt)

    # fine-tune: NAVSIM-only heads, a WOD grid, no CARLA heads -> every matching tensor loads, new ones reported
    fine_config = tfv6_config(
        **TINY, bev_semantic_classes={"navsim": 7}, box_classes={"navsim": 1}, semantic_classes={}, depth_sources=()
    )
    fine = DrivingModule(TFv6(fine_config), init_from=str(ckpt))
    report = fine.init_report
    pre_state, fine_state = pre.model.state_dict(), fine.model.state_dict()
    shared = [k for k in fine_state if k in pre_state and pre_state[k].shape == fine_state[k].shape]
    assert sorted(report.loaded) == sorted(shared)
    assert all(torch.equal(fine_state[k], pre_state[k]) for k in shared)
    assert any(k.startswith("bev_semantic.carla") for k in report.unexpected)
    assert report.missing == [k for k in fine_state if k not in pre_state]
    assert "init_from: loaded" in report.summary()

    # validation ADE / FDE per dataset equals a hand computation
    val_batch = {"wod": random_batch(fine_config, 3, "wod")}
    evaluation = trainer()
    metrics = evaluation.validate(fine, loader([val_batch]), verbose=False)[0]
    fine.eval()
    with torch.no_grad():
        pred = fine.model(val_batch["wod"], "wod", {"waypoints"})["waypoints"]
    err = (pred - val_batch["wod"]["waypoints"]).norm(dim=-1)
    assert metrics["val/wod/ade"] == pytest.approx(err.mean().item(), rel=1e-5)
    assert metrics["val/wod/fde"] == pytest.approx(err[:, -1].mean().item(), rel=1e-5)
    assert not any(name.startswith("val/wod/waypoints") for name in metrics)  # loss terms only when asked for
    fine.hparams.log_val_losses = True
    metrics = evaluation.validate(fine, loader([val_batch]), verbose=False)[0]
    assert metrics["val/wod/waypoints"] == pytest.approx(losses.waypoint_loss({"waypoints": pred}, val_batch["wod"]))

    # predictions: ISO ego frame poses on the source's own time grid
    out = trainer().predict(fine, loader([val_batch]))[0]["wod"]
    assert out["t"].tolist() == pytest.approx([0.5 * (i + 1) for i in range(10)])
    assert out["xy"].shape == (3, 10, 2) and out["yaw"].shape == (3, 10)
    assert out["key"] == val_batch["wod"]["__key__"]
    torch.testing.assert_close(out["xy"], pred)

    # the fine-tuned checkpoint rebuilds its module alone, without init_from's file (gone by now)
    evaluation.save_checkpoint(tmp_path / "fine.ckpt")
    ckpt.unlink()
    loaded = DrivingModule.load_from_checkpoint(tmp_path / "fine.ckpt", map_location="cpu")
    assert type(loaded.model) is TFv6 and loaded.model.config == fine_config
    assert loaded.hparams.init_from is None and loaded.supervise == fine.supervise
    for key, value in fine.state_dict().items():
        torch.testing.assert_close(loaded.state_dict()[key], value, rtol=0, atol=0)


def test_a_network_without_a_dataclass_config_is_not_described():
    assert model_spec(torch.nn.Linear(2, 2)) is None
    spec = model_spec(TFv6(ltfv6_config(**TINY)))
    assert spec["class_path"] == "lead_s2r.models.tfv6.TFv6"
    assert spec["init_args"]["config"]["trajectory_grids"]["navsim"] == [8, 0.5]  # JSON types: a weights_only load


def test_init_from_rejects_missing_and_foreign_files(tmp_path):
    config = tfv6_config(**TINY)
    with pytest.raises(UserError, match=r"init_from: no checkpoint at .*nope\.ckpt"):
        DrivingModule(TFv6(config), init_from=str(tmp_path / "nope.ckpt"))
    reshaped = tmp_path / "reshaped.ckpt"  # every name of the model, no shape: nothing would load
    torch.save({k: torch.zeros(1, 1, 1, 1, 1) for k in TFv6(config).state_dict()}, reshaped)
    with pytest.raises(UserError, match=r"reshaped\.ckpt: no tensor matches the model's shape"):
        DrivingModule(TFv6(config), init_from=str(reshaped))
    bad = tmp_path / "bad.ckpt"
    torch.save({"state_dict": {"a": "not a tensor"}}, bad)
    with pytest.raises(UserError, match=r"bad\.ckpt holds no state dict of tensors"):
        DrivingModule(TFv6(config), init_from=str(bad))


def converted_copy(source: str, target, target_points: dict | None) -> str:
    """A copy of a converted folder whose info.json holds ``target_points`` statistics (None: no target points)."""
    shutil.copytree(source, target)
    info = json.loads((target / "info.json").read_text())
    info["statistics"].pop("target_points", None)
    if target_points is not None:
        info["statistics"]["target_points"] = target_points
    (target / "info.json").write_text(json.dumps(info))
    return str(target)


def test_training_folders_give_the_union_of_their_target_point_ranges(toy_data, tmp_path):
    a = converted_copy(toy_data, tmp_path / "a", {"low": [-5.0, -20.0], "high": [60.0, 20.0]})
    b = converted_copy(toy_data, tmp_path / "b", {"low": [0.0, -30.0], "high": [80.0, 3.0]})
    none = converted_copy(toy_data, tmp_path / "none", None)
    spec = lambda *paths: SourceSpec(list(paths), cameras=["front"])  # noqa: E731
    data = DriveDataModule(train={"carla": spec(a, none), "navsim": spec(b)})
    assert data.target_point_range() == ((-5.0, -30.0), (80.0, 20.0))
    assert DriveDataModule(train={"navsim": spec(none)}).target_point_range() is None


def test_fit_normalises_target_points_by_training_statistics_and_predict_keeps_the_checkpoints(toy_data, tmp_path):
    a = converted_copy(toy_data, tmp_path / "a", {"low": [-5.0, -20.0], "high": [60.0, 20.0]})
    b = converted_copy(toy_data, tmp_path / "b", {"low": [0.0, -3.0], "high": [15.0, 3.0]})
    config = tfv6_config(**TINY, trajectory_grids={"carla": TrajectoryGrid(4, 0.5)}, use_radar=False)
    spec_a, spec_b = SourceSpec([a], cameras=["front"]), SourceSpec([b], cameras=["front"])
    schedule = MixingSchedule.constant({"carla": 1.0}, 2)
    fit_data = DriveDataModule(train={"carla": spec_a}, predict={"carla": spec_a}, schedule=schedule, steps_per_epoch=1)
    module = DrivingModule(TFv6(config), supervise={"carla": ["waypoints"]})
    assert module.model.target_point_range == ((-200.0, -50.0), (200.0, 50.0))  # LEAD's constants until fit
    fit = trainer(max_steps=1, **TRAINER_DEFAULTS)
    fit.fit(module, datamodule=fit_data)
    assert module.model.target_point_range == ((-5.0, -20.0), (60.0, 20.0))
    ckpt = tmp_path / "a.ckpt"
    fit.save_checkpoint(ckpt)
    state = torch.load(ckpt, weights_only=True)["state_dict"]
    assert state["model.planner.status.tp_norm.high"].tolist() == [60.0, 20.0]
    want = trainer().predict(module, datamodule=fit_data)

    # a run whose data has other statistics: prediction still uses the range the checkpoint was trained with
    fresh = DrivingModule(TFv6(config), supervise={"carla": ["waypoints"]})
    other_data = DriveDataModule(train={"carla": spec_b}, predict={"carla": spec_b}, schedule=schedule)
    got = trainer().predict(fresh, datamodule=other_data, ckpt_path=ckpt)
    assert fresh.model.target_point_range == ((-5.0, -20.0), (60.0, 20.0))
    for mine, theirs in zip(got, want, strict=True):
        torch.testing.assert_close(mine["carla"]["xy"], theirs["carla"]["xy"])

    fixed = DrivingModule(TFv6(replace(config, target_point_normalisation="fixed")), supervise={"carla": ["waypoints"]})
    trainer(max_steps=1, **TRAINER_DEFAULTS).fit(fixed, datamodule=fit_data)
    assert fixed.model.target_point_range == ((-200.0, -50.0), (200.0, 50.0))


@pytest.mark.parametrize(
    ("image_size", "camera"),
    [((384, 1152), {}), ((128, 384), {}), ((128, 384), {"camera_tiles": 3, "fov_fraction": 0.5})],
)
def test_perception_losses_on_the_lean_batch_equal_the_full_size_int64_labels(tmp_path, image_size, camera):
    """The loader's uint8 labels (255 = ignore) and 1/4-size depth give the losses of the old contract (int64 labels
    with -1 = ignore, depth resampled to the image on the CPU: the reference definitions in test_transform_speed) on
    generated frames, one of them without labels (collation's filler)."""
    from test_transform_speed import reference_bev_labels, reference_camera

    from lead_s2r.data.collate import collate
    from lead_s2r.data.transforms import SourceTransform
    from lead_s2r.registry import get_adapter
    from lead_s2r.synthetic.carla_lead import generate

    generate(tmp_path, count=1, seed=7, frames=2)
    adapter = get_adapter("carla_lead")
    samples = [s for log in adapter.list_logs(tmp_path) for s in adapter.iter_samples(log)]
    config = tfv6_config(**{**TINY, "image_size": image_size, **camera})
    transform = SourceTransform("carla", input_spec(config))
    unlabelled = {k: v for k, v in samples[1].items() if k not in ("bev_semantic", "semantic_carla_mosaic")}
    lean = collate([transform(samples[0]), transform(unlabelled)])
    bev = reference_bev_labels(samples[0]["bev_semantic"], samples[0]["meta"]["bev"]["pixel_to_ego"], config.bev)
    semantic = reference_camera(transform, samples[0])["semantic"]
    old = dict(
        lean,
        bev_semantic=torch.from_numpy(np.stack([bev, np.full_like(bev, -1)])),
        semantic=torch.from_numpy(np.stack([semantic, np.full_like(semantic, -1)])),
        depth=torch.stack([torch.from_numpy(reference_camera(transform, s)["depth"]) for s in samples]),
    )
    assert lean["depth"].shape[-2:] == (96, 288) and old["depth"].shape[-2:] == image_size
    assert lean["semantic"].dtype == lean["bev_semantic"].dtype == torch.uint8 and old["semantic"].dtype == torch.int64
    assert (lean["semantic"][1] == 255).all() and (lean["bev_semantic"][1] == 255).all()

    module = DrivingModule(TFv6(config))
    torch.manual_seed(0)
    h, w = image_size[0] // 8, module.model.backbone.cameras.output_width(image_size[1]) // 8
    pred = {
        "semantic": torch.randn(2, config.semantic_classes["carla"], h, w),
        "depth": torch.rand(2, h, w) * config.max_depth,
        "bev_semantic": torch.randn(2, config.bev_semantic_classes["carla"], *lean["bev_semantic"].shape[-2:]),
    }
    for task in ("semantic", "depth", "bev_semantic"):
        before, after = task_loss(task, pred, old, module.model), task_loss(task, pred, lean, module.model)
        assert before > 0
        torch.testing.assert_close(after, before, rtol=1e-6, atol=0.0, msg=task)
