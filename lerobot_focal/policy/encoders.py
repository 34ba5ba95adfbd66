"""Observation encoders: per-step features that are concatenated into the U-Net's global FiLM condition.

* point cloud  → DP3's MLP encoder (per-point MLP with LayerNorm, max-pool, projection + LayerNorm)
* proprioception / env state → small MLP
* RGB cameras  → LeRobot's diffusion ResNet + spatial-softmax encoder (reused, not copied)
"""

from __future__ import annotations

from typing import TYPE_CHECKING

import torch
from lerobot.policies.diffusion.modeling_diffusion import DiffusionRgbEncoder
from torch import Tensor, nn

from lerobot_focal.policy.network import diffusion_spec

if TYPE_CHECKING:
    from lerobot_focal.policy.configuration_focal import FocalConfig


class PointCloudEncoder(nn.Module):
    """DP3's point-cloud MLP: Linear C→64→128→256 (LayerNorm + ReLU each), max over points, Linear 256→out, LN.

    Order-invariant through the max-pool, which is why it tolerates farthest-point-sampled clouds whose point
    order carries no meaning.

    Training runs the per-point MLP with gradients on the points that hold some channel's maximum only
    (``winners_only_backward``): the max-pool passes gradient to those points alone, and the MLP treats each
    point on its own (LayerNorm normalises over a point's channels, there are no batch statistics), so the
    other points contribute nothing to the loss's value or gradient beyond the maxima they lose. A no-grad pass
    over the whole cloud finds the winners (about 100 of 512 points of a MetaWorld cloud for DP3's 256
    channels); the forward and backward with gradients then run on those only. Output and gradients are those
    of the dense computation up to float rounding (tests/policy/test_policy.py); `lerobot-focal-bench
    train-step --inputs pointcloud` times both in one process.
    """

    def __init__(self, in_channels: int = 3, out_dim: int = 64, hidden: tuple[int, ...] = (64, 128, 256),
                 winners_only_backward: bool = True):
        super().__init__()
        layers: list[nn.Module] = []
        prev = in_channels
        for width in hidden:
            # In place: LayerNorm's backward needs its input, not its output, so the ReLU may overwrite it.
            # A batch of 64 × 2 clouds × 512 points makes each activation 16-64 MB: three fewer allocations and
            # writes of that size per forward, with bit-identical results (tests/policy/test_policy.py).
            layers += [nn.Linear(prev, width), nn.LayerNorm(width), nn.ReLU(inplace=True)]
            prev = width
        self.point_mlp = nn.Sequential(*layers)
        self.projection = nn.Sequential(nn.Linear(prev, out_dim), nn.LayerNorm(out_dim))
        self.in_channels = in_channels
        self.winners_only_backward = winners_only_backward

    def forward(self, points: Tensor) -> Tensor:
        """points: (B, P, C≥in_channels) → (B, out_dim). Extra channels (e.g. rgb) are ignored."""
        points = points[..., : self.in_channels]
        if self.winners_only_backward and torch.is_grad_enabled() and self.point_mlp[0].weight.requires_grad:
            points = self._max_winners(points)
        feats = self.point_mlp(points)
        return self.projection(feats.max(dim=-2).values)

    @torch.no_grad()
    def max_winners(self, points: Tensor) -> Tensor:
        """(B, P) bool: the points of each cloud that hold some channel's maximum (no gradients)."""
        winners = self.point_mlp(points[..., : self.in_channels]).argmax(dim=-2)  # (B, F): each channel's point
        return torch.zeros(points.shape[:-1], dtype=torch.bool, device=points.device).scatter_(-1, winners, True)

    @torch.no_grad()
    def _max_winners(self, points: Tensor) -> Tensor:
        """(B, K, C): each cloud's points that hold some channel's maximum, K = the most any cloud has.

        A cloud with fewer winners is padded with some of its other points: they lose every maximum, so they
        change neither the pooled features nor the gradients."""
        held = self.max_winners(points).to(torch.uint8)
        k = int(held.sum(-1).max())
        order = torch.argsort(held, dim=-1, descending=True, stable=True)[..., :k]
        return torch.gather(points, -2, order.unsqueeze(-1).expand(*order.shape, points.shape[-1]))


