"""Record what crosses LeRobot's async inference in real processes (test support, not product code).

* ``FOCAL_ASYNC_DUMP_SERVER=<dir>`` (the `lerobot-focal-policy-server` process): each chunk the server computes
  becomes ``<dir>/chunk_<n>.pkl``: its frame index, the frames it was computed from (as the policy's
  preprocessor got them), the timesteps it was stamped with and the actions.
* ``FOCAL_ASYNC_DUMP_CLIENT=<dir>`` (LeRobot's robot_client process): ``<dir>/robot.pkl``, a stream of
  ``("obs", frame, raw observation)`` and ``("action", action dict, timestep)`` records in call order. The
  timestep is the one LeRobot's client stamped the action with (read from its caller, the client's
  ``control_loop_action``: the client runs as ``__main__``, so its class cannot be wrapped from here); the frame
  is the timestep of the last action sent + 1, the index the server gives the observation.

The wrapped methods return what the originals return: the code paths under test are untouched.
"""

import os
import pickle
import sys
from pathlib import Path

if os.environ.get("FOCAL_ASYNC_DUMP_SERVER"):
    import itertools

    from lerobot_focal.deploy.policy_server import FocalPolicyServer

    _server_dir = Path(os.environ["FOCAL_ASYNC_DUMP_SERVER"])
    _server_dir.mkdir(parents=True, exist_ok=True)
    _count = itertools.count()
    _infer, _predict = FocalPolicyServer._infer, FocalPolicyServer._predict_action_chunk

    def _recording_infer(self, frames, task):
        self._dump_frames = frames
        return _infer(self, frames, task)

    def _recording_predict(self, observation_t):
        chunk = _predict(self, observation_t)
        record = {"frame": observation_t.focal_frame, "frames": self._dump_frames,
                  "timesteps": [a.get_timestep() for a in chunk], "actions": [a.get_action().numpy() for a in chunk]}
        (_server_dir / f"chunk_{next(_count):04d}.pkl").write_bytes(pickle.dumps(record))
        return chunk

    FocalPolicyServer._infer, FocalPolicyServer._predict_action_chunk = _recording_infer, _recording_predict

if os.environ.get("FOCAL_ASYNC_DUMP_CLIENT"):
    from lerobot_focal.robots.ur10e.ur10e import UR10e

    _client_dir = Path(os.environ["FOCAL_ASYNC_DUMP_CLIENT"])
    _client_dir.mkdir(parents=True, exist_ok=True)
    _stream = (_client_dir / "robot.pkl").open("ab")
    _last_timestep = [-1]
    _get_observation, _send_action = UR10e.get_observation, UR10e.send_action

    def _dump(record):
        pickle.dump(record, _stream)
        _stream.flush()

    def _recording_get_observation(self):
        obs = _get_observation(self)
        _dump(("obs", _last_timestep[0] + 1, dict(obs)))
        return obs

    def _recording_send_action(self, action):
        timed = sys._getframe(1).f_locals.get("timed_action")  # LeRobot's TimedAction being sent
        timestep = timed.get_timestep() if timed is not None else None
        _dump(("action", dict(action), timestep))
        if timestep is not None:
            _last_timestep[0] = timestep
        return _send_action(self, action)

    UR10e.get_observation, UR10e.send_action = _recording_get_observation, _recording_send_action
