"""LightningModule: loss masking per source, overfitting, init_from, bf16 fit, validation ADE/FDE, predictions."""

import itertools

import lightning as L
import numpy as np
import pytest
import torch
from batches import random_batch
from tiny_models import TINY
from torch.utils.data import DataLoader

from lead_s2r.errors import UserError
from lead_s2r.models.input_spec import input_spec
from lead_s2r.models.lead_driver import LeadDriver, ltfv6_navsim, ltfv6_wod, tfv6
from lead_s2r.training import losses
from lead_s2r.training.loss_table import task_loss
from lead_s2r.training.masking import SIM_TO_REAL, active_tasks
from lead_s2r.training.module import DrivingModule, model_spec

#: LEAD's CARLA perception heads of a sim-to-real network (its CARLA heads beside NAVSIM's).
PERCEPTION_MODULES = ("network.bev_semantic_decoder", "network.center_net_decoder", "network.semantic_decoder")
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
    driver = ltfv6_navsim(**TINY, use_carla_data=True)
    module = DrivingModule(driver)  # default supervise = sim-to-real
    terms = step(module, {"carla": random_batch(driver, 2, "carla")})
    assert {t.split("/")[1] for t in terms} == {"bev_semantic", "lead_boxes", "semantic"}
    assert grad_norm(driver.network.planning_decoder) == 0.0
    assert all(grad_norm(driver.get_submodule(m)) > 0 for m in PERCEPTION_MODULES)


def test_sim_to_real_wod_batch_gives_no_perception_gradient():
    driver = ltfv6_wod(**TINY, use_carla_data=True)
    module = DrivingModule(driver)
    terms = step(module, {"wod": random_batch(driver, 2, "wod")})
    assert set(terms) == {"wod/waypoints"}
    assert grad_norm(driver.network.semantic_decoder) == 0.0
    assert grad_norm(driver.network.planning_decoder) > 0


@pytest.mark.parametrize("sources", [s for n in (1, 2) for s in itertools.combinations(("carla", "navsim"), n)])
def test_every_source_mix_trains(sources):
    driver = ltfv6_navsim(**TINY, use_carla_data=True)
    module = DrivingModule(driver, supervise=EVERYTHING)
    terms = step(module, {s: random_batch(driver, 2, s) for s in sources})
    assert {t.split("/")[0] for t in terms} == set(sources)
    assert all(torch.isfinite(v) for v, _ in terms.values())
    assert grad_norm(driver.network.backbone) > 0


def test_loss_term_is_sample_weighted_mean_over_sources():
    driver = ltfv6_navsim(**TINY, use_carla_data=True)
    module = DrivingModule(driver, supervise={"navsim": ["waypoints"], "carla": ["waypoints"]}).eval()
    batch = {"navsim": random_batch(driver, 1, "navsim"), "carla": random_batch(driver, 3, "carla")}
    total, terms = module.compute_losses(batch)
    mean = (terms["navsim/waypoints"][0] * 1 + terms["carla/waypoints"][0] * 3) / 4
    torch.testing.assert_close(total, module.loss_weights["waypoints"] * mean)  # LEAD's normalised weight


def test_supervise_errors_name_the_problem():
    model = ltfv6_wod(**TINY)
    batch = random_batch(model, 1, "wod")
    with pytest.raises(ValueError, match="'flying'"):
        active_tasks("wod", batch, model.tasks("wod"), {"wod": ["flying"]})
    with pytest.raises(ValueError, match="'depth'"):
        active_tasks("wod", batch, model.tasks("wod"), {"wod": ["depth"]})
    with pytest.raises(ValueError, match="'route'"):
        active_tasks("wod", batch, model.tasks("wod"), {"wod": ["route"]})
    carla = tfv6(**TINY)
    unlabelled = {k: v for k, v in random_batch(carla, 1, "carla").items() if not k.startswith("route")}
    with pytest.raises(KeyError, match="'route'"):
        active_tasks("carla", unlabelled, carla.tasks("carla"), {"carla": ["route"]})
    assert active_tasks("wod", batch, model.tasks("wod"), SIM_TO_REAL) == {"waypoints"}
    with pytest.raises(ValueError, match="unknown tasks"):
        DrivingModule(model, loss_weights={"wayponts": 1.0})