class StateEncoder(nn.Module):
    """Linear(D, 64) → ReLU → Linear(64, out): DP3's proprioception MLP."""

    def __init__(self, in_dim: int, out_dim: int = 64, hidden: int = 64):
        super().__init__()
        self.net = nn.Sequential(nn.Linear(in_dim, hidden), nn.ReLU(), nn.Linear(hidden, out_dim))

    def forward(self, x: Tensor) -> Tensor:
        return self.net(x)


def _rgb_encoder(config: FocalConfig, image_features: dict) -> DiffusionRgbEncoder:
    spec = diffusion_spec(
        input_features=image_features,
        resize_shape=config.resize_shape,
        crop_shape=config.crop_shape,
        crop_is_random=config.crop_is_random,
        vision_backbone=config.vision_backbone,
        pretrained_backbone_weights=config.pretrained_backbone_weights,
        use_group_norm=config.use_group_norm,
        spatial_softmax_num_keypoints=config.spatial_softmax_num_keypoints,
    )
    return DiffusionRgbEncoder(spec)


class ObservationEncoder(nn.Module):
    """Encodes every used observation key for each of the n_obs steps and flattens to (B, n_obs · feat_dim).

    Built from focal's config or from dp3's, which names what it reads and the widths with the same fields, so
    the two policies condition on one encoder."""

    def __init__(self, config: FocalConfig):
        super().__init__()
        self.n_obs_steps = config.n_obs_steps
        self.pointcloud_key = config.used_pointcloud_key
        self.state_key = config.used_state_key
        self.env_state_key = config.used_env_state_key
        self.image_keys = list(config.used_image_keys)
        feat_dim = 0
        if self.pointcloud_key:
            channels = 6 if config.use_pointcloud_color else 3
            self.pointcloud = PointCloudEncoder(channels, config.pointcloud_feature_dim)
            feat_dim += config.pointcloud_feature_dim
        if self.state_key:
            dim = config.input_features[self.state_key].shape[0]
            self.state = StateEncoder(dim, config.state_feature_dim)
            feat_dim += config.state_feature_dim
        if self.env_state_key:
            dim = config.input_features[self.env_state_key].shape[0]
            self.env_state = StateEncoder(dim, config.state_feature_dim)
            feat_dim += config.state_feature_dim
        if self.image_keys:
            feats = {k: config.input_features[k] for k in self.image_keys}
            n_enc = len(self.image_keys) if config.use_separate_rgb_encoder_per_camera else 1
            self.rgb = nn.ModuleList([_rgb_encoder(config, feats) for _ in range(n_enc)])
            feat_dim += self.rgb[0].feature_dim * len(self.image_keys)
        self.feature_dim = feat_dim
        self.global_cond_dim = feat_dim * config.n_obs_steps

    def encode_image(self, key: str, frames: Tensor) -> Tensor:
        """RGB frames (N, 3, H, W) of camera `key` → (N, image feature dim)."""
        i = self.image_keys.index(key)
        return self.rgb[i if len(self.rgb) > 1 else 0](frames)

    def forward(self, obs: dict[str, Tensor], image_features: dict[str, Tensor] | None = None) -> Tensor:
        """obs[key]: (B, n_obs, *feature_shape) → (B, n_obs · feature_dim).

        ``image_features[key]`` (B, n_obs, F), when given, replaces encoding that camera's frames (the policy
        encodes each frame once at inference, see `FocalPolicy.select_action`)."""
        parts: list[Tensor] = []
        if self.pointcloud_key:
            parts.append(_per_step(self.pointcloud, obs[self.pointcloud_key]))
        if self.state_key:
            parts.append(self.state(obs[self.state_key]))
        if self.env_state_key:
            parts.append(self.env_state(obs[self.env_state_key]))
        for i, key in enumerate(self.image_keys):
            if image_features is not None and key in image_features:
                parts.append(image_features[key])
                continue
            encoder = self.rgb[i if len(self.rgb) > 1 else 0]
            parts.append(_per_step(encoder, obs[key]))
        feats = torch.cat(parts, dim=-1)  # (B, n_obs, feature_dim)
        return feats.flatten(1)


def _per_step(module: nn.Module, x: Tensor) -> Tensor:
    """Apply a per-frame encoder to (B, T, ...) by folding T into the batch."""
    b, t = x.shape[:2]
    return module(x.flatten(0, 1)).unflatten(0, (b, t))
