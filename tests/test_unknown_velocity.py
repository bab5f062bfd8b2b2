"""A box velocity the source does not know (vx, vy NaN; docs/schema.md) through the labels and losses that read it:
the CenterNet speed map and LEAD's speed term, the radar targets and LEAD's radar term. Each unknown speed adds no
loss and no gradient, and every other value is what it is with the speed known."""

import numpy as np
import pytest
import torch

from lead_s2r.data.lead_centernet import lead_centernet_targets
from lead_s2r.data.radar import radar_targets
from lead_s2r.errors import UserError
from lead_s2r.models.config import NAVSIM_BEV
from lead_s2r.models.lead_loss import radar_loss
from lead_s2r.schema import SchemaError, validate
from lead_s2r.training.losses import lead_box_loss

SCALE = (96.0, 80.0, 25.0)
#: The prediction's speed everywhere (m/s).
PREDICTED = 4.0


def boxes(second_velocity: tuple[float, float]) -> np.ndarray:
    """Two vehicles on NAVSIM's grid, the first moving at 3 m/s, the second at ``second_velocity``."""
    rows = np.zeros((2, 10), np.float32)
    rows[:, 0:2] = [[5.3, -3.7], [12.0, 6.0]]
    rows[:, 3:5] = [4.0, 2.0]
    rows[0, 7:9] = [3.0, 0.0]
    rows[1, 7:9] = second_velocity
    return rows


def box_loss(rows: np.ndarray) -> tuple[torch.Tensor, torch.Tensor]:
    """LEAD's CenterNet terms for one sample of ``rows`` against a prediction of :data:`PREDICTED` m/s everywhere;
    the loss and the speed prediction's gradient."""
    targets = lead_centernet_targets(rows, np.zeros(len(rows), np.int64), NAVSIM_BEV, 1, 12)
    batch = {name: value[None] for name, value in targets.items()}
    h, w = batch["lead_box_weight"].shape[1:]
    speed = torch.full((1, 1, h, w), PREDICTED, requires_grad=True)
    pred = {
        "box_heatmap": torch.zeros(1, 1, h, w),
        "box_size": torch.zeros(1, 2, h, w),
        "box_offset": torch.zeros(1, 2, h, w),
        "box_yaw_class": torch.zeros(1, 12, h, w),
        "box_yaw_residual": torch.zeros(1, 1, h, w),
        "box_velocity": speed,
    }
    loss = lead_box_loss(pred, batch, velocity=True)
    loss.backward()
    return loss.detach(), speed.grad[0, 0]


def test_an_unknown_speed_is_nan_in_its_cell_and_adds_no_loss_or_gradient() -> None:
    unknown = lead_centernet_targets(boxes((np.nan, np.nan)), np.zeros(2, np.int64), NAVSIM_BEV, 1, 12)
    known = lead_centernet_targets(boxes((PREDICTED, 0.0)), np.zeros(2, np.int64), NAVSIM_BEV, 1, 12)
    nan = unknown["lead_box_velocity"].isnan()
    assert int(nan.sum()) == 1 and bool(unknown["lead_box_weight"][nan].all())  # the second box's cell
    for name, value in known.items():
        if name != "lead_box_velocity":
            assert torch.equal(unknown[name], value), name
    loss, grad = box_loss(boxes((np.nan, np.nan)))
    # the same as when the box moved as predicted: |4 - 3| at the first box, |4 - 0| at LEAD's padding box, over 3
    want, want_grad = box_loss(boxes((PREDICTED, 0.0)))
    assert torch.isfinite(loss) and loss.item() == pytest.approx(want.item(), rel=1e-6)
    assert grad[nan].item() == 0.0 and torch.equal(grad, want_grad)
    assert grad.abs().sum().item() == pytest.approx(2 / 3, rel=1e-6)  # the first box and the padding box


def test_an_unknown_radar_speed_comes_last_and_only_its_speed_is_left_out_of_the_loss() -> None:
    rows = boxes((np.nan, np.nan))
    rows[0, 7:9] = [1.0, 0.0]
    radar = np.array([[5.3, -3.7, 0.5, 0.0, 0.0], [12.0, 6.0, 0.5, 0.0, 1.0]], np.float32)
    targets = radar_targets(radar, rows[::-1].copy())  # the unknown one first: it still comes after the known
    np.testing.assert_array_equal(targets["radar_targets"][:2, :2].numpy(), rows[:, :2])
    assert targets["radar_targets"][0, 2].item() == 1.0 and targets["radar_targets"][1, 2].isnan()
    detections = torch.cat([targets["radar_targets"], targets["radar_targets_valid"].float()[:, None]], -1)[None, :2]
    exact = torch.cat([detections[..., :3].nan_to_num(), torch.full((1, 2, 1), 50.0)], -1)
    pred = exact.clone().requires_grad_(True)
    with torch.no_grad():
        pred[0, 1, 2] = 20.0  # any speed for the unknown one
        pred[0, 0, 2] = 1.0 + 2.5  # 0.1 of the maximum speed off for the known one
    loss = radar_loss(pred, detections, SCALE)
    loss.backward()
    assert loss.item() == pytest.approx(5 * 0.1 / 2, rel=1e-4)  # the known speed's L1 over both valid slots
    assert pred.grad[0, 1, 2].item() == 0.0 and pred.grad[0, 0, 2].item() > 0


@pytest.mark.parametrize(("velocity", "ok"), [((np.nan, np.nan), True), ((1.0, np.nan), False), ((np.inf, 0.0), False)])
def test_the_schema_admits_a_velocity_unknown_in_both_axes_only(velocity: tuple[float, float], ok: bool) -> None:
    sample = {
        "__key__": "k",
        "past": np.zeros((1, 4), np.float32),
        "boxes": boxes(velocity),
        "meta": {
            "schema_version": 1, "dataset": "d", "split": "s", "log_id": "l", "frame_idx": 0, "timestamp_us": 0,
            "is_synthetic": False, "location": None, "adapter": "a", "adapter_version": "1",
            "ego": {"speed": 0.0, "velocity": [0.0, 0.0], "acceleration": [0.0, 0.0], "yaw_rate": 0.0, "command": 0,
                    "command_raw": None},
            "vehicle": {"length": 5.0, "width": 2.0, "wheel_base": 3.0, "rear_axle_to_center": 1.5},
            "cameras": [], "has": {"boxes": True, "past": True}, "extras": {},
        },
    }  # fmt: skip
    if ok:
        validate(sample)
    else:
        with pytest.raises((SchemaError, UserError), match="vx, vy may both be NaN"):
            validate(sample)
