"""Every supervised task, keyed by its name: the batch key that holds its label and the loss that scores it.

A loss reads the model only for what the term needs beyond predictions and labels (the box head's yaw bins, the
radar normalisation, the target-speed bins, the BEV's visible area, the camera crop of the ablations); adding a
task is one entry here. Perception terms are LEAD's definitions (:mod:`lead_s2r.models.lead_loss`): BEV semantics
ignore what the cameras cannot see but count it in the mean, perspective terms are per-sample pixel means, depth
labels are whole metres. One family of networks (:class:`~lead_s2r.models.lead_driver.LeadDriver`; the Ego MLP has
planning terms only), so one table.
"""

from collections.abc import Callable
from typing import NamedTuple

from torch import Tensor, nn

from lead_s2r.models.inputs import Batch, on_image_grid
from lead_s2r.training import losses

#: ``loss(pred, batch, model)``: one scalar for one source's batch.
LossFn = Callable[[dict[str, Tensor], Batch, nn.Module], Tensor]


class Task(NamedTuple):
    """A supervised task: the batch key of its label (the term is computed only where it is present) and its loss."""

    target: str
    loss: LossFn


def _target_speed(pred: dict[str, Tensor], batch: Batch, model: nn.Module) -> Tensor:
    return losses.target_speed_loss(pred, batch, model.target_speed_classes)  # a buffer: on the device, no copy


def _lead_boxes(pred: dict[str, Tensor], batch: Batch, model: nn.Module) -> Tensor:
    return losses.lead_box_loss(pred, batch, velocity=model.box_velocity_loss)


def _radar(pred: dict[str, Tensor], batch: Batch, model: nn.Module) -> Tensor:
    return losses.radar_loss(pred, batch, model.radar_scale)


def _on_input_image(task: str, batch: Batch, model: nn.Module) -> Tensor:
    """A perspective label on the input image's grid (brought there on the device), cropped as the camera
    ablations crop the image."""
    crop = getattr(model, "camera_select", nn.Identity())
    return crop(on_image_grid(batch[task], tuple(batch["rgb"].shape[-2:])))


def _bev_semantic(pred: dict[str, Tensor], batch: Batch, model: nn.Module) -> Tensor:
    return losses.lead_bev_semantic_loss(pred["bev_semantic"], batch["bev_semantic"], model.bev_visible)


def _semantic(pred: dict[str, Tensor], batch: Batch, model: nn.Module) -> Tensor:
    return losses.lead_semantic_loss(pred["semantic"], _on_input_image("semantic", batch, model))


def _depth(pred: dict[str, Tensor], batch: Batch, model: nn.Module) -> Tensor:
    return losses.lead_depth_loss(pred["depth"], _on_input_image("depth", batch, model))


TASKS: dict[str, Task] = {
    "waypoints": Task("waypoints", lambda pred, batch, model: losses.waypoint_loss(pred, batch)),
    "headings": Task("headings", lambda pred, batch, model: losses.heading_loss(pred, batch)),
    "route": Task("route", lambda pred, batch, model: losses.route_loss(pred, batch)),
    "target_speed": Task("target_speed", _target_speed),
    "bev_semantic": Task("bev_semantic", _bev_semantic),
    "lead_boxes": Task("lead_box_heatmap", _lead_boxes),
    "depth": Task("depth", _depth),
    "semantic": Task("semantic", _semantic),
    "radar": Task("radar_targets", _radar),
}
#: Each task's label key in the batch.
TASK_TARGETS = {name: task.target for name, task in TASKS.items()}


def task_loss(task: str, pred: dict[str, Tensor], batch: Batch, model: nn.Module) -> Tensor:
    """The loss term of ``task`` for one source's batch."""
    if task not in TASKS:
        raise ValueError(f"unknown task {task!r}; known: {sorted(TASKS)}")
    return TASKS[task].loss(pred, batch, model)
