"""LEAD's TFv6 network (``lead/tfv6/tfv6.py``) as a plain module whose ``state_dict`` is LEAD's, key for key.

``forward(data)`` takes LEAD's input dict (its keys, units and frame: x forward, y right; see docs/models.md) and
returns LEAD's ``Prediction`` fields as a flat dict of tensors; CenterNet sub-fields are ``pred_bounding_box.<field>`` /
``pred_bounding_box_navsim.<field>``. Fields a configuration does not produce are absent rather than None.
"""

from torch import Tensor, nn

from lead_s2r.models.lead_backbone import TransfuserBackbone
from lead_s2r.models.lead_config import NAVSIM_BEV_SEMANTIC_CLASSES, NAVSIM_BOX_CLASSES, LeadConfig
from lead_s2r.models.lead_heads import BEVDecoder, CenterNetDecoder, PerspectiveDecoder
from lead_s2r.models.lead_planner import PlanningDecoder
from lead_s2r.models.lead_radar import RadarDetector
from lead_s2r.models.lead_tfv5 import TFv5PlanningDecoder


class LeadTFv6(nn.Module):
    """TFv6 / LTFv6 / TFv5 exactly as LEAD builds them from a :class:`LeadConfig`."""

    def __init__(self, config: LeadConfig, pretrained: bool = False) -> None:
        super().__init__()
        self.config = c = config
        self.backbone = TransfuserBackbone(c, pretrained=pretrained)
        image_channels, up = self.backbone.num_image_features, self.backbone.perspective_upsample_factor
        if c.use_semantic and c.use_carla_data:
            self.semantic_decoder = PerspectiveDecoder(c, image_channels, c.num_semantic_classes, up)
        if c.use_depth and c.use_carla_data:
            self.depth_decoder = PerspectiveDecoder(c, image_channels, 1, up)
        if c.use_bev_semantic and c.use_carla_data:
            self.bev_semantic_decoder = BEVDecoder(c, c.num_bev_semantic_classes)
        if c.use_bev_semantic and c.use_navsim_data:
            self.bev_semantic_decoder_navsim = BEVDecoder(c, NAVSIM_BEV_SEMANTIC_CLASSES)
        if c.detect_boxes and c.use_carla_data:
            self.center_net_decoder = CenterNetDecoder(c, c.num_bb_classes)
        if c.detect_boxes and c.use_navsim_data:
            self.center_net_decoder_navsim = CenterNetDecoder(c, NAVSIM_BOX_CLASSES)
        bev_channels = self.backbone.num_lidar_features
        if c.has_radar_detector:
            self.radar_detector = RadarDetector(bev_channels, c)
        if c.use_planning_decoder:
            planner = TFv5PlanningDecoder if c.use_tfv5_planning_decoder else PlanningDecoder
            self.planning_decoder = planner(bev_channels, c)

    def forward(self, data: dict[str, Tensor]) -> dict[str, Tensor]:
        c = self.config
        bev, image = self.backbone(data)
        out: dict[str, Tensor] = {}
        radar = None
        if c.has_radar_detector:
            weight = self.radar_detector.bev_proj.weight
            radar = self.radar_detector(
                bev, data["radar"].to(weight.device, weight.dtype), data["speed"].to(weight.device, weight.dtype)
            )
            out["pred_radar_features"], out["pred_radar_predictions"] = radar
        if c.use_planning_decoder:
            planner_radar = radar if c.use_radar_detection and c.use_carla_data else None
            out.update(self.planning_decoder(bev, data, planner_radar))
        if c.use_semantic and c.use_carla_data:
            out["pred_semantic"] = self.semantic_decoder(image)
        if c.use_depth and c.use_carla_data:
            out["pred_depth"] = self.depth_decoder(image).squeeze(1)
        grid = self.backbone.top_down(bev)
        for suffix, present in (("", c.use_carla_data), ("_navsim", c.use_navsim_data)):
            if c.detect_boxes and present:
                boxes = getattr(self, f"center_net_decoder{suffix}")(grid)
                out.update({f"pred_bounding_box{suffix}.{k}": v for k, v in boxes.items()})
            if c.use_bev_semantic and present:
                out[f"pred_bev_semantic{suffix}"] = getattr(self, f"bev_semantic_decoder{suffix}")(grid)
        return out
