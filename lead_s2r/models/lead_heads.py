"""LEAD's dense heads under LEAD's names: BEV semantics (``bev_decoder.py``), CenterNet boxes
(``center_net_decoder.py``) and the perspective semantic / depth decoders (``perspective_decoder.py``).

The heads return raw maps; losses and the CenterNet box decoding stay outside the network.
"""

import torch.nn.functional as F
from torch import Tensor, nn

from lead_s2r.models.lead_config import TRAINING_USED_LIDAR_STEPS, LeadConfig


class BEVDecoder(nn.Module):
    """3x3 conv, ReLU, 1x1 conv without bias, bilinear upsample from the stride-4 grid to the full BEV."""

    def __init__(self, config: LeadConfig, num_classes: int) -> None:
        super().__init__()
        c = config.bev_features_chanels
        self.net = nn.Sequential(
            nn.Conv2d(c, c, kernel_size=(3, 3), stride=1, padding=(1, 1), bias=True),
            nn.ReLU(inplace=True),
            nn.Conv2d(c, num_classes, kernel_size=(1, 1), stride=1, padding=0, bias=False),
            nn.Upsample(
                size=(config.lidar_height_pixel, config.lidar_width_pixel), mode="bilinear", align_corners=False
            ),
        )

    def forward(self, grid: Tensor) -> Tensor:
        return self.net(grid)


def _head(channels: int, out: int) -> nn.Sequential:
    return nn.Sequential(
        nn.Conv2d(channels, channels, 3, padding=1), nn.ReLU(inplace=True), nn.Conv2d(channels, out, 1)
    )


class CenterNetDecoder(nn.Module):
    """CenterNet maps at BEV/4: heatmap logits (and float32 sigmoid), size, offset, yaw bins and residual, speed."""

    def __init__(self, config: LeadConfig, num_classes: int) -> None:
        super().__init__()
        c = config.bb_input_channel
        self.heatmap_head = _head(c, num_classes)
        self.wh_head = _head(c, 2)
        self.offset_head = _head(c, 2)
        self.yaw_class_head = _head(c, config.num_dir_bins)
        self.yaw_res_head = _head(c, 1)
        if TRAINING_USED_LIDAR_STEPS > 1:
            self.velocity_head = _head(c, 1)

    def forward(self, grid: Tensor) -> dict[str, Tensor]:
        logits = self.heatmap_head(grid)
        return {
            "center_heatmap_logit_pred": logits,
            "center_heatmap_pred": logits.float().sigmoid(),
            "wh_pred": self.wh_head(grid),
            "offset_pred": self.offset_head(grid),
            "yaw_class_pred": self.yaw_class_head(grid),
            "yaw_res_pred": self.yaw_res_head(grid),
            "velocity_pred": self.velocity_head(grid),
        }


def _conv_pair(c_in: int, c_mid: int, c_out: int, last_relu: bool) -> nn.Sequential:
    layers = [nn.Conv2d(c_in, c_mid, 3, 1, 1), nn.ReLU(inplace=True), nn.Conv2d(c_mid, c_out, 3, 1, 1)]
    return nn.Sequential(*layers, nn.ReLU(inplace=True)) if last_relu else nn.Sequential(*layers)


class PerspectiveDecoder(nn.Module):
    """Stride-32 image map -> full-resolution semantic logits or depth (two convs, bilinear x8, two convs, x4, two
    convs, then a resize to the configured image size when within 10 %, as LEAD checks)."""

    def __init__(self, config: LeadConfig, in_channels: int, out_channels: int, upsample_factor: int) -> None:
        super().__init__()
        self.config = config
        self.scale_factor_0 = upsample_factor // config.deconv_scale_factor_0
        self.scale_factor_1 = upsample_factor // config.deconv_scale_factor_1
        c0, c1, c2 = config.deconv_channel_num_0, config.deconv_channel_num_1, config.deconv_channel_num_2
        self.deconv1 = _conv_pair(in_channels, c0, c1, last_relu=True)
        self.deconv2 = _conv_pair(c1, c2, c2, last_relu=True)
        self.deconv3 = _conv_pair(c2, c2, out_channels, last_relu=False)

    def forward(self, image_features: Tensor) -> Tensor:
        x = self.deconv1(image_features)
        x = F.interpolate(x, scale_factor=self.scale_factor_0, mode="bilinear", align_corners=False)
        x = self.deconv2(x)
        x = F.interpolate(x, scale_factor=self.scale_factor_1, mode="bilinear", align_corners=False)
        x = self.deconv3(x)
        size = (self.config.final_image_height, self.config.final_image_width)
        if tuple(x.shape[2:]) != size:
            error = max(abs(x.shape[2] - size[0]) / size[0], abs(x.shape[3] - size[1]) / size[1])
            if error > 0.1:
                raise ValueError(f"perspective decoder output {tuple(x.shape[2:])} is over 10 % off the image {size}")
            x = F.interpolate(x, size=size, mode="bilinear", align_corners=False)
        return x