def test_overfits_eight_samples():
    torch.manual_seed(0)
    driver = ltfv6_navsim(**TINY, embd_pdrop=0.0, attn_pdrop=0.0, resid_pdrop=0.0)
    module = DrivingModule(driver, supervise={"navsim": ["waypoints"]}, lr=2e-3, weight_decay=0.0)
    batch = {"navsim": random_batch(driver, 8, "navsim")}
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
    # pre-train: CARLA planning and perception for a WOD-E2E network with CARLA heads, bf16-mixed
    pre_driver = ltfv6_wod(**TINY, use_carla_data=True)
    pre = DrivingModule(pre_driver, supervise=EVERYTHING)
    batches = [{"carla": random_batch(pre_driver, 2, "carla")} for _ in range(2)]
    fit = trainer(max_steps=2, precision="bf16-mixed")
    fit.fit(pre, loader(batches))
    ckpt = tmp_path / "pre.ckpt"
    fit.save_checkpoint(ckpt)

    # fine-tune: no CARLA heads -> every matching tensor loads, the dropped heads reported
    fine_driver = ltfv6_wod(**TINY)
    fine = DrivingModule(fine_driver, init_from=str(ckpt))
    report = fine.init_report
    pre_state, fine_state = pre.model.state_dict(), fine.model.state_dict()
    shared = [k for k in fine_state if k in pre_state and pre_state[k].shape == fine_state[k].shape]
    assert sorted(report.loaded) == sorted(shared)
    assert all(torch.equal(fine_state[k], pre_state[k]) for k in shared)
    assert any(k.startswith("network.semantic_decoder") for k in report.unexpected)
    assert report.missing == [k for k in fine_state if k not in pre_state]
    assert "init_from: loaded" in report.summary()

    # validation ADE / FDE per dataset equals a hand computation
    val_batch = {"wod": random_batch(fine_driver, 3, "wod")}
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
    assert type(loaded.model) is LeadDriver and loaded.model.config == fine_driver.config
    assert loaded.hparams.init_from is None and loaded.supervise == fine.supervise
    for key, value in fine.state_dict().items():
        torch.testing.assert_close(loaded.state_dict()[key], value, rtol=0, atol=0)


def test_a_network_without_a_dataclass_config_is_not_described():
    assert model_spec(torch.nn.Linear(2, 2)) is None
    spec = model_spec(ltfv6_navsim(**TINY))
    assert spec["class_path"] == "lead_s2r.models.lead_driver.LeadDriver"
    assert spec["init_args"]["config"]["camera_tile_size"] == [32, 32]  # JSON types: a weights_only load


def test_init_from_rejects_missing_and_foreign_files(tmp_path):
    with pytest.raises(UserError, match=r"init_from: no checkpoint at .*nope\.ckpt"):
        DrivingModule(ltfv6_wod(**TINY), init_from=str(tmp_path / "nope.ckpt"))
    reshaped = tmp_path / "reshaped.ckpt"  # every name of the model, no shape: nothing would load
    torch.save({k: torch.zeros(1, 1, 1, 1, 1) for k in ltfv6_wod(**TINY).state_dict()}, reshaped)
    with pytest.raises(UserError, match=r"reshaped\.ckpt: no tensor matches the model's shape"):
        DrivingModule(ltfv6_wod(**TINY), init_from=str(reshaped))
    bad = tmp_path / "bad.ckpt"
    torch.save({"state_dict": {"a": "not a tensor"}}, bad)
    with pytest.raises(UserError, match=r"bad\.ckpt holds no state dict of tensors"):
        DrivingModule(ltfv6_wod(**TINY), init_from=str(bad))


@pytest.mark.parametrize(
    ("image_size", "camera"),
    [
        ((384, 1152), {"camera_tile_size": None}),
        ((128, 384), {"camera_tile_size": [128, 128]}),
        ((128, 384), {"camera_tile_size": [128, 128], "used_cameras": [False, True, True]}),
    ],
)
def test_perception_losses_on_the_lean_batch_equal_the_full_size_int64_labels(tmp_path, image_size, camera):
    """The loader's uint8 labels (255 = ignore) and 1/4-size depth give the losses of the old contract (int64 labels
    with -1 = ignore, depth resampled to the image on the CPU: the reference definitions in test_transform_speed) on
    generated frames, one of them without labels (collation's filler)."""
    from test_transform_speed import reference_camera

    from lead_s2r.data.collate import collate
    from lead_s2r.data.transforms import SourceTransform
    from lead_s2r.registry import get_adapter
    from lead_s2r.synthetic.carla_lead import generate

    generate(tmp_path, count=1, seed=7, frames=2)
    adapter = get_adapter("carla_lead")
    samples = [s for log in adapter.list_logs(tmp_path) for s in adapter.iter_samples(log)]
    driver = tfv6(**{**TINY, **camera})
    spec = input_spec(driver.config)
    assert spec.image_size == image_size
    transform = SourceTransform("carla", spec)
    unlabelled = {k: v for k, v in samples[1].items() if k not in ("bev_semantic", "semantic_carla_mosaic")}
    lean = collate([transform(samples[0]), transform(unlabelled)])
    bev = lean["bev_semantic"][0].numpy().astype(np.int64)  # LEAD's classes with the boxes drawn in, as int64
    bev[bev == 255] = -1
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

    module = DrivingModule(driver)
    torch.manual_seed(0)
    h, w = image_size[0] // 8, driver.camera_select(torch.zeros(image_size)).shape[-1] // 8
    pred = {
        "semantic": torch.randn(2, spec.semantic_classes["carla"], h, w),
        "depth": torch.rand(2, h, w) * spec.max_depth,
        "bev_semantic": torch.randn(2, spec.bev_semantic_classes["carla"], *lean["bev_semantic"].shape[-2:]),
    }
    for task in ("semantic", "depth", "bev_semantic"):
        before, after = task_loss(task, pred, old, module.model), task_loss(task, pred, lean, module.model)
        assert before > 0
        torch.testing.assert_close(after, before, rtol=1e-6, atol=0.0, msg=task)
