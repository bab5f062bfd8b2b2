"""LEAD's TransFuser backbone (``lead/tfv6/transfuser_backbone.py``) under LEAD's module names, so LEAD's state_dicts
load without a key map: two timm ``features_only`` encoders stepped block by block, a GPT fusing them after each of the
four stages, and the top-down pyramid that gives the dense BEV heads their stride-4 grid.

The LiDAR branch reads a (B, 1, Hb, Wb) raster, or with ``LTF`` a 2-channel coordinate grid built here (channel 0 =
row position, channel 1 = column position, 0..1). BEV rows are ego y (left to right), columns ego x (back to front).
"""

import timm
import torch
import torch.nn.functional as F
from torch import Tensor, nn

from lead_s2r.models.lead_config import LeadConfig

IMAGENET_MEAN = (0.485, 0.456, 0.406)
IMAGENET_STD = (0.229, 0.224, 0.225)


def normalize_imagenet(rgb: Tensor) -> Tensor:
    """0..255 RGB -> ImageNet-normalised, channel by channel in LEAD's operation order (bit-equal results)."""
    channels = [((rgb[:, c] / 255.0) - IMAGENET_MEAN[c]) / IMAGENET_STD[c] for c in range(3)]
    return torch.stack(channels, dim=1)


def encoder_blocks(encoder: nn.Module) -> list[list[str]]:
    """The module names of each block a timm FeatureListNet is stepped through: with five return layers the stem is
    its own first block (run without fusion), then one block per fused stage."""
    blocks, current = [], []
    for name, _ in encoder.items():
        current.append(name)
        if name in encoder.return_layers:
            blocks.append(current)
            current = []
    return blocks


