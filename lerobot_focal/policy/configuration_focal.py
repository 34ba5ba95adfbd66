"""`FocalConfig`: every knob of FocalPolicy, with the paper's settings as defaults.

Registered as LeRobot policy type ``focal`` (``--policy.type=focal``). The class name ``FocalConfig`` and this
module's name matter: LeRobot derives ``FocalPolicy`` in ``modeling_focal`` and
``make_focal_pre_post_processors`` in ``processor_focal`` from them by string replacement.

Windows (n_obs = 2, H = 4, N = 3, L = 12), all relative to the current step t:
    observations  t-1, t                      (observation_delta_indices = [-1, 0])
    macro-trajectory  a_t … a_{t+L-1}         (action_delta_indices = [0 … L-1])
    proximal chunk    a_t … a_{t+H-1}         supervised by L_time *and* executed — the same window.
The authors' code supervises steps 0..H-1 of a window starting at t-1 but executes steps 1..H; starting the
action window at t removes that off-by-one.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import ClassVar

from lerobot.configs import NormalizationMode, PreTrainedConfig
from lerobot.configs.types import FeatureType
from lerobot.optim import DiffuserSchedulerConfig
from lerobot.policies.rtc.configuration_rtc import RTCConfig
from lerobot.utils.constants import ACTION, OBS_ENV_STATE, OBS_STATE

from lerobot_focal.config_errors import (
    ConfigError,
    check_adamw,
    reports_config_errors,
    require_choice,
    require_non_negative,
    require_positive,
)
from lerobot_focal.constants import OBS_POINTCLOUD
from lerobot_focal.policy.ablations import ABLATIONS, PAPER_METHOD, resolve_method_switches
from lerobot_focal.policy.depth_cloud_settings import (
    DepthCloudConfig,
    declare_cloud_input,
    validate_depth_cloud,
)
from lerobot_focal.policy.ema import check_ema_settings
from lerobot_focal.policy.method_groups import MOVED_METHOD_FIELDS, AnchorConfig, LossConfig
from lerobot_focal.policy.objective import ObjectiveSpec
from lerobot_focal.policy.optimizer import FusedAdamWConfig
from lerobot_focal.policy.saved_config_upgrade import install as read_configs_saved_before_moves
from lerobot_focal.policy.time_samplers import TimeSamplerSpec

# ABLATIONS and PAPER_METHOD live in `ablations`; they stay importable from here, where users found them.
__all__ = ["ABLATIONS", "PAPER_METHOD", "FocalConfig", "FocalConfigError", "check_feature_shapes",
           "pointcloud_normalization_mapping"]

class FocalConfigError(ConfigError):
    """A `FocalConfig` setting that cannot work; the message names it and the fix.

    A `ConfigError`, not a ValueError, so that it reaches the `lerobot-train` user (see `config_errors`).
    """


def pointcloud_normalization_mapping() -> dict[str, NormalizationMode]:
    """LeRobot's normalisation mode per feature type, as the point-cloud policies (focal, dp3) normalise."""
    return {
        # A point cloud is a STATE feature to LeRobot; MIN_MAX per xyz channel is DP3's "limits" normaliser.
        "VISUAL": NormalizationMode.MEAN_STD,
        "STATE": NormalizationMode.MIN_MAX,
        # observation.environment_state (object poses); dimensions constant in the demos keep a unit scale
        # (see stats.widen_degenerate_min_max).
        "ENV": NormalizationMode.MIN_MAX,
        "ACTION": NormalizationMode.MIN_MAX,
    }


def check_feature_shapes(config: PreTrainedConfig, policy: str) -> None:
    """The shapes of what a point-cloud policy (focal, dp3) reads, before its encoder is sized from them.

    `config` names what it reads with ``used_pointcloud_key`` / ``used_state_key`` / ``used_env_state_key`` (None:
    not read) and ``use_pointcloud_color``. A ValueError names the feature, its shape and the one expected.
    """
    action = config.output_features.get(ACTION) if config.output_features else None
    if action is None or action.type is not FeatureType.ACTION or len(action.shape) != 1:
        raise ValueError(
            f"{policy} needs a 1-D '{ACTION}' output feature; got {action}. Check the dataset's "
            "'action' feature (shape (d,))."
        )
    pc = config.used_pointcloud_key
    if pc:
        shape = tuple(config.input_features[pc].shape)
        if len(shape) != 2 or shape[1] not in (3, 6):
            raise ValueError(
                f"'{pc}' must have shape (num_points, 3) for xyz or (num_points, 6) for xyz+rgb; got {shape}."
            )
        if config.use_pointcloud_color and shape[1] != 6:
            raise ValueError(f"use_pointcloud_color=true needs a (P, 6) point cloud; '{pc}' has shape {shape}.")
    for key in (config.used_state_key, config.used_env_state_key):
        if key and len(config.input_features[key].shape) != 1:
            raise ValueError(
                f"'{key}' must be a flat vector (D,); got shape {tuple(config.input_features[key].shape)}."
            )


