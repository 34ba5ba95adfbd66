"""`lerobot-focal-policy-server`: LeRobot's async-inference policy server, for focal checkpoints.

LeRobot's async inference runs the policy on one machine (a GPU) while the robot's computer streams
observations to it and plays the action chunks it returns. This is LeRobot's ``PolicyServer`` (same gRPC
service, same messages, LeRobot's own ``robot_client`` on the robot side), subclassed where it falls short:

* it loads the plugins (``focal``, ``ur10e``, ...) and serves ``focal`` and the diffusion variants besides
  LeRobot's own policy types;
* it hands the checkpoint every input it reads, built from the raw robot observation as ``lerobot-rollout``
  builds it: ``observation.state`` and ``observation.environment_state`` by the training dataset's feature
  names, the depth frame a ``focal`` point cloud is made from (by the checkpoint's own preprocessor step), RGB;
  what the robot cannot provide is refused when the client connects, with the list of what is missing;
* it gives a policy with ``n_obs_steps > 1`` its frames t−1 .. t from the observations the client streamed
  (kept per client session), instead of one frame copied;
* the first action of a chunk is the one to execute next: LeRobot stamps it with the timestep of the action
  the robot had just executed, so its client drops it;
* when the policy raises, the client gets the error (its log shows it) instead of empty answers, and the next
  observation is tried again.

Run (on the policy machine; the client is LeRobot's)::

    lerobot-focal-policy-server --host=0.0.0.0 --port=8080 --fps=30
    python -m lerobot.async_inference.robot_client --robot.type=ur10e --robot.backend=sim \\
        --server_address=<server>:8080 --policy_type=focal --pretrained_name_or_path=<checkpoint dir> \\
        --policy_device=cuda --actions_per_chunk=4 --chunk_size_threshold=0.5 --fps=30 --task="push the cube"

``--dataset_root=<dataset>``: where the training dataset's ``meta/info.json`` is, if the checkpoint's
``train_config.json`` does not lead to it on this machine (needed only for inputs other than the robot's full
state). Other options are LeRobot's ``PolicyServerConfig``'s (``--inference_latency``, ``--obs_queue_timeout``).
See docs/async_inference.md for what differs from LeRobot's server and why.
"""

# No `from __future__ import annotations`: draccus reads serve()'s annotation as a class.
import logging
import pickle  # nosec: LeRobot's protocol pickles its messages
import threading
import time
from concurrent import futures
from dataclasses import asdict, dataclass, field
from pprint import pformat
from typing import Any

import draccus
import grpc
import torch
from lerobot.async_inference.configs import PolicyServerConfig
from lerobot.async_inference.constants import SUPPORTED_POLICIES
from lerobot.async_inference.helpers import RemotePolicyConfig, TimedAction, TimedObservation
from lerobot.async_inference.policy_server import PolicyServer
from lerobot.configs.policies import PreTrainedConfig
from lerobot.policies import get_policy_class, make_pre_post_processors
from lerobot.policies.diffusion.configuration_diffusion import DiffusionConfig
from lerobot.transport import services_pb2, services_pb2_grpc  # type: ignore
from lerobot.utils.import_utils import register_third_party_plugins

from lerobot_focal.deploy.observation import (
    FrameHistory,
    ObservationMismatchError,
    ObservationPlan,
    input_needs,
    plan_observation,
    training_dataset_features,
)
from lerobot_focal.policy.configuration_focal import FocalConfig

# Policies whose predict_action_chunk takes a (B, n_obs_steps, ...) batch when their queues are empty.
_HISTORY_CONFIGS = (FocalConfig, DiffusionConfig)
_FRAME = "focal_frame"  # attribute the server gives each TimedObservation: its frame index in the session
_ERROR_INTERVAL_S = 1.0  # at most one error answer per second while the policy keeps failing


def served_policy_types() -> list[str]:
    """LeRobot's async-served types plus every registered type built on focal's or LeRobot's diffusion config."""
    extra = [name for name, cls in PreTrainedConfig.get_known_choices().items()
             if isinstance(cls, type) and issubclass(cls, _HISTORY_CONFIGS)]
    return list(dict.fromkeys([*SUPPORTED_POLICIES, *sorted(extra)]))


class PolicySetupError(ValueError):
    """The client asked for something this server does not serve."""


@dataclass
class FocalPolicyServerConfig(PolicyServerConfig):
    dataset_root: str | None = field(
        default=None,
        metadata={"help": "The checkpoint's training dataset (its meta/info.json names the raw keys of each input); "
                          "default: the one its train_config.json names."},
    )