class SelfAttention(nn.Module):
    """Multi-head self-attention with separate key/query/value linears (LEAD's names) and SDPA."""

    def __init__(self, n_embd: int, n_head: int, attn_pdrop: float, resid_pdrop: float) -> None:
        super().__init__()
        if n_embd % n_head:
            raise ValueError(f"fusion width {n_embd} is not divisible by n_head={n_head}")
        self.key = nn.Linear(n_embd, n_embd)
        self.query = nn.Linear(n_embd, n_embd)
        self.value = nn.Linear(n_embd, n_embd)
        self.dropout = attn_pdrop
        self.resid_drop = nn.Dropout(resid_pdrop)
        self.proj = nn.Linear(n_embd, n_embd)
        self.n_head = n_head

    def forward(self, x: Tensor) -> Tensor:
        b, t, c = x.shape

        def heads(linear: nn.Linear) -> Tensor:
            return linear(x).view(b, t, self.n_head, c // self.n_head).transpose(1, 2)

        k, q, v = heads(self.key), heads(self.query), heads(self.value)
        y = F.scaled_dot_product_attention(q, k, v, dropout_p=self.dropout if self.training else 0.0)
        return self.resid_drop(self.proj(y.transpose(1, 2).contiguous().view(b, t, c)))


class Block(nn.Module):
    """Pre-norm transformer block; the MLP uses ReLU (LEAD changed it from GELU)."""

    def __init__(self, n_embd: int, n_head: int, block_exp: int, attn_pdrop: float, resid_pdrop: float) -> None:
        super().__init__()
        self.ln1 = nn.LayerNorm(n_embd)
        self.ln2 = nn.LayerNorm(n_embd)
        self.attn = SelfAttention(n_embd, n_head, attn_pdrop, resid_pdrop)
        self.mlp = nn.Sequential(
            nn.Linear(n_embd, block_exp * n_embd),
            nn.ReLU(True),
            nn.Linear(block_exp * n_embd, n_embd),
            nn.Dropout(resid_pdrop),
        )

    def forward(self, x: Tensor) -> Tensor:
        x = x + self.attn(self.ln1(x))
        return x + self.mlp(self.ln2(x))


class GPT(nn.Module):
    """Fusion transformer over image tokens then LiDAR tokens (row-major), learned positional embedding."""

    def __init__(self, n_embd: int, config: LeadConfig) -> None:
        super().__init__()
        self.n_embd = n_embd
        self.n_image = config.img_vert_anchors * config.img_horz_anchors
        n_lidar = config.lidar_vert_anchors * config.lidar_horz_anchors
        self.pos_emb = nn.Parameter(torch.zeros(1, self.n_image + n_lidar, n_embd))
        self.drop = nn.Dropout(config.embd_pdrop)
        arguments = (n_embd, config.n_head, config.block_exp, config.attn_pdrop, config.resid_pdrop)
        self.blocks = nn.Sequential(*(Block(*arguments) for _ in range(config.n_layer)))
        self.ln_f = nn.LayerNorm(n_embd)
        for module in self.modules():
            if isinstance(module, nn.Linear):
                module.weight.data.normal_(config.gpt_linear_layer_init_mean, config.gpt_linear_layer_init_std)
                module.bias.data.zero_()
            elif isinstance(module, nn.LayerNorm):
                module.bias.data.zero_()
                module.weight.data.fill_(config.gpt_layer_norm_init_weight)

    def forward(self, image: Tensor, lidar: Tensor) -> tuple[Tensor, Tensor]:
        b = lidar.shape[0]
        (ih, iw), (lh, lw) = image.shape[2:4], lidar.shape[2:4]
        tokens = torch.cat([t.permute(0, 2, 3, 1).contiguous().view(b, -1, self.n_embd) for t in (image, lidar)], dim=1)
        x = self.ln_f(self.blocks(self.drop(self.pos_emb + tokens)))
        image_out = x[:, : self.n_image].view(b, ih, iw, -1).permute(0, 3, 1, 2).contiguous()
        lidar_out = x[:, self.n_image :].view(b, lh, lw, -1).permute(0, 3, 1, 2).contiguous()
        return image_out, lidar_out


class TransfuserBackbone(nn.Module):
    """Image + LiDAR encoders fused after each stage; ``forward`` returns (stride-32 BEV map, stride-32 image map)."""

    def __init__(self, config: LeadConfig, pretrained: bool = False) -> None:
        super().__init__()
        self.config = config
        self.image_encoder = timm.create_model(config.image_architecture, pretrained=pretrained, features_only=True)
        self.avgpool_img = nn.AdaptiveAvgPool2d((config.img_vert_anchors, config.img_horz_anchors))
        self.lidar_encoder = timm.create_model(
            config.lidar_architecture, pretrained=False, in_chans=2 if config.LTF else 1, features_only=True
        )
        image_info = self.image_encoder.feature_info.info[-4:]
        lidar_info = self.lidar_encoder.feature_info.info[-4:]
        self.num_image_features = image_info[3]["num_chs"]
        self.num_lidar_features = lidar_info[3]["num_chs"]
        channels = [(li["num_chs"], ii["num_chs"]) for li, ii in zip(lidar_info, image_info, strict=True)]
        self.lidar_channel_to_img = nn.ModuleList(nn.Conv2d(lc, ic, kernel_size=1) for lc, ic in channels)
        self.img_channel_to_lidar = nn.ModuleList(nn.Conv2d(ic, lc, kernel_size=1) for lc, ic in channels)
        self.avgpool_lidar = nn.AdaptiveAvgPool2d((config.lidar_vert_anchors, config.lidar_horz_anchors))
        self.transformers = nn.ModuleList(GPT(ii["num_chs"], config) for ii in image_info)
        self.perspective_upsample_factor = image_info[3]["reduction"] // config.perspective_downsample_factor
        c, down = config.bev_features_chanels, config.bev_down_sample_factor
        self.upsample = nn.Upsample(scale_factor=config.bev_upsample_factor, mode="bilinear", align_corners=False)
        size = (config.lidar_height_pixel // down, config.lidar_width_pixel // down)
        self.upsample2 = nn.Upsample(size=size, mode="bilinear", align_corners=False)
        self.up_conv5 = nn.Conv2d(c, c, (3, 3), padding=1)
        self.up_conv4 = nn.Conv2d(c, c, (3, 3), padding=1)
        self.c5_conv = nn.Conv2d(self.num_lidar_features, c, (1, 1))
        self._image_blocks = encoder_blocks(self.image_encoder)
        self._lidar_blocks = encoder_blocks(self.lidar_encoder)

    def lidar_input(self, data: dict[str, Tensor], like: Tensor) -> Tensor:
        """The LiDAR branch's input: the raster from ``data``, or LTF's coordinate grid (float32, as LEAD builds it)."""
        c = self.config
        if not c.LTF:
            if "rasterized_lidar" not in data:
                raise KeyError("LEAD TFv6 without LTF needs 'rasterized_lidar' (B, 1, Hb, Wb) in its inputs")
            return data["rasterized_lidar"].to(like.device, like.dtype)
        rows = torch.linspace(0, 1, c.lidar_height_pixel, device=like.device)
        cols = torch.linspace(0, 1, c.lidar_width_pixel, device=like.device)
        row_grid, col_grid = torch.meshgrid(rows, cols, indexing="ij")
        return torch.stack([row_grid, col_grid])[None].repeat(like.shape[0], 1, 1, 1)

    def run_block(self, encoder: nn.Module, names: list[str], x: Tensor) -> Tensor:
        for name in names:
            x = encoder[name](x)
        return x

    def fuse(self, image: Tensor, lidar: Tensor, i: int) -> tuple[Tensor, Tensor]:
        image_tokens = self.avgpool_img(image)
        lidar_tokens = self.lidar_channel_to_img[i](self.avgpool_lidar(lidar))
        image_out, lidar_out = self.transformers[i](image_tokens, lidar_tokens)
        lidar_out = self.img_channel_to_lidar[i](lidar_out)
        image_out = F.interpolate(image_out, size=image.shape[2:4], mode="bilinear", align_corners=False)
        lidar_out = F.interpolate(lidar_out, size=lidar.shape[2:4], mode="bilinear", align_corners=False)
        return image + image_out, lidar + lidar_out

    def forward(self, data: dict[str, Tensor]) -> tuple[Tensor, Tensor]:
        rgb = data["rgb"].to(self.c5_conv.weight.device, self.c5_conv.weight.dtype)
        image = normalize_imagenet(rgb)
        lidar = self.lidar_input(data, rgb)
        image_blocks, lidar_blocks = self._image_blocks, self._lidar_blocks
        if len(image_blocks) > 4:
            image = self.run_block(self.image_encoder, image_blocks[0], image)
        if len(lidar_blocks) > 4:
            lidar = self.run_block(self.lidar_encoder, lidar_blocks[0], lidar)
        for i in range(4):
            image = self.run_block(self.image_encoder, image_blocks[i - 4], image)
            lidar = self.run_block(self.lidar_encoder, lidar_blocks[i - 4], lidar)
            image, lidar = self.fuse(image, lidar, i)
        return lidar, image

    def top_down(self, bev: Tensor) -> Tensor:
        """Stride-32 BEV map -> the (B, bev_features_chanels, Hb/4, Wb/4) grid of the dense BEV heads."""
        p5 = F.relu(self.c5_conv(bev), inplace=True)
        p4 = F.relu(self.up_conv5(self.upsample(p5)), inplace=True)
        return F.relu(self.up_conv4(self.upsample2(p4)), inplace=True)
