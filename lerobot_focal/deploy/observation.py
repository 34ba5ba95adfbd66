"""What a policy server hands a checkpoint, built from the raw observation a LeRobot robot client sends.

LeRobot's robot client pickles ``robot.get_observation()`` as it is: ``{"shoulder_pan_joint.pos": 0.1, ...,
"front": (H, W, 3) uint8, "front_depth": (H, W, 1) uint16, "task": "..."}``. LeRobot's own server turns that into
``observation.state`` (every float of the robot, in its order) and ``observation.images.*`` (RGB, resized to
the policy's shape) only. A checkpoint may read more:

* ``observation.environment_state`` (object poses) and a state made of some of the robot's values: their raw
  keys are the ``names`` of those features in the dataset the checkpoint was trained on (found from its
  ``train_config.json``, or given with ``--dataset_root``); ``observation.state`` falls back to the robot's
  floats, as LeRobot records them;
* a point cloud made from depth by its own preprocessor step (``focal_depth_to_pointcloud``): the server then
  delivers the depth frame (``observation.images.<camera>_depth``) and the step makes the cloud, as in
  ``lerobot-rollout``.

:func:`plan_observation` works out, once per client, where each input comes from and says at set-up what the
robot cannot provide; :class:`ObservationPlan` builds each frame as ``lerobot-rollout`` does
(``build_dataset_frame`` then ``prepare_observation_for_inference``). :class:`FrameHistory` keeps the frames a
policy with ``n_obs_steps > 1`` reads (``focal``: t−1 and t).
"""

from __future__ import annotations

import json
import threading
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import torch
from lerobot.policies.utils import prepare_observation_for_inference
from lerobot.processor import RenameObservationsProcessorStep
from lerobot.utils.constants import HF_LEROBOT_HOME, OBS_IMAGES, OBS_STATE

from lerobot_focal.policy.depth_pointcloud_step import DepthToPointCloudProcessorStep

_CAMERA = OBS_IMAGES + "."


class ObservationMismatchError(ValueError):
    """The robot does not provide what the checkpoint reads; the message names each input and the fix."""


@dataclass(frozen=True)
class InputNeeds:
    """What the robot must send for one checkpoint: its input keys as the preprocessor receives them (before
    its rename step), their trained shapes, and the (H, W) each depth-to-cloud step's camera info is for."""

    keys: tuple[str, ...]
    shapes: dict[str, tuple[int, ...]]
    depth_sizes: dict[str, tuple[int, int]] = field(default_factory=dict)


def input_needs(config: Any, preprocessor: Any) -> InputNeeds:
    """The observation keys the robot must provide for ``config``'s policy run through ``preprocessor``.

    ``focal`` reads only ``used_observation_keys`` (a dataset may hold more, e.g. a depth map next to RGB);
    LeRobot's policies read all their ``input_features``. A point cloud made by the preprocessor from depth is
    replaced by that depth key, and keys the preprocessor renames are given their robot-side names.
    """
    used = getattr(config, "used_observation_keys", None)
    keys = list(used) if used else list(config.input_features)
    shapes = {k: tuple(ft.shape) for k, ft in config.input_features.items()}
    depth_sizes: dict[str, tuple[int, int]] = {}
    inverse: dict[str, str] = {}
    for step in getattr(preprocessor, "steps", []):
        if isinstance(step, DepthToPointCloudProcessorStep):
            keys = [k for k in keys if k != step.pointcloud_key]
            if step.depth_key not in keys:
                keys.append(step.depth_key)
            depth_sizes[step.depth_key] = (int(step.camera_info["height"]), int(step.camera_info["width"]))
        elif isinstance(step, RenameObservationsProcessorStep):
            inverse.update({new: old for old, new in step.rename_map.items()})
    return InputNeeds(
        keys=tuple(inverse.get(k, k) for k in keys),
        shapes={inverse.get(k, k): v for k, v in shapes.items()},
        depth_sizes={inverse.get(k, k): v for k, v in depth_sizes.items()},
    )


