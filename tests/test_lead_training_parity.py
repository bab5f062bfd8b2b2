"""LEAD's training step: our ``lead.loss`` / ``lead.optimizer`` against LEAD's own training code on the tiny NAVSIM
LTFv6 (tests/data/lead_tfv6/tiny_ltfv6_navsim/training/, copied from the golden folder; TRAINING.md there): every loss
term and the total, every gradient and the parameters after one optimizer step, in eval mode and in train mode with
dropout off (BatchNorm on batch statistics)."""

import json
import shutil
from pathlib import Path

import pytest
import torch
import yaml
from torch import Tensor, nn

from lead_s2r.models import lead
from lead_s2r.models.lead_backbone import SelfAttention
from lead_s2r.models.lead_config import LeadConfig
from lead_s2r.models.lead_driver import LeadDriver
from lead_s2r.models.lead_frame import NAVSIM_COMMAND_INDEX, bev_map_from_lead, flip_y
from lead_s2r.models.lead_loss import loss_weights, visible_bev_pixels
from lead_s2r.training.module import DrivingModule

pytestmark = pytest.mark.usefixtures("one_thread")

TINY = Path(__file__).parent / "data" / "lead_tfv6" / "tiny_ltfv6_navsim"
CASE = TINY / "training"
TOL = 1e-5


def load(path: Path) -> dict[str, Tensor]:
    return torch.load(path, weights_only=True)


def without_dropout(model: nn.Module) -> nn.Module:
    """``model`` in train mode with every dropout probability 0, as LEAD's train_nodropout case was made."""
    model.train()
    for module in model.modules():
        if isinstance(module, nn.Dropout):
            module.p = 0.0
        elif isinstance(module, nn.MultiheadAttention | SelfAttention):
            module.dropout = 0.0
    return model


def loss_and_grads(mode: str) -> tuple[nn.Module, dict[str, Tensor], dict[str, Tensor]]:
    model = lead.load_checkpoint(TINY)
    if mode == "train_nodropout":
        without_dropout(model)
    losses = lead.loss(model, load(TINY / "inputs.pt"), load(CASE / "targets.pt"))
    losses["total"].backward()
    return model, losses, {name: p.grad for name, p in model.named_parameters()}


@pytest.fixture(scope="module", params=["eval", "train_nodropout"])
def step(request: pytest.FixtureRequest) -> tuple[str, nn.Module, dict[str, Tensor], dict[str, Tensor]]:
    torch.set_num_threads(1)
    return request.param, *loss_and_grads(request.param)


def case(mode: str) -> Path:
    return CASE if mode == "eval" else CASE / mode


def test_every_term_and_the_total_are_leads(step) -> None:
    mode, _, losses, _ = step
    want = load(case(mode) / "losses.pt")
    assert list(losses) == list(want)  # LEAD's names, in compute_loss's order, then total
    for key, value in want.items():
        torch.testing.assert_close(losses[key].detach().reshape(value.shape), value, rtol=TOL, atol=TOL, msg=key)


def test_every_gradient_is_leads(step) -> None:
    """Tolerance relative to the largest gradient: the attention key biases' exact gradient is 0 (softmax ignores a
    shift along keys), so theirs is rounding noise (1e-11) on both sides."""
    mode, _, _, grads = step
    want = load(case(mode) / "grads.pt")
    assert set(grads) == set(want)
    largest = max(g.abs().max().item() for g in want.values())
    for name, grad in grads.items():
        torch.testing.assert_close(grad, want[name], rtol=TOL, atol=TOL * largest, msg=name)


def test_weights_are_normalised_over_leads_whole_table() -> None:
    """A NAVSIM LTFv6: nine non-zero weights, two of them for terms NAVSIM never produces, so each term weighs 1/9."""
    model = lead.load_checkpoint(TINY)
    want = json.loads((CASE / "losses.json").read_text())["all_detailed_loss_weights_normalised"]
    got = loss_weights(model.config)
    assert {k: got[k] for k in want} == pytest.approx(want, rel=1e-12)
    assert set(got) - set(want) == {"loss_tf", "loss_tfpp_speed", "loss_tfpp"}


def test_visibility_mask_is_leads_frustum() -> None:
    model = lead.load_checkpoint(TINY)
    want = load(CASE / "derived.pt")["bev_semantic_decoder_navsim.valid_bev_pixels"][0]
    assert torch.equal(visible_bev_pixels(model.config), want)


