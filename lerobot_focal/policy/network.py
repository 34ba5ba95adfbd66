"""The velocity network: LeRobot's conditional 1-D U-Net with FiLM, reused rather than rewritten.

LeRobot's `DiffusionConditionalUnet1d` is exactly the DP/DP3/FlowPolicy U-Net the paper uses (sinusoidal
time embedding → MLP, FiLM scale+bias, two residual blocks per level, strided-conv down / transposed-conv up).
Only `DiffusionConfig`'s horizon check is stricter than the network needs (it demands L % 2**len(down_dims));
the network itself downsamples len(down_dims) − 1 times, so L = 12 with three levels (12 → 6 → 3) is fine.
The U-Net never reads the horizon, so it is built from a real `DiffusionConfig` (`diffusion_spec`) carrying our
values and any horizon that passes that check: every field LeRobot's module reads, today or in a later
version, is there with LeRobot's own default.
"""

from __future__ import annotations

from typing import Any

from lerobot.configs.types import FeatureType, PolicyFeature
from lerobot.policies.diffusion.configuration_diffusion import DiffusionConfig
from lerobot.policies.diffusion.modeling_diffusion import DiffusionConditionalUnet1d
from lerobot.utils.constants import ACTION
from torch import Tensor, nn


def diffusion_spec(*, action_dim: int = 1, input_features: dict | None = None, **fields: Any) -> DiffusionConfig:
    """A `DiffusionConfig` to build LeRobot's diffusion modules (U-Net, RGB encoder) with focal's settings.

    Fields the config's own ``__post_init__`` would rewrite (``crop_shape`` from ``resize_shape``) are set after
    construction, so the modules see exactly the values given here.
    """
    levels = len(fields.get("down_dims", DiffusionConfig.down_dims))
    after = {k: fields.pop(k) for k in ("crop_shape",) if k in fields}
    spec = DiffusionConfig(
        device="cpu",  # a description of the modules, never moved anywhere itself
        horizon=2**levels,
        n_action_steps=1,
        input_features=dict(input_features or {}),
        output_features={ACTION: PolicyFeature(type=FeatureType.ACTION, shape=(action_dim,))},
        push_to_hub=False,
        **fields,
    )
    for key, value in after.items():
        setattr(spec, key, value)
    return spec


class VelocityUnet(nn.Module):
    """v_θ(M, τ, cond): maps a (B, L, d) flow state, flow time (B,) and a global condition to a velocity."""

    def __init__(
        self,
        action_dim: int,
        global_cond_dim: int,
        down_dims: tuple[int, ...],
        kernel_size: int,
        n_groups: int,
        time_embed_dim: int,
        use_film_scale_modulation: bool = True,
        gradient_checkpointing: bool = False,
        time_scale: float = 99.0,
    ):
        super().__init__()
        spec = diffusion_spec(
            action_dim=action_dim,
            down_dims=tuple(down_dims),
            kernel_size=kernel_size,
            n_groups=n_groups,
            diffusion_step_embed_dim=time_embed_dim,
            use_film_scale_modulation=use_film_scale_modulation,
            gradient_checkpointing=gradient_checkpointing,
        )
        self.unet = DiffusionConditionalUnet1d(spec, global_cond_dim=global_cond_dim)
        # The authors feed τ·99 to the sinusoidal embedding (a DDPM-like timestep range); kept for parity.
        self.time_scale = time_scale

    def forward(self, x: Tensor, t: Tensor, global_cond: Tensor) -> Tensor:
        return self.unet(x, t * self.time_scale, global_cond=global_cond)