def training_dataset_features(pretrained: str, dataset_root: str | None = None) -> dict[str, dict] | None:
    """The ``features`` of the dataset a checkpoint was trained on (``meta/info.json``), or None if not found.

    ``dataset_root`` (a dataset folder, or a copy of its ``meta/``'s parent) wins; otherwise the checkpoint's
    ``train_config.json`` names the dataset: its ``root``, else ``$HF_LEROBOT_HOME/<repo_id>``.
    """
    roots: list[Path] = []
    if dataset_root:
        info = Path(dataset_root) / "meta" / "info.json"
        if not info.is_file():
            raise FileNotFoundError(f"--dataset_root={dataset_root}: no meta/info.json there (a LeRobotDataset).")
        roots.append(Path(dataset_root))
    else:
        train_config = Path(pretrained) / "train_config.json"
        if train_config.is_file():
            dataset = json.loads(train_config.read_text()).get("dataset") or {}
            if dataset.get("root"):
                roots.append(Path(dataset["root"]))
            if dataset.get("repo_id"):
                roots.append(HF_LEROBOT_HOME / dataset["repo_id"])
    for root in roots:
        info = root / "meta" / "info.json"
        if info.is_file():
            return json.loads(info.read_text())["features"]
    return None


@dataclass(frozen=True)
class ObservationPlan:
    """Where each input of the checkpoint comes from in the robot's raw observation.

    ``vectors``: key -> the raw float keys concatenated into it, in order; ``cameras``: key -> raw camera key;
    ``resize``: RGB keys whose frames the robot sends at another size than the policy was trained on, with that
    (H, W) (LeRobot's server resizes them too; depth is never resized: its pixels are geometry).
    """

    vectors: dict[str, tuple[str, ...]]
    cameras: dict[str, str]
    resize: dict[str, tuple[int, int]] = field(default_factory=dict)

    @property
    def raw_keys(self) -> tuple[str, ...]:
        return (*dict.fromkeys(n for names in self.vectors.values() for n in names), *self.cameras.values())

    def frame(self, raw: dict[str, Any]) -> dict[str, np.ndarray]:
        """The dataset-style frame of one raw observation (what ``build_dataset_frame`` gives ``lerobot-rollout``)."""
        missing = [k for k in self.raw_keys if k not in raw]
        if missing:
            raise ObservationMismatchError(f"The robot's observation lacks {missing}, which the policy reads.")
        out: dict[str, np.ndarray] = {k: np.array([raw[n] for n in names], dtype=np.float32)
                                      for k, names in self.vectors.items()}
        out.update({k: np.asarray(raw[cam]) for k, cam in self.cameras.items()})
        return out

    def to_policy_input(self, frame: dict[str, np.ndarray], device: str, task: str) -> dict[str, Any]:
        """Batched tensors on ``device``, as ``lerobot-rollout``'s sync engine gives the preprocessor."""
        obs = prepare_observation_for_inference(dict(frame), torch.device(device), task, "")
        for key, size in self.resize.items():
            obs[key] = torch.nn.functional.interpolate(obs[key], size=size, mode="bilinear", align_corners=False)
        return obs


