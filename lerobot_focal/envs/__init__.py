"""Simulation envs for FocalPolicy. Importing this package registers ``focal_metaworld`` and ``focal_adroit``
as LeRobot ``EnvConfig`` types and the ``focal_pointcloud_observation`` processor step."""

from .focal_adroit import FocalAdroitEnvConfig
from .focal_metaworld import FocalMetaworldEnvConfig
from .processor import PointCloudObservationStep

__all__ = ["FocalAdroitEnvConfig", "FocalMetaworldEnvConfig", "PointCloudObservationStep"]
