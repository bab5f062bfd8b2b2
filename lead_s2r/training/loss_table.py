"""Every supervised task, keyed by its name: the batch key that holds its label (:data:`TASK_TARGETS`) and the loss
that scores it (:func:`task_loss`).

A loss reads the model only for what the term needs beyond predictions and labels (the box head's yaw bins, the
radar normalisation, the target-speed bins, the BEV's visible area, the camera crop of the ablations); adding a
task is one entry in each. Perception terms are LEAD's definitions (:mod:`lead_s2r.models.lead_loss`): BEV semantics
ignore what the cameras cannot see but count it in the mean, perspective terms are per-sample pixel means, depth
labels are whole metres. One family of networks (:class:`~lead_s2r.models.lead_driver.LeadDriver`; the Ego MLP has
planning terms only), so one table.
"""

from torch import Tensor, nn

from lead_s2r.models.inputs import Batch, on_image_grid
from lead_s2r.training import losses

#: Each task's label key in the batch: its term is computed only where the label is present.
TASK_TARGETS = {
    "waypoints": "waypoints",
    "headings": "headings",
    "route": "route",
    "target_speed": "target_speed",
    "bev_semantic": "bev_semantic",
    "lead_boxes": "lead_box_heatmap",
    "depth": "depth",
    "semantic": "semantic",
    "radar": "radar_targets",
}


def task_loss(task: str, pred: dict[str, Tensor], batch: Batch, model: nn.Module) -> Tensor:
    """The loss term of ``task`` for one source's batch."""
    match task:
        case "waypoints":
            return losses.waypoint_loss(pred, batch)
        case "headings":
            return losses.heading_loss(pred, batch)
        case "route":
            return losses.route_loss(pred, batch)
        case "target_speed":  # the speed bins: a buffer, on the device, no copy
            return losses.target_speed_loss(pred, batch, model.target_speed_classes)
        case "bev_semantic":
            return losses.lead_bev_semantic_loss(pred["bev_semantic"], batch["bev_semantic"], model.bev_visible)
        case "lead_boxes":
            return losses.lead_box_loss(pred, batch, velocity=model.box_velocity_loss)
        case "depth":
            return losses.lead_depth_loss(pred["depth"], _on_input_image("depth", batch, model))
        case "semantic":
            return losses.lead_semantic_loss(pred["semantic"], _on_input_image("semantic", batch, model))
        case "radar":
            return losses.radar_loss(pred, batch, model.radar_scale)
    raise ValueError(f"unknown task {task!r}; known: {sorted(TASK_TARGETS)}")


def _on_input_image(task: str, batch: Batch, model: nn.Module) -> Tensor:
    """A perspective label on the input image's grid (brought there on the device), cropped as the camera
    ablations crop the image."""
    crop = getattr(model, "camera_select", nn.Identity())
    return crop(on_image_grid(batch[task], tuple(batch["rgb"].shape[-2:])))