class FocalPolicyServer(PolicyServer):
    """LeRobot's PolicyServer with complete inputs, observation history and errors sent to the client."""

    def __init__(self, config: FocalPolicyServerConfig):
        super().__init__(config)
        self.plan: ObservationPlan | None = None
        self.n_obs_steps = 1
        self.stacks_history = False
        self.history = FrameHistory(keep=8)
        self._call = threading.local()  # the failure of the GetActions call running in this thread
        self._retry = threading.Event()  # process the next observation whatever LeRobot's filters say
        self._last_error: tuple[str, float] = ("", 0.0)
        self._warned_gap = False

    # --- sessions ------------------------------------------------------------------------------------------
    def Ready(self, request, context):  # noqa: N802
        reply = super().Ready(request, context)
        self._new_session()
        return reply

    def _new_session(self) -> None:
        """A client connected: no frame, filter state or policy queue of the previous one may leak in."""
        self.history.clear()
        self.last_processed_obs = None
        self._retry.clear()
        self._last_error = ("", 0.0)
        self._warned_gap = False
        for part in (self.policy, self.preprocessor, self.postprocessor):
            if part is not None:
                part.reset()

    def SendPolicyInstructions(self, request, context):  # noqa: N802
        if not self.running:
            self.logger.warning("Server is not running. Ignoring policy instructions.")
            return services_pb2.Empty()
        try:
            self._load_policy(pickle.loads(request.data), context.peer())  # nosec
        except Exception as e:  # noqa: BLE001  (every set-up failure goes back to the client)
            expected = isinstance(e, (ObservationMismatchError, PolicySetupError))
            self.logger.error("Policy set-up failed: %s", e, exc_info=not expected)  # a traceback if unforeseen
            message = f"lerobot-focal-policy-server could not set up the policy: {type(e).__name__}: {e}"
            context.abort(grpc.StatusCode.INVALID_ARGUMENT, message)
        return services_pb2.Empty()

    def _load_policy(self, specs: RemotePolicyConfig, client: str) -> None:
        if not isinstance(specs, RemotePolicyConfig):
            raise PolicySetupError(f"Policy specs must be a RemotePolicyConfig. Got {type(specs)}")
        served = served_policy_types()
        if specs.policy_type not in served:
            raise PolicySetupError(f"Policy type {specs.policy_type!r} is not served. Served types: {served}")
        self.logger.info(
            f"Receiving policy instructions from {client} | Policy type: {specs.policy_type} | "
            f"Pretrained name or path: {specs.pretrained_name_or_path} | "
            f"Actions per chunk: {specs.actions_per_chunk} | Device: {specs.device}"
        )
        start = time.perf_counter()
        policy = get_policy_class(specs.policy_type).from_pretrained(specs.pretrained_name_or_path)
        policy.to(specs.device)
        device_override = {"device": specs.device}
        preprocessor, postprocessor = make_pre_post_processors(
            policy.config,
            pretrained_path=specs.pretrained_name_or_path,
            preprocessor_overrides={
                "device_processor": device_override,
                "rename_observations_processor": {"rename_map": specs.rename_map},
            },
            postprocessor_overrides={"device_processor": device_override},
        )
        dataset_features = training_dataset_features(specs.pretrained_name_or_path, self.config.dataset_root)
        plan = plan_observation(input_needs(policy.config, preprocessor), specs.lerobot_features, dataset_features)
        self.device, self.policy_type = specs.device, specs.policy_type
        self.lerobot_features, self.actions_per_chunk = specs.lerobot_features, specs.actions_per_chunk
        self.policy, self.preprocessor, self.postprocessor, self.plan = policy, preprocessor, postprocessor, plan
        self.n_obs_steps = int(getattr(policy.config, "n_obs_steps", 1) or 1)
        self.stacks_history = self.n_obs_steps > 1 and isinstance(policy.config, _HISTORY_CONFIGS)
        self.history = FrameHistory(keep=self.n_obs_steps + specs.actions_per_chunk + 2)
        self._new_session()
        self.logger.info(
            f"Time taken to put policy on {self.device}: {time.perf_counter() - start:.4f} seconds | inputs: "
            + ", ".join(f"{k} <- {v}" for k, v in {**plan.vectors, **plan.cameras}.items())
            + (f" | {self.n_obs_steps} observation frames per chunk" if self.stacks_history else "")
        )

    # --- observations --------------------------------------------------------------------------------------
    def _enqueue_observation(self, obs: TimedObservation) -> bool:
        raw = obs.get_observation()
        keys = self.plan.raw_keys if self.plan is not None else ()
        setattr(obs, _FRAME, self.history.add(obs.get_timestep(), {k: raw[k] for k in keys if k in raw}))
        if self._retry.is_set():
            self._retry.clear()
            obs.must_go = True  # the last one failed: LeRobot's filters would drop this one as "already predicted"
        elif not obs.must_go and self.last_processed_obs is None and self._already_predicted(obs):
            # LeRobot's filters start only once the first chunk is done. While it is computed (the slowest chunk:
            # the first call), the client keeps streaming its start observation; a second chunk for that frame
            # reaches the client while it executes the first action, which LeRobot's client then queues again
            # (it marks an action done only after sending it) and executes twice.
            return False
        return super()._enqueue_observation(obs)

    def _already_predicted(self, obs: TimedObservation) -> bool:
        with self._predicted_timesteps_lock:
            return obs.get_timestep() in self._predicted_timesteps

    # --- actions -------------------------------------------------------------------------------------------
    def GetActions(self, request, context):  # noqa: N802
        self._call.failure = None
        reply = super().GetActions(request, context)  # LeRobot's: waits for an observation, times the answer
        failure = self._call.failure
        if failure is not None:
            message, code = failure
            time.sleep(max(0.0, self._last_error[1] + _ERROR_INTERVAL_S - time.monotonic()))
            self._last_error = (message, time.monotonic())
            context.abort(code, message)
        if isinstance(reply, services_pb2.Actions):
            self.history.chunk_sent()
        return reply

    def _predict_action_chunk(self, observation_t: TimedObservation) -> list[TimedAction]:
        frame = getattr(observation_t, _FRAME, 0)
        try:
            raw = observation_t.get_observation()
            current = {k: raw[k] for k in self.plan.raw_keys if k in raw}
            n = self.n_obs_steps if self.stacks_history else 1
            raws, missing = self.history.window(frame, current, n)
            if missing and not self._warned_gap:
                self._warned_gap = True
                self.logger.warning(
                    f"The client did not send {missing} of the {n - 1} frame(s) before frame {frame}; each is "
                    "replaced by the next one. The client sends an observation per step once its queue is at or "
                    "below chunk_size_threshold x actions_per_chunk: keep that >= n_obs_steps - 1."
                )
            actions = self._infer([self.plan.frame(r) for r in raws], str(raw.get("task", "")))
            self.last_processed_obs = observation_t
        except Exception as e:
            self._fail(observation_t, e)
            raise
        return self._time_action_chunk(observation_t.get_timestamp(), list(actions), frame)

    def _infer(self, frames: list[dict[str, Any]], task: str) -> torch.Tensor:
        """(actions_per_chunk, action_dim) unnormalised actions on the CPU for the frames t-n+1 .. t."""
        start = time.perf_counter()
        with torch.inference_mode():
            batches = [self.preprocessor(self.plan.to_policy_input(f, self.device, task)) for f in frames]
            if self.stacks_history:
                batch = {k: torch.stack([b[k] for b in batches], dim=1)
                         if k.startswith("observation.") and isinstance(v, torch.Tensor) else v
                         for k, v in batches[-1].items()}
                self.policy.reset()  # empty queues: the policy reads the window given, nothing older
            else:
                batch = batches[-1]
            chunk = self._get_action_chunk(batch)  # LeRobot's: (B, <= actions_per_chunk, d)
            actions = torch.stack([self.postprocessor(chunk[:, i]) for i in range(chunk.shape[1])], dim=1)
        self.logger.info(f"Chunk of {chunk.shape[1]} actions in {1000 * (time.perf_counter() - start):.2f} ms")
        return actions.squeeze(0).detach().cpu()

    def _fail(self, observation_t: TimedObservation, error: Exception) -> None:
        message = (f"lerobot-focal-policy-server: the policy failed on observation #{observation_t.get_timestep()}: "
                   f"{type(error).__name__}: {error}")
        repeated = message == self._last_error[0]
        self.logger.error(message + (" (again)" if repeated else ""), exc_info=not repeated)
        bad_input = isinstance(error, (KeyError, ValueError, TypeError, IndexError))
        self._call.failure = (message, grpc.StatusCode.INVALID_ARGUMENT if bad_input else grpc.StatusCode.INTERNAL)
        self._retry.set()