def test_one_optimizer_step_gives_leads_parameters() -> None:
    """Equal to 1e-5 wherever LEAD's gradient is at least Adam's eps (1e-8). Below it the first step,
    lr * g / (|g| + eps), follows rounding noise: the attention key biases' exact gradient is 0 and both sides hold
    noise of 1e-9 there (about 70 of 384 planner in_proj_bias entries step differently, by at most 6e-5 < lr)."""
    model, _, _ = loss_and_grads("eval")
    optimizer = lead.optimizer(model, json.loads((TINY / "config.json").read_text()))
    settings = json.loads((CASE / "optimizer.json").read_text())
    assert len(optimizer.param_groups) == settings["param_groups"]
    group = optimizer.param_groups[0]
    for key in ("lr", "eps", "weight_decay", "amsgrad"):
        assert group[key] == settings["settings"][key], key
    assert list(group["betas"]) == settings["settings"]["betas"]
    from_file = lead.optimizer(model, TINY / "config.json").defaults
    assert from_file == lead.optimizer(model, TINY).defaults == optimizer.defaults
    optimizer.step()
    want, grads = load(CASE / "params_after_step.pt"), load(CASE / "grads.pt")
    got = model.state_dict()
    assert set(got) == set(want)
    for name, value in want.items():
        settled = grads[name].abs() >= group["eps"] if name in grads else torch.ones_like(value, dtype=torch.bool)
        torch.testing.assert_close(got[name][settled], value[settled], rtol=TOL, atol=TOL, msg=name)
        assert (got[name] - value).abs().max() < group["lr"], name


def test_batch_statistics_after_train_forwards_are_leads() -> None:
    """BatchNorm's running statistics (momentum 0.1) match LEAD's file after two train-mode forwards from the loaded
    checkpoint: the file's ``num_batches_tracked`` is 2 although TRAINING.md speaks of one forward (the harness's
    second, other-seed run evidently went through the same model)."""
    model = without_dropout(lead.load_checkpoint(TINY))
    inputs, targets = load(TINY / "inputs.pt"), load(CASE / "targets.pt")
    for _ in range(2):
        lead.loss(model, inputs, targets)
    want = load(CASE / "train_nodropout" / "buffers_after_forward.pt")
    buffers = dict(model.named_buffers())
    assert set(want) == set(buffers)
    for name, value in want.items():
        torch.testing.assert_close(buffers[name], value, rtol=TOL, atol=TOL, msg=name)


def test_schedule_is_leads() -> None:
    """Cosine with warm restarts after 1, 2, 4 ... epochs (T_0 = steps per epoch), stepped after the optimizer step,
    so the first step uses lr 3e-4; WOD-E2E decays once over its 20 epochs."""
    model = lead.load_checkpoint(TINY)
    optimizer = lead.optimizer(model)
    schedule = lead.scheduler(optimizer, model.config, steps_per_epoch=10)
    assert type(schedule).__name__ == json.loads((CASE / "optimizer.json").read_text())["scheduler"]
    lrs = []
    for _ in range(31):
        lrs.append(optimizer.param_groups[0]["lr"])
        optimizer.step()
        schedule.step()
    assert lrs[0] == lrs[10] == lrs[30] == pytest.approx(3e-4) and lrs[9] < 1e-5 and lrs[20] < lrs[10]
    wod = lead.model_from_config({"use_waymo_e2e_data": True, "use_carla_data": False, "use_planning_decoder": True})
    wod_schedule = lead.scheduler(lead.optimizer(wod), wod.config, steps_per_epoch=10)
    assert type(wod_schedule).__name__ == "CosineAnnealingLR" and wod_schedule.T_max == 200


def our_navsim_batch() -> dict[str, Tensor]:
    """The golden case's inputs and targets in our batch contract (ISO frame, our names): the y flip and LEAD's
    raster orientation undone, CenterNet labels moved as :func:`boxes_from_lead` moves the head's maps (mirrored yaw
    bins, lateral offset from the other cell edge), no speed map (NAVSIM's loader gives none)."""
    inputs, targets = load(TINY / "inputs.pt"), load(CASE / "targets.pt")
    command = inputs["command"].argmax(1)
    ours = {lead_index: ours for ours, lead_index in NAVSIM_COMMAND_INDEX.items()}
    speed = inputs["speed"]
    batch = {
        "rgb": inputs["rgb"],
        "speed": speed,
        "acceleration": torch.stack([inputs["acceleration"], torch.zeros_like(speed)], dim=1),
        "command": torch.tensor([int(ours[int(c)]) for c in command]),
        "waypoints": flip_y(targets["future_waypoints"]),
        "headings": -targets["future_yaws"],
        "bev_semantic": bev_map_from_lead(targets["navsim_bev_semantic"][:, None])[:, 0],
    }
    maps = {key: bev_map_from_lead(targets[f"navsim_center_net_{key}"]) for key in ("heatmap", "wh", "offset")}
    offset = torch.cat([maps["offset"][:, :1], 1 - maps["offset"][:, 1:]], dim=1)
    weight = bev_map_from_lead(targets["navsim_center_net_pixel_weight"])[:, 0]
    yaw_class = bev_map_from_lead(targets["navsim_center_net_yaw_class"][:, None])[:, 0].long()
    batch.update(
        lead_box_heatmap=maps["heatmap"],
        lead_box_size=maps["wh"],
        lead_box_offset=torch.where(weight[:, None] > 0, offset, 0.0),
        lead_box_yaw_class=(-yaw_class) % 12,
        lead_box_yaw_residual=-bev_map_from_lead(targets["navsim_center_net_yaw_res"])[:, 0],
        lead_box_weight=weight > 0,
        lead_box_count=targets["navsim_center_net_avg_factor"].float(),
    )
    return batch


