"""Keys shared by every layer of the project (envs, policy, robots, datasets), defined once."""

#: The point cloud, (P, 3) xyz or (P, 6) xyz + rgb. LeRobot has no point-cloud feature type: it is a STATE
#: feature to LeRobot, and this is its observation key (as LeRobot's own `observation.state` / `.images.*`).
OBS_POINTCLOUD = "observation.pointcloud"