def start_server(config: FocalPolicyServerConfig, max_workers: int = 4) -> tuple[grpc.Server, FocalPolicyServer, int]:
    """Start the gRPC server (``port=0`` picks a free one); returns it, the servicer and the bound port."""
    servicer = FocalPolicyServer(config)
    server = grpc.server(futures.ThreadPoolExecutor(max_workers=max_workers))
    services_pb2_grpc.add_AsyncInferenceServicer_to_server(servicer, server)
    port = server.add_insecure_port(f"{config.host}:{config.port}")
    if port == 0:
        raise OSError(f"Cannot listen on {config.host}:{config.port} (address in use or not on this machine).")
    server.start()
    servicer.logger.info(f"PolicyServer started on {config.host}:{port}, serving {served_policy_types()}")
    return server, servicer, port


@draccus.wrap()
def serve(cfg: FocalPolicyServerConfig) -> None:
    logging.info(pformat(asdict(cfg)))
    server, servicer, _ = start_server(cfg)
    try:
        server.wait_for_termination()
    except KeyboardInterrupt:
        pass
    finally:
        servicer.stop()
        server.stop(grace=1.0)
        servicer.logger.info("Server terminated")


def main() -> None:
    register_third_party_plugins()
    serve()


if __name__ == "__main__":
    main()
