"""Env processor step that delivers the point cloud to the policy as ``observation.pointcloud``.

``lerobot-eval`` runs ``lerobot.envs.utils.preprocess_observation`` on every raw observation before the env
processors. Which raw keys survive that call depends on the LeRobot build (some builds drop unknown keys;
the installed 0.6.1 passes them through as ``observation.<key>`` float tensors). This step is the one place
that guarantees the contract whatever that function did: the cloud arrives as float32 (B, P, C) under
``observation.pointcloud``, or the rollout fails loudly instead of a policy silently running without it.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
import torch
from lerobot.configs import PipelineFeatureType, PolicyFeature
from lerobot.processor import ObservationProcessorStep, ProcessorStepRegistry

from lerobot_focal.constants import OBS_POINTCLOUD

from .features import POINTCLOUD_KEY


@dataclass
@ProcessorStepRegistry.register(name="focal_pointcloud_observation")
class PointCloudObservationStep(ObservationProcessorStep):
    """Move the cloud from whichever key carried it to ``observation.pointcloud`` and check its shape."""

    num_points: int = 512
    channels: int = 3
    # Keys the cloud may arrive under, in order of preference (post-preprocess names first, then raw).
    source_keys: list[str] = field(
        default_factory=lambda: [OBS_POINTCLOUD, f"observation.{POINTCLOUD_KEY}", POINTCLOUD_KEY]
    )

    def observation(self, observation: dict) -> dict:
        obs = dict(observation)
        source = next((k for k in self.source_keys if k in obs), None)
        if source is None:
            raise KeyError(
                f"no point cloud in the observation (looked for {self.source_keys}; got keys {sorted(obs)}). "
                "The env must be created with obs_type='pointcloud', and preprocess_observation must keep "
                f"the raw '{POINTCLOUD_KEY}' key."
            )
        cloud = obs.pop(source)
        if isinstance(cloud, np.ndarray):
            cloud = torch.from_numpy(cloud)
        cloud = cloud.to(torch.float32)
        if cloud.dim() == 2:  # a single, unbatched env observation
            cloud = cloud.unsqueeze(0)
        expected = (self.num_points, self.channels)
        if cloud.dim() != 3 or tuple(cloud.shape[1:]) != expected:
            raise ValueError(f"point cloud under {source!r} has shape {tuple(cloud.shape)}; expected (B, *{expected})")
        obs[OBS_POINTCLOUD] = cloud
        return obs

    def get_config(self) -> dict:
        return {"num_points": self.num_points, "channels": self.channels, "source_keys": list(self.source_keys)}

    def transform_features(
        self, features: dict[PipelineFeatureType, dict[str, PolicyFeature]]
    ) -> dict[PipelineFeatureType, dict[str, PolicyFeature]]:
        # The key and shape are already what the policy declares; nothing to rename at the feature level.
        return features
