"""Depth → point cloud geometry: back-projection, crop, voxel grid, farthest-point sampling, camera models.

NumPy only, and it imports nothing else of the project: the simulated envs, the policy's depth-to-cloud
processor step and the robot all build their clouds with these functions, so a cloud means the same everywhere.
"""

from lerobot_focal.geometry.pointcloud import (
    PinholeIntrinsics,
    PointCloudSpec,
    WorkspaceBounds,
    backproject_depth,
    crop_to_workspace,
    depth_to_pointcloud,
)

__all__ = ["PinholeIntrinsics", "PointCloudSpec", "WorkspaceBounds", "backproject_depth", "crop_to_workspace",
           "depth_to_pointcloud"]
