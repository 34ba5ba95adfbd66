"""``dp3``: 3D Diffusion Policy built from LeRobot's diffusion policy, focal's encoder and diffusion_ema's EMA.

DP3 is Diffusion Policy conditioned on a point cloud: a per-point MLP with max-pooling encodes the cloud, a small
MLP the agent state, and their features of the ``n_obs_steps`` last observations, joined, are the FiLM condition
of the 1-D U-Net. Every piece of that exists already, so this module writes none of it again:

  * the U-Net, the noise scheduler, the loss and DDIM/DDPM sampling are LeRobot's ``DiffusionModel``;
  * the encoders are focal's ``ObservationEncoder`` (``PointCloudEncoder``, DP3's point MLP, and the state MLP),
    so both policies see the observations through the same modules at the same widths;
  * the EMA copy on DP3's schedule, acting with it, is ``DiffusionEmaPolicy``'s;
  * normalisation is focal's pipeline (``processor_dp3``).

``DP3Model`` replaces what LeRobot's ``DiffusionModel`` encodes (the state vector as it is, images through a
ResNet) with that encoder, by overriding ``_prepare_global_conditioning``; training, sampling, the chunk queues,
``save_pretrained`` / ``from_pretrained`` / ``--resume`` are LeRobot's and ``diffusion_ema``'s, unchanged.
"""

import copy
from collections import deque
from typing import Any

from lerobot.configs.types import FeatureType, PolicyFeature
from lerobot.policies.diffusion.modeling_diffusion import DiffusionModel
from lerobot.policies.pretrained import PreTrainedPolicy
from lerobot.utils.constants import ACTION, OBS_ENV_STATE, OBS_STATE
from torch import Tensor

from lerobot_focal.policy.diffusion_ema.modeling_diffusion_ema import DiffusionEmaPolicy
from lerobot_focal.policy.dp3.configuration_dp3 import DP3Config
from lerobot_focal.policy.encoders import ObservationEncoder
from lerobot_focal.policy.stats import adopt_dataset_stats


class DP3Model(DiffusionModel):
    """LeRobot's ``DiffusionModel`` whose global condition is focal's encoding of the cloud and the state."""

    def __init__(self, config: DP3Config):
        encoder = ObservationEncoder(config)
        # LeRobot sizes the U-Net's condition as n_obs_steps × (state width + its cameras' and env state's widths),
        # and builds an encoder per camera. Shown a state as wide as one step of the encoder's features and nothing
        # else, it builds the U-Net for exactly the condition the encoder gives, and no encoder of its own.
        unet_view = copy.copy(config)
        unet_view.input_features = {OBS_STATE: PolicyFeature(FeatureType.STATE, (encoder.feature_dim,))}
        super().__init__(unet_view)
        self.obs_encoder = encoder

    def _prepare_global_conditioning(self, batch: dict[str, Tensor]) -> Tensor:
        """(B, n_obs_steps · feature_dim): each observation step's cloud and state features, joined as focal does."""
        return self.obs_encoder(batch)

    def compute_loss(self, batch: dict[str, Tensor]) -> Tensor:
        # LeRobot's loss first asserts an image or environment-state input, what its own encoders read. DP3's
        # condition is the cloud, encoded above: the placeholder passes that check and is never read.
        return super().compute_loss({OBS_ENV_STATE: None, **batch})


class DP3Policy(DiffusionEmaPolicy):
    """DP3: LeRobot's diffusion U-Net on focal's point-cloud and state encoder, acting with the EMA weights."""

    config_class = DP3Config
    name = "dp3"

    def __init__(self, config: DP3Config, dataset_stats: dict | None = None, **kwargs: Any):
        # DiffusionPolicy.__init__ would first build LeRobot's own DiffusionModel for the dataset's inputs (a U-Net
        # sized for them, a ResNet per camera) only for it to be replaced: its body and diffusion_ema's, with
        # DP3Model in that place.
        PreTrainedPolicy.__init__(self, config)
        config.validate_features()
        if dataset_stats is not None:  # as focal: checked, and adapted for a fine-tuning run's normaliser
            adopt_dataset_stats(config, dataset_stats, kwargs.get("dataset_meta"))
        self.config = config
        self.diffusion = DP3Model(config)
        self.init_ema()
        self.reset()

    def reset(self) -> None:
        """Empty the action queue and the queues of the observations DP3 reads (the cloud's among them)."""
        self._queues = {key: deque(maxlen=self.config.n_obs_steps) for key in self.config.used_observation_keys}
        self._queues[ACTION] = deque(maxlen=self.config.n_action_steps)
