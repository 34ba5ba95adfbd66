"""The velocity network: LeRobot's conditional 1-D U-Net with FiLM, reused rather than rewritten.

LeRobot's `DiffusionConditionalUnet1d` is exactly the DP/DP3/FlowPolicy U-Net the paper uses (sinusoidal
time embedding → MLP, FiLM scale+bias, two residual blocks per level, strided-conv down / transposed-conv up).
Only `DiffusionConfig`'s horizon check is stricter than the network needs (it demands L % 2**len(down_dims));
the network itself downsamples len(down_dims) − 1 times, so L = 12 with three levels (12 → 6 → 3) is fine.
We therefore build the U-Net from a minimal spec object instead of a `DiffusionConfig`.
"""

from __future__ import annotations

from types import SimpleNamespace

from lerobot.policies.diffusion.modeling_diffusion import DiffusionConditionalUnet1d
from torch import Tensor, nn


def unet_downsampling_factor(down_dims: tuple[int, ...] | list[int]) -> int:
    """How many times the horizon is halved: one stride-2 conv between consecutive levels."""
    return 2 ** (len(down_dims) - 1)


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
        spec = SimpleNamespace(
            action_feature=SimpleNamespace(shape=(action_dim,)),
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