def test_the_lightning_module_trains_a_lead_network_with_leads_total_and_gradients() -> None:
    """Our training path (DrivingModule on LeadDriver, our batch and names) backpropagates LEAD's total: the same
    terms through the same definitions, LEAD's normalised weights, and LEAD's optimizer settings."""
    module = DrivingModule(LeadDriver(checkpoint=str(TINY)), supervise={"navsim": ["planning", "perception"]}).eval()
    module.setup("fit")  # channels-last, as a fit starts
    total, terms = module.compute_losses({"navsim": our_navsim_batch()})
    assert set(terms) == {"navsim/waypoints", "navsim/headings", "navsim/bev_semantic", "navsim/lead_boxes"}
    want = load(CASE / "losses.pt")
    torch.testing.assert_close(total.reshape(1), want["total"], rtol=TOL, atol=TOL)
    total.backward()
    grads = load(CASE / "grads.pt")
    largest = max(g.abs().max().item() for g in grads.values())
    for name, p in module.model.network.named_parameters():
        grad = p.grad if p.grad is not None else torch.zeros_like(p)  # NAVSIM's speed head: LEAD's 0-weighted term
        torch.testing.assert_close(grad, grads[name], rtol=TOL, atol=TOL * largest, msg=name)
    optimizer = module.configure_optimizers()
    reference = lead.optimizer(module.model.network, module.model.config)
    assert len(optimizer.param_groups) == 1
    for key in ("lr", "betas", "eps", "weight_decay", "amsgrad", "fused"):
        assert optimizer.param_groups[0][key] == reference.param_groups[0][key], key


RECIPES = Path(__file__).parents[1] / "recipes"
LEAD_RECIPES = sorted(
    path
    for family in ("carla", "navsim", "wod")
    for path in (RECIPES / family).glob("*.yaml")
    if "LeadDriver" in path.read_text()
)


@pytest.mark.parametrize("recipe", LEAD_RECIPES, ids=lambda p: f"{p.parent.name}/{p.name}")
def test_lead_recipes_configure_leads_optimizer_and_schedule(recipe: Path) -> None:
    """Every full-scale LEAD recipe: LEAD's AdamW settings, no warm-up, no gradient clipping, and LEAD's schedule for
    its config (cosine restarts; one cosine for WOD-E2E)."""
    spec = yaml.safe_load(recipe.read_text())
    module = spec["model"]
    config = LeadConfig.from_json(module["model"]["init_args"]["config"])
    assert module.get("lr", 3e-4) == config.lr and module.get("weight_decay", 0.01) == config.weight_decay
    assert module.get("amsgrad", True) is True and tuple(module.get("betas", (0.9, 0.999))) == (0.9, 0.999)
    assert module.get("warmup_steps", 0) == 0
    assert spec["trainer"].get("gradient_clip_val") is None
    assert module["lr_schedule"] == ("cosine_restarts" if config.use_cosine_annealing_with_restarts else "cosine")


def test_an_ensemble_validates_on_the_outputs_it_merges(tmp_path: Path) -> None:
    """A LEAD ensemble folder validated with ``log_val_losses``: NAVSIM's ensemble merges the planner only
    (``LeadEnsemble``), so its loss terms are the planner's, equal to the mean prediction's, not a KeyError for the
    BEV and box maps it drops."""
    for name in ("config.json", "model_0000.pth"):
        shutil.copy(TINY / name, tmp_path / name)
    shutil.copy(TINY / "model_0000.pth", tmp_path / "model_0001.pth")
    ensemble = DrivingModule(LeadDriver(checkpoint=str(tmp_path)), log_val_losses=True).eval()
    single = DrivingModule(LeadDriver(checkpoint=str(TINY)), log_val_losses=True).eval()
    assert ensemble.model.tasks("navsim") == {"waypoints", "headings"}
    with torch.no_grad():
        _, terms = ensemble.compute_losses({"navsim": our_navsim_batch()})
        _, single_terms = single.compute_losses({"navsim": our_navsim_batch()})
    assert set(terms) == {"navsim/waypoints", "navsim/headings"}
    for name, (value, count) in terms.items():  # two copies of one member: its own terms
        torch.testing.assert_close(value, single_terms[name][0], rtol=TOL, atol=TOL)
        assert count == single_terms[name][1]