@PreTrainedConfig.register_subclass("focal")
@reports_config_errors("--policy.type=focal", FocalConfigError)
@dataclass
class FocalConfig(PreTrainedConfig):
    """Configuration of FocalPolicy: windows, observations, network, method switches, EMA and optimiser.

    Defaults are the paper's settings (its hyper-parameter table); `configs/focal_cpu*.json` shrink the network
    for CPUs. Every ablation of the paper is a switch here (`ablation` sets a group of the fields below). Three
    groups nest, as LeRobot's own policies nest theirs: the sampler (`anchor`), the loss (`loss`) and the
    deployed depth → cloud settings (`depth_cloud`); a `config.json` saved with their old flat keys loads
    (`MOVED_FIELDS`). The EMA and optimiser fields stay flat, named as LeRobot's diffusion and `diffusion_ema`
    name them.

    Args:
        n_obs_steps: Observation steps in the condition (t−1, t), concatenated into the FiLM vector.
        chunk_size: H, the proximal chunk: supervised by L_time and executed before re-planning.
        n_chunks: N, chunks in the macro-trajectory; L = N·H steps are predicted (and regularised by L_freq).
        n_action_steps: Actions executed per network evaluation. None → H, the paper's "execution window =
            supervised window"; up to L executes into the foresight part of the macro-trajectory (fewer
            re-plans, as LeRobot's diffusion executes 8 of 16), which only L_freq shapes.
        drop_n_last_frames: Frames at each episode's end that never start a training window; None → H − 1, so
            the supervised proximal chunk is always real data; the foresight part past the episode end repeats
            the last action (LeRobot's edge padding, the same as DP3's replicate padding).
        normalization_mapping: LeRobot normalisation mode per feature type. A point cloud is a STATE feature
            (MIN_MAX per xyz channel, DP3's limits); ENV (object poses) is MIN_MAX too; dimensions that are
            constant in the data keep a unit scale (see `stats.widen_degenerate_min_max`).
        pointcloud_key: Observation key of the point cloud, (P, 3) or (P, 6) with colour.
        use_pointcloud: Read the point cloud when the dataset has one.
        use_pointcloud_color: Use xyz+rgb when the cloud has 6 channels (xyz only otherwise).
        pointcloud_feature_dim: Output width of the DP3 point-cloud MLP encoder.
        depth_cloud: Depth → point cloud in the preprocessor, for robots that record depth
            (`--policy.depth_cloud.from_depth=observation.images.front_depth` and a crop box); its fields are
            documented in `DepthCloudConfig`, and a checkpoint saves them with the camera's intrinsics.
        use_state: Read `observation.state` (proprioception) through a small MLP.
        use_env_state: Read `observation.environment_state` (e.g. MetaWorld's object poses) through the same kind
            of MLP; off by default, as in the paper (point cloud + state).
        state_feature_dim: Output width of the state MLP(s).
        use_images: Read RGB `observation.images.*` through LeRobot's diffusion RGB encoder (the presets turn this
            off, so a dataset that also holds frames does not silently add a ResNet to the condition).
        vision_backbone: torchvision backbone of the RGB encoder.
        pretrained_backbone_weights: torchvision weights name; None trains from scratch. Nothing is downloaded at
            run time: names such as "ResNet18_Weights.IMAGENET1K_V1" work only where the weights are cached.
        use_group_norm: GroupNorm instead of BatchNorm in the backbone (not with pretrained weights).
        spatial_softmax_num_keypoints: Keypoints of the RGB encoder's spatial softmax.
        resize_shape: (H, W) images are resized to before cropping; None keeps them.
        crop_shape: (H, W) crop; None disables cropping.
        crop_is_random: Random crop in training (centre crop at inference).
        use_separate_rgb_encoder_per_camera: One encoder per camera instead of a shared one.
        down_dims: U-Net channel widths per level; L must be divisible by 2^(levels − 1).
        kernel_size: U-Net 1-D convolution kernel.
        n_groups: GroupNorm groups in the U-Net blocks.
        time_embed_dim: Width of the sinusoidal flow-time embedding.
        use_film_scale_modulation: FiLM with scale and bias (False: bias only).
        gradient_checkpointing: Trade compute for memory in the U-Net.
        time_scale: The flow time is fed to the network as t·time_scale (99, as the authors' code).
        ablation: One of `ABLATIONS` (the paper's ablations); sets the method switches it names (the keys of
            `PAPER_METHOD`: the sampler and its μ_r, σ_r, r, the loss and its windows, weights and band, the
            consistency target). Those default to None, "not given", and are resolved to the ablation's value or
            the paper's; giving one that contradicts the ablation is a `FocalConfigError`.
        anchor: How the flow time τ and the anchor r are drawn (`--policy.anchor.kind=logit_normal`, LAS; the
            fields are documented in `method_groups.AnchorConfig`).
        loss: The training loss (`--policy.loss.kind=fco`, the Foresight Composite Objective; the fields are
            documented in `method_groups.LossConfig`).
        consistency_target: θ⁻ of the consistency target: "ema" (the paper) or "online" weights under stop-grad
            (the authors' code, and FlowPolicy's).
        num_inference_steps: Network evaluations per chunk (1, the method; > 1 integrates with Euler steps).
        inference_noise_scale: Standard deviation of the starting noise M_0 at inference. 1 samples the
            distribution the flow was trained from (the method); below 1 is a sampling temperature that trades
            the diversity of chunks for their consistency from one re-plan to the next (0: deterministic).
        use_ema: Keep an EMA copy of the network (a frozen submodule saved with the checkpoint).
        ema_power: DP3's EMA warm-up: decay = 1 − (1 + step)^−power.
        ema_min_decay: Lower clip of the decay.
        ema_max_decay: Upper clip of the decay (0.9999).
        ema_update_after_step: EMA updates before this step copy the weights.
        use_ema_for_inference: Act with the EMA weights (True) or the online ones.
        check_finite: Refuse batches with NaN/inf, naming the key, instead of silently training on them (one
            reduction per key per step).
        rtc_config: LeRobot's real-time chunking settings; None (training, lerobot-eval, synchronous rollout)
            leaves inference unchanged. `lerobot-rollout --inference.type=rtc` sets it (`--inference.rtc.*`);
            then each chunk is the whole macro-trajectory, guided towards the previous chunk (policy/rtc.py).
        optimizer_lr: AdamW learning rate.
        optimizer_betas: AdamW betas.
        optimizer_eps: AdamW epsilon.
        optimizer_weight_decay: AdamW weight decay.
        optimizer_grad_clip_norm: Gradient-norm clip applied by lerobot-train. The authors never clip; LeRobot's
            default of 10 only acts on exploding gradients.
        scheduler_name: diffusers learning-rate schedule.
        scheduler_warmup_steps: Warm-up steps of that schedule.
    """

    # Each field is documented once, in the Args block above.
    #: Flat keys of configs saved before the groups existed → (group, field) (see `saved_config_upgrade`).
    MOVED_FIELDS: ClassVar[dict[str, tuple[str, str]]] = {
        **{f"pointcloud_{name}": ("depth_cloud", name)
           for name in ("from_depth", "camera_info", "camera", "crop_min", "crop_max", "num_points", "voxel_size",
                        "depth_unit", "min_depth")},
        **MOVED_METHOD_FIELDS,
    }

    # --- windows -------------------------------------------------------------------------------------------
    n_obs_steps: int = 2
    chunk_size: int = 4
    n_chunks: int = 3
    n_action_steps: int | None = None
    drop_n_last_frames: int | None = None
    normalization_mapping: dict[str, NormalizationMode] = field(default_factory=pointcloud_normalization_mapping)

    # --- observations --------------------------------------------------------------------------------------
    pointcloud_key: str = OBS_POINTCLOUD
    use_pointcloud: bool = True
    use_pointcloud_color: bool = False
    pointcloud_feature_dim: int = 64
    depth_cloud: DepthCloudConfig = field(default_factory=DepthCloudConfig)
    use_state: bool = True
    use_env_state: bool = False
    state_feature_dim: int = 64
    use_images: bool = True
    vision_backbone: str = "resnet18"
    pretrained_backbone_weights: str | None = None
    use_group_norm: bool = True
    spatial_softmax_num_keypoints: int = 32
    resize_shape: tuple[int, int] | None = None
    crop_shape: tuple[int, int] | None = None
    crop_is_random: bool = True
    use_separate_rgb_encoder_per_camera: bool = False

    # --- network -------------------------------------------------------------------------------------------
    down_dims: tuple[int, ...] = (512, 1024, 2048)
    kernel_size: int = 5
    n_groups: int = 8
    time_embed_dim: int = 128
    use_film_scale_modulation: bool = True
    gradient_checkpointing: bool = False
    time_scale: float = 99.0

    # --- method: sampling, loss, target (switches None: "not given", resolved by `ablations`) ---------------
    ablation: str | None = None
    anchor: AnchorConfig = field(default_factory=AnchorConfig)
    loss: LossConfig = field(default_factory=LossConfig)
    consistency_target: str | None = None
    num_inference_steps: int = 1
    inference_noise_scale: float = 1.0

    # --- EMA (DP3's schedule) ------------------------------------------------------------------------------
    use_ema: bool = True
    ema_power: float = 0.75
    ema_min_decay: float = 0.0
    ema_max_decay: float = 0.9999
    ema_update_after_step: int = 0
    use_ema_for_inference: bool = True

    # --- inputs at run time --------------------------------------------------------------------------------
    check_finite: bool = True
    rtc_config: RTCConfig | None = None

    # --- optimisation (paper Table "Hyperparameters setup") ------------------------------------------------
    optimizer_lr: float = 1e-4
    optimizer_betas: tuple[float, float] = (0.95, 0.999)
    optimizer_eps: float = 1e-8
    optimizer_weight_decay: float = 1e-6
    optimizer_grad_clip_norm: float = 10.0
    scheduler_name: str = "cosine"
    scheduler_warmup_steps: int = 500

    def __post_init__(self) -> None:
        # A ValueError from here (the specs' own checks included) reaches the CLI user as a FocalConfigError.
        super().__post_init__()
        resolve_method_switches(self, FocalConfigError)
        self._validate()

    def _validate(self) -> None:
        if self.drop_n_last_frames is None:
            self.drop_n_last_frames = self.chunk_size - 1
        if self.n_obs_steps < 1 or self.chunk_size < 1 or self.n_chunks < 1:
            raise FocalConfigError(
                f"n_obs_steps, chunk_size and n_chunks must be ≥ 1 (got {self.n_obs_steps}, "
                f"{self.chunk_size}, {self.n_chunks})."
            )
        if self.n_action_steps is None:
            self.n_action_steps = self.chunk_size
        if not 1 <= self.n_action_steps <= self.horizon:
            raise FocalConfigError(
                f"n_action_steps={self.n_action_steps} must be between 1 and the macro horizon L = "
                f"chunk_size·n_chunks = {self.horizon}: a chunk step executes actions of the trajectory it "
                f"predicts. Fix: leave it unset (executes the proximal chunk, H = {self.chunk_size}) or lower it."
            )
        factor = self.unet_downsampling_factor
        if self.horizon % factor != 0:
            ok = [h for h in range(factor, 4 * factor + 1, factor)]
            raise FocalConfigError(
                f"The U-Net with down_dims={tuple(self.down_dims)} halves the horizon {len(self.down_dims) - 1} "
                f"times, so the macro horizon L = chunk_size·n_chunks must be a multiple of {factor}; got "
                f"L = {self.chunk_size}·{self.n_chunks} = {self.horizon}. Fix: choose chunk_size/n_chunks with L "
                f"in {ok}, or use fewer down_dims."
            )
        if self.consistency_target not in ("ema", "online"):
            raise FocalConfigError(f"consistency_target must be 'ema' or 'online', got {self.consistency_target!r}.")
        if self.consistency_target == "ema" and not self.use_ema:
            raise FocalConfigError("consistency_target='ema' needs use_ema=true (or set consistency_target='online').")
        if self.num_inference_steps < 1:
            raise FocalConfigError(f"num_inference_steps must be ≥ 1, got {self.num_inference_steps}.")
        if not 0.0 <= self.inference_noise_scale < float("inf"):
            raise FocalConfigError(
                f"inference_noise_scale must be a finite number ≥ 0, got {self.inference_noise_scale} (1 samples the "
                "flow's own prior; 0 starts every chunk from M_0 = 0, one deterministic trajectory per observation)."
            )
        check_ema_settings(self)
        self._validate_network_and_inputs()
        validate_depth_cloud(self)
        # Building the specs validates every method switch and loss weight, with a message naming the range.
        self.objective_spec()
        self.time_sampler_spec()
        self._validate_freq_cutoff()
        check_adamw(lr=self.optimizer_lr, betas=self.optimizer_betas, eps=self.optimizer_eps,
                    weight_decay=self.optimizer_weight_decay, grad_clip_norm=self.optimizer_grad_clip_norm,
                    prefix="optimizer_")
        require_non_negative(scheduler_warmup_steps=self.scheduler_warmup_steps)
        from diffusers.optimization import SchedulerType  # already imported by lerobot.optim

        require_choice("scheduler_name", self.scheduler_name, [t.value for t in SchedulerType])

    def _validate_network_and_inputs(self) -> None:
        require_non_negative(drop_n_last_frames=self.drop_n_last_frames)
        require_positive(
            pointcloud_feature_dim=self.pointcloud_feature_dim, state_feature_dim=self.state_feature_dim,
            spatial_softmax_num_keypoints=self.spatial_softmax_num_keypoints, time_scale=self.time_scale,
        )
        for name in ("resize_shape", "crop_shape"):
            shape = getattr(self, name)
            if shape is not None and (len(shape) != 2 or min(shape) < 1):
                raise ValueError(f"{name} must be (height, width) with both ≥ 1 pixel, or unset; got {shape}.")
        dims = tuple(self.down_dims)
        if not dims or min(dims) < 1:
            raise ValueError(f"down_dims must list ≥ 1 positive channel width, got {dims}.")
        if self.n_groups < 1 or any(d % self.n_groups for d in dims):
            raise ValueError(
                f"n_groups={self.n_groups} must be ≥ 1 and divide every U-Net width down_dims={dims} (GroupNorm "
                "splits each block's channels into n_groups groups)."
            )
        if self.kernel_size < 1 or self.kernel_size % 2 == 0:
            raise ValueError(
                f"kernel_size must be an odd number ≥ 1 (the U-Net pads kernel_size // 2 on each side to keep the "
                f"horizon), got {self.kernel_size}."
            )
        if self.time_embed_dim < 4 or self.time_embed_dim % 2:
            raise ValueError(
                f"time_embed_dim must be an even number ≥ 4 (half sines, half cosines), got {self.time_embed_dim}."
            )
        import torchvision  # already imported by LeRobot's diffusion encoder, which the network uses

        # The RGB encoder replaces a ResNet's pooling and head, so only ResNets fit.
        resnets = [m for m in torchvision.models.list_models(module=torchvision.models) if m.startswith("resnet")]
        require_choice("vision_backbone", self.vision_backbone, resnets)
        if self.pretrained_backbone_weights is not None and self.use_group_norm:
            raise ValueError(
                f"pretrained_backbone_weights={self.pretrained_backbone_weights!r} holds BatchNorm statistics, which "
                "use_group_norm=true would replace: set --policy.use_group_norm=false with pretrained weights."
            )

    def _validate_freq_cutoff(self) -> None:
        """The "low"/"high" DCT bands split the L_freq window's coefficients at freq_cutoff: both must be non-empty."""
        loss = self.loss
        if loss.regularizer != "freq" or loss.freq_band == "all":
            return
        n = self.horizon if loss.freq_window == "macro" else self.chunk_size
        cutoff = loss.freq_cutoff if loss.freq_cutoff is not None else max(1, n // 2)
        if not 0 < cutoff < n:
            raise ValueError(
                f"loss.freq_cutoff must be in (0, {n}) for loss.freq_band={loss.freq_band!r}: the L_freq window "
                f"({loss.freq_window}, {n} steps) has DCT coefficients 0…{n - 1} and the cutoff is the first "
                f"'high' one; got {cutoff}{' (the default, L/2)' if loss.freq_cutoff is None else ''}."
            )

    def set_dataset_feature_metadata(self, features: dict) -> None:
        """LeRobot hook (`make_policy`, after it filled `input_features` from the dataset): with
        `depth_cloud.from_depth`, declare the cloud the preprocessor makes from the dataset's depth as an input."""
        declare_cloud_input(self, features)

    # --- derived -------------------------------------------------------------------------------------------
    @property
    def horizon(self) -> int:
        """L = N·H, the macro-trajectory length the network predicts."""
        return self.chunk_size * self.n_chunks

    @property
    def unet_downsampling_factor(self) -> int:
        """How many times the U-Net halves the horizon: one stride-2 conv between consecutive levels."""
        return 2 ** (len(self.down_dims) - 1)

    def objective_spec(self) -> ObjectiveSpec:
        return ObjectiveSpec(**self.loss.values(), chunk_size=self.chunk_size, cfm_delta=self.anchor.adjacent_delta)

    def time_sampler_spec(self) -> TimeSamplerSpec:
        return TimeSamplerSpec(**self.anchor.values())

    # Which of the (possibly many) input features the policy uses. `make_policy` fills input_features with
    # every non-action dataset key, so the policy must pick its own and ignore the rest.
    @property
    def used_pointcloud_key(self) -> str | None:
        return self.pointcloud_key if self.use_pointcloud and self.pointcloud_key in self.input_features else None

    @property
    def used_state_key(self) -> str | None:
        return OBS_STATE if self.use_state and OBS_STATE in self.input_features else None

    @property
    def used_env_state_key(self) -> str | None:
        return OBS_ENV_STATE if self.use_env_state and OBS_ENV_STATE in self.input_features else None

    @property
    def used_image_keys(self) -> list[str]:
        if not self.use_images:
            return []
        # Depth maps and other non-RGB visual features are not fed to the RGB encoder.
        return [k for k, ft in self.image_features.items() if len(ft.shape) == 3 and ft.shape[0] == 3]

    @property
    def used_observation_keys(self) -> list[str]:
        keys = [self.used_pointcloud_key, self.used_state_key, self.used_env_state_key, *self.used_image_keys]
        return [k for k in keys if k]

    def validate_features(self) -> None:
        check_feature_shapes(self, "FocalPolicy")
        if not self.used_observation_keys:
            available = sorted(self.input_features) if self.input_features else []
            raise ValueError(
                "FocalPolicy found no observation it can use. It reads "
                f"'{self.pointcloud_key}' (P, 3|6), '{OBS_STATE}' (D,), RGB 'observation.images.*' (3, H, W) "
                f"and, with use_env_state=true, '{OBS_ENV_STATE}'. The dataset/env provides: {available}. "
                "Fix: record one of those keys, rename yours with --rename_map, or enable the matching use_* flag."
            )
        images = self.used_image_keys
        if images:
            first = tuple(self.input_features[images[0]].shape)
            for key in images[1:]:
                if tuple(self.input_features[key].shape) != first:
                    raise ValueError(f"All cameras must share one shape: '{key}' differs from '{images[0]}' {first}.")
            if self.crop_shape is not None and self.resize_shape is None:
                if self.crop_shape[0] > first[1] or self.crop_shape[1] > first[2]:
                    raise ValueError(f"crop_shape {self.crop_shape} does not fit the images {first}.")

    # --- LeRobot hooks -------------------------------------------------------------------------------------
    def get_optimizer_preset(self) -> FusedAdamWConfig:
        return FusedAdamWConfig(
            lr=self.optimizer_lr,
            betas=self.optimizer_betas,
            eps=self.optimizer_eps,
            weight_decay=self.optimizer_weight_decay,
            grad_clip_norm=self.optimizer_grad_clip_norm,
        )

    def get_scheduler_preset(self) -> DiffuserSchedulerConfig:
        return DiffuserSchedulerConfig(name=self.scheduler_name, num_warmup_steps=self.scheduler_warmup_steps)

    @property
    def observation_delta_indices(self) -> list[int]:
        return list(range(1 - self.n_obs_steps, 1))

    @property
    def action_delta_indices(self) -> list[int]:
        return list(range(self.horizon))

    @property
    def reward_delta_indices(self) -> None:
        return None


read_configs_saved_before_moves()