def plan_observation(needs: InputNeeds, robot_features: dict[str, dict],
                     dataset_features: dict[str, dict] | None = None) -> ObservationPlan:
    """Map every input in ``needs`` to the raw keys of a robot with ``robot_features`` (the client's
    ``lerobot_features``: ``observation.state`` with the robot's float names, ``observation.images.<camera>``
    with (H, W, C) shapes). Raises :class:`ObservationMismatchError` listing everything the robot lacks."""
    robot_floats = list((robot_features.get(OBS_STATE) or {}).get("names") or [])
    robot_cameras = {k.removeprefix(_CAMERA): tuple(ft["shape"]) for k, ft in robot_features.items()
                     if k.startswith(_CAMERA)}
    sends = f"The robot sends {len(robot_floats)} values {robot_floats} and cameras {sorted(robot_cameras)}."
    vectors: dict[str, tuple[str, ...]] = {}
    cameras: dict[str, str] = {}
    resize: dict[str, tuple[int, int]] = {}
    problems: list[str] = []
    for key in needs.keys:
        trained = needs.shapes.get(key)
        names = ((dataset_features or {}).get(key) or {}).get("names")
        if key.startswith(_CAMERA):
            camera = key.removeprefix(_CAMERA)
            shape = robot_cameras.get(camera)
            if shape is None:
                problems.append(f"'{key}': the robot has no camera '{camera}'.")
                continue
            cameras[key] = camera
            depth_size = needs.depth_sizes.get(key)
            if depth_size is not None and tuple(shape[:2]) != depth_size:
                problems.append(
                    f"'{key}': the checkpoint makes its point cloud with the intrinsics of a {depth_size[0]}x"
                    f"{depth_size[1]} depth camera, the robot's '{camera}' is {shape[0]}x{shape[1]}. Run the camera "
                    "at the resolution the training data was recorded at."
                )
            elif depth_size is None and trained is not None and len(trained) == 3:
                if trained[0] != shape[2]:
                    problems.append(f"'{key}': the checkpoint reads {trained[0]} channels, the robot's '{camera}' "
                                    f"has {shape[2]}.")
                elif tuple(trained[1:]) != tuple(shape[:2]):
                    resize[key] = (int(trained[1]), int(trained[2]))
            continue
        if isinstance(names, list) and names and all(isinstance(n, str) for n in names):
            source = f"the training dataset's names for it {names}"
            absent = [n for n in names if n not in robot_floats]
            if absent:
                problems.append(f"'{key}': the robot sends no {absent} (from {source}).")
                continue
            vectors[key] = tuple(names)
        elif key == OBS_STATE and robot_floats:
            source = "the robot's floats (no dataset with names for it was found)"
            vectors[key] = tuple(robot_floats)
        else:
            problems.append(
                f"'{key}': no way to build it from the robot's values: the training dataset's meta/info.json, "
                "which names its raw keys, was not found. Pass --dataset_root=<that dataset, or a copy of its meta/>."
            )
            continue
        if trained is not None and len(trained) == 1 and trained[0] != len(vectors[key]):
            problems.append(f"'{key}': the checkpoint reads {trained[0]} values, {source} gives {len(vectors[key])}.")
    if problems:
        raise ObservationMismatchError(
            "The robot does not provide what this checkpoint reads:\n  - " + "\n  - ".join(problems) + f"\n{sends}"
        )
    return ObservationPlan(vectors=vectors, cameras=cameras, resize=resize)


class FrameHistory:
    """The observations of one client session, by frame, for policies that read the last ``n`` frames.

    LeRobot's client stamps an observation with the index of the last action it executed (0 before any, too).
    Frame ``f`` here is the observation taken after ``f`` actions: the first observation of a session is frame
    0, any later one with timestep ``t`` is frame ``t + 1``, which is the frame ``lerobot-rollout`` would hand the
    policy before sending action ``t + 1``. The first observation kept for a frame is the one used (later ones,
    sent while the client waits for actions, are older than their stamp says)."""

    def __init__(self, keep: int):
        self.keep = keep
        self._frames: dict[int, dict[str, Any]] = {}
        self._started = False  # an action chunk went to the client in this session
        self._lock = threading.Lock()

    def clear(self) -> None:
        with self._lock:
            self._frames.clear()
            self._started = False

    def chunk_sent(self) -> None:
        with self._lock:
            self._started = True

    def add(self, timestep: int, observation: dict[str, Any]) -> int:
        """Record an observation; returns its frame index."""
        with self._lock:
            frame = timestep + 1 if self._started else 0
            self._frames.setdefault(frame, observation)
            newest = max(self._frames)
            for old in [k for k in self._frames if k < newest - self.keep]:
                del self._frames[old]
            return frame

    def window(self, frame: int, current: dict[str, Any], n: int) -> tuple[list[dict[str, Any]], int]:
        """The ``n`` observations ending with ``current`` (frame ``frame``), and how many of the frames before it
        were never received (each then repeats the next one, as LeRobot's queues repeat the first frame of an
        episode; frames before frame 0 are that start, not missing)."""
        with self._lock:
            frames = [self._frames.get(j) for j in range(frame - n + 1, frame)] + [current]
        missing = sum(1 for j, f in zip(range(frame - n + 1, frame), frames, strict=False) if f is None and j >= 0)
        for i in range(n - 2, -1, -1):
            if frames[i] is None:
                frames[i] = frames[i + 1]
        return frames, missing
