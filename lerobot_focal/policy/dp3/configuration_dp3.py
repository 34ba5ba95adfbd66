"""Configuration of ``dp3``: 3D Diffusion Policy (DP3) as a LeRobot policy, for the benchmark's point-cloud baseline.

Registered as LeRobot policy type ``dp3`` (``--policy.type=dp3``). It subclasses ``DiffusionEmaConfig``: every
``--policy.*`` flag of ``diffusion`` / ``diffusion_ema`` works the same (U-Net, noise scheduler, EMA,
optimiser), and the fields below choose the observation encoder. The encoder is focal's (``PointCloudEncoder`` and
the state MLP, ``lerobot_focal.policy.encoders``), and its widths carry focal's field names, so a benchmark gives
both policies the same encoder with the same flags and the comparison is of the method, not of the encoder.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from lerobot.configs import NormalizationMode, PreTrainedConfig
from lerobot.configs.types import PolicyFeature
from lerobot.utils.constants import OBS_ENV_STATE, OBS_STATE

from lerobot_focal.config_errors import reports_config_errors, require_positive
from lerobot_focal.constants import OBS_POINTCLOUD
from lerobot_focal.policy.configuration_focal import check_feature_shapes, pointcloud_normalization_mapping
from lerobot_focal.policy.depth_cloud_settings import DepthCloudConfig
from lerobot_focal.policy.diffusion_ema.configuration_diffusion_ema import DiffusionEmaConfig


@PreTrainedConfig.register_subclass("dp3")
@reports_config_errors("--policy.type=dp3")
@dataclass
class DP3Config(DiffusionEmaConfig):
    """``DiffusionEmaConfig`` conditioned on a point cloud and the agent state, with DP3's defaults.

    DP3's inputs are the cloud and the agent state only: cameras are never read, and
    ``observation.environment_state`` only with ``use_env_state``. A dataset may hold more (LeRobot lists every
    feature as an input); the policy, its queues and its normaliser take just these.

    Normalisation is focal's (``make_focal_pre_post_processors``): the cloud is a STATE feature, MIN_MAX per xyz
    channel over the dataset (DP3's "limits" normaliser, into [-1, 1]); statistics stored per point slot are pooled
    per channel, since after farthest-point sampling a slot holds a different point every frame; a dimension
    constant in the demonstrations (of the cloud, the state, the action) keeps a unit scale instead of being
    multiplied by 1e8 (``lerobot_focal.policy.stats``). Only the features the policy reads are normalised.

    Global condition of the U-Net: ``n_obs_steps · (pointcloud_feature_dim + state_feature_dim)`` (DP3's 2 · (64 +
    64) = 256 by default), plus ``state_feature_dim`` per step with ``use_env_state``.

    Args (in addition to ``DiffusionEmaConfig``'s):
        pointcloud_key: Observation key of the point cloud, (P, 3) or (P, 6) with colour.
        use_pointcloud_color: Read xyz+rgb of a (P, 6) cloud (DP3 reads xyz only).
        pointcloud_feature_dim: Output width of the point-cloud encoder (focal's field, DP3's 64).
        state_feature_dim: Output width of the state MLP (focal's field, DP3's 64).
        use_env_state: Also read ``observation.environment_state`` through a second state MLP (not DP3's input).

    Defaults changed from ``DiffusionEmaConfig`` to DP3's: ``horizon`` 16 and ``n_action_steps`` 8 (with
    ``n_obs_steps`` 2 and ``drop_n_last_frames`` 7, already LeRobot's), ``prediction_type`` ``"sample"`` (DP3 predicts
    the clean action trajectory; LeRobot's diffusion the noise), and ``normalization_mapping`` with ENV as MIN_MAX
    for ``use_env_state``. Inference stays DDIM with 10 steps on the EMA weights.
    """

    horizon: int = 16
    n_action_steps: int = 8
    prediction_type: str = "sample"
    normalization_mapping: dict[str, NormalizationMode] = field(default_factory=pointcloud_normalization_mapping)

    pointcloud_key: str = OBS_POINTCLOUD
    use_pointcloud_color: bool = False
    pointcloud_feature_dim: int = 64
    state_feature_dim: int = 64
    use_env_state: bool = False

    def __post_init__(self) -> None:
        super().__post_init__()
        require_positive(pointcloud_feature_dim=self.pointcloud_feature_dim, state_feature_dim=self.state_feature_dim)

    # What the encoder reads (focal's ObservationEncoder takes the same names from focal's config).
    @property
    def used_pointcloud_key(self) -> str:
        return self.pointcloud_key

    @property
    def used_state_key(self) -> str:
        return OBS_STATE

    @property
    def used_env_state_key(self) -> str | None:
        return OBS_ENV_STATE if self.use_env_state else None

    @property
    def used_image_keys(self) -> list[str]:
        return []

    @property
    def used_observation_keys(self) -> list[str]:
        return [k for k in (self.pointcloud_key, OBS_STATE, self.used_env_state_key) if k]

    @property
    def image_features(self) -> dict[str, PolicyFeature]:
        """Empty: LeRobot's diffusion code stacks and queues every camera listed here, and DP3 reads none."""
        return {}

    @property
    def depth_cloud(self) -> DepthCloudConfig:
        """Off: focal's preprocessor can make the cloud from a depth map; dp3 reads a recorded cloud only."""
        return DepthCloudConfig()

    def validate_features(self) -> None:
        """Refuse, before the encoder is sized, a dataset or env without the inputs DP3 conditions on."""
        available = sorted(self.input_features or {})
        missing = [k for k in self.used_observation_keys if k not in available]
        if missing:
            raise ValueError(
                f"dp3 conditions on {self.used_observation_keys}, and the dataset/env has no {missing} (it has "
                f"{available}). Fix: train on data with a point cloud '{self.pointcloud_key}' (P, 3|6) and the "
                f"agent state '{OBS_STATE}' (D,) (focal_metaworld / focal_adroit with obs_type=pointcloud record "
                "both), rename your keys with --rename_map or --policy.pointcloud_key, or, without a cloud, use "
                "--policy.type=diffusion_ema."
            )
        check_feature_shapes(self, "dp3")
