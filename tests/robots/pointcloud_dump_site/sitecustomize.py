"""Record what the `focal_depth_to_pointcloud` step sees and returns inside a real ``lerobot-rollout`` (test
support, not product code).

With ``FOCAL_DUMP_POINTCLOUDS=<dir>`` set, every call of the step in this process writes
``<dir>/call_<n>.npz`` with the depth exactly as the preprocessor received it (dtype and layout included) and
the point cloud the step produced, then returns that cloud unchanged: the rollout's code path is untouched.
"""

import os

if os.environ.get("FOCAL_DUMP_POINTCLOUDS"):
    import itertools
    from pathlib import Path

    import numpy as np

    from lerobot_focal.policy.processor_focal import DepthToPointCloudProcessorStep

    _dir = Path(os.environ["FOCAL_DUMP_POINTCLOUDS"])
    _dir.mkdir(parents=True, exist_ok=True)
    _count = itertools.count()
    _observation = DepthToPointCloudProcessorStep.observation

    def _recording_observation(self, observation):
        depth = observation.get(self.depth_key)
        out = _observation(self, observation)
        np.savez(
            _dir / f"call_{next(_count):04d}.npz",
            depth=depth.detach().cpu().numpy(),
            cloud=out[self.pointcloud_key].detach().cpu().numpy(),
        )
        return out

    DepthToPointCloudProcessorStep.observation = _recording_observation
