"""The MuJoCo side shared by the simulated envs and the robot twin: the ray-cast depth camera (point clouds
without a GPU) and the offscreen-rendering choices. Builds on :mod:`lerobot_focal.geometry`."""
