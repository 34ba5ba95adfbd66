"""`FocalPolicy`: consistency flow matching over macro-trajectories, one network evaluation per action chunk.

Training (`forward`): M_1 = the expert macro-trajectory (L steps), M_0 ~ N(0, I), (τ, r) from the configured
sampler (LAS by default), loss from `objective.consistency_loss` (FCO by default) with the consistency target
evaluated by the EMA network θ⁻ (or the online one, per `consistency_target`).

Inference (`select_action` / `predict_action_chunk`): M̂ = M_0 + (1 − ε)·v_θ(M_0, ε, o) — a single U-Net call —
then the first H actions are executed and the policy re-plans.

The EMA copy is a frozen submodule, so LeRobot's own `save_pretrained` / `from_pretrained` / Hub upload /
`--resume` carry it without any special code; `update()` (called by `lerobot-train` after every optimizer
step) advances it.
"""

from collections import deque
from pathlib import Path

import torch
from lerobot.policies.pretrained import PreTrainedPolicy
from lerobot.policies.utils import populate_queues
from lerobot.utils.constants import ACTION
from torch import Tensor, nn

from lerobot_focal.policy.configuration_focal import FocalConfig
from lerobot_focal.policy.ema import ema_decay, ema_update_, frozen_copy  # noqa: F401  (ema_decay: re-exported)
from lerobot_focal.policy.encoders import ObservationEncoder
from lerobot_focal.policy.lerobot_compat import lerobot_model_card
from lerobot_focal.policy.network import VelocityUnet
from lerobot_focal.policy.objective import consistency_loss
from lerobot_focal.policy.rtc import FocalRTC, rtc_active
from lerobot_focal.policy.stats import adopt_dataset_stats
from lerobot_focal.policy.time_samplers import sample_times


class FocalModel(nn.Module):
    """Observation encoder + velocity U-Net: the unit that is trained, EMA-averaged and evaluated."""

    def __init__(self, config: FocalConfig):
        super().__init__()
        self.obs_encoder = ObservationEncoder(config)
        self.velocity_net = VelocityUnet(
            action_dim=config.action_feature.shape[0],
            global_cond_dim=self.obs_encoder.global_cond_dim,
            down_dims=tuple(config.down_dims),
            kernel_size=config.kernel_size,
            n_groups=config.n_groups,
            time_embed_dim=config.time_embed_dim,
            use_film_scale_modulation=config.use_film_scale_modulation,
            gradient_checkpointing=config.gradient_checkpointing,
            time_scale=config.time_scale,
        )

    def encode(self, obs: dict[str, Tensor], image_features: dict[str, Tensor] | None = None) -> Tensor:
        return self.obs_encoder(obs, image_features)

    def velocity(self, m: Tensor, t: Tensor, cond: Tensor) -> Tensor:
        return self.velocity_net(m, t, cond)


MODEL_CARD_TAGS = ("focal", "focalpolicy", "flow-matching", "consistency-flow-matching", "action-chunking",
                   "imitation-learning", "lerobot_policy_focal")
MODEL_CARD_INTRO = (
    "**FocalPolicy** (ICML 2026, *Frequency-Optimized Chunking and Locally Anchored Flow Matching for Coherent "
    "Visuomotor Policy*): one-step consistency flow matching over action macro-trajectories, with Locally "
    "Anchored Sampling (LAS) of the consistency anchor and the Foresight Composite Objective (FCO: consistency on "
    "the executed chunk, an orthonormal-DCT frequency term on the whole macro-trajectory). One network evaluation "
    "per action chunk. Load it with the `lerobot_policy_focal` plugin installed (`pip install "
    "lerobot_policy_focal`): `lerobot-eval --policy.path=<this repo>` or `lerobot-rollout --policy.path=<this repo>`."
)


class FocalPolicy(PreTrainedPolicy):
    config_class = FocalConfig
    name = "focal"

    def __init__(self, config: FocalConfig, dataset_stats: dict | None = None, **kwargs):
        # kwargs: make_policy also passes dataset_meta=; normalisation lives in the processors.
        super().__init__(config)
        config.validate_features()
        if dataset_stats is not None:
            adopt_dataset_stats(config, dataset_stats, kwargs.get("dataset_meta"))
        # Where the weights came from, for error messages; set by _load_as_safetensor.
        self.checkpoint_file: str | None = None
        self.config = config
        self.model = FocalModel(config)
        self.ema_model: FocalModel | None = None
        if config.use_ema:
            self.ema_model = frozen_copy(self.model)
        # Number of EMA updates so far; a buffer so checkpoints and --resume keep the EMA schedule.
        self.register_buffer("ema_step", torch.zeros((), dtype=torch.long))
        self._objective = config.objective_spec()
        self._sampler = config.time_sampler_spec()
        self._obs_keys = config.used_observation_keys
        self._queues: dict[str, deque] = {}
        # Per queued observation frame: {camera key: (B, F) RGB features} once encoded, else None (see select_action).
        self._frame_features: deque = deque()
        self._rank_rng_decorrelated = False
        self.rtc_processor: FocalRTC | None = None
        self.init_rtc_processor()
        self.reset()

    # --- LeRobot interface ---------------------------------------------------------------------------------
    @classmethod
    def _load_as_safetensor(cls, model, model_file: str, map_location: str, strict: bool):
        """LeRobot's loader, with a message that names the file when it is missing or corrupt (safetensors
        itself only reports e.g. "Error while deserializing header: ...", without the path)."""
        try:
            loaded = super()._load_as_safetensor(model, model_file, map_location, strict)
        except FileNotFoundError as e:
            raise FileNotFoundError(
                f"Checkpoint weights {model_file} do not exist. Point --policy.path at a pretrained_model folder "
                "of a finished save (it holds config.json and model.safetensors)."
            ) from e
        except Exception as e:  # noqa: BLE001 - safetensors raises its own SafetensorError / OSError variants
            size = Path(model_file).stat().st_size if Path(model_file).is_file() else None
            raise RuntimeError(
                f"Checkpoint weights {model_file} ({size} bytes) are corrupt or incomplete and cannot be read "
                f"({type(e).__name__}: {e}). The file was truncated or damaged, e.g. by an interrupted copy, "
                "download or save. Fix: download the checkpoint again, take another checkpoint of the run "
                "(checkpoints/<step>/pretrained_model), or re-train."
            ) from e
        loaded.checkpoint_file = str(model_file)
        return loaded

    def generate_model_card(self, dataset_repo_id, model_type, license, tags, cfg=None, dataset_meta=None):
        """LeRobot's card (data, commands, features) plus what `focal` is: LeRobot's template only describes
        the policy types it ships, and names any other type "a focal policy". LeRobot's main branch renders its
        card with a free function instead of this method (docs/compatibility.md); this method uses either."""
        tags = sorted(set(tags or []) | set(MODEL_CARD_TAGS))
        card = lerobot_model_card(super(), self.config, dataset_repo_id, model_type, license or "apache-2.0", tags,
                                  cfg=cfg, dataset_meta=dataset_meta)
        generic = f"This is a **{model_type}** policy trained with"
        text = card.text
        if generic in text:
            head, tail = text.split(generic, 1)
            text = head + MODEL_CARD_INTRO + "\n\n" + generic + tail
        else:
            text = MODEL_CARD_INTRO + "\n\n" + text
        card.text = text
        return card

    def supports_rtc(self) -> bool:
        """focal is a flow policy: `lerobot-rollout --inference.type=rtc` guides its chunks (see policy/rtc.py)."""
        return True

    def init_rtc_processor(self) -> None:
        """(Re)build the RTC guide from ``config.rtc_config`` (LeRobot's rollout sets it, then calls this)."""
        self.rtc_processor = FocalRTC(self.config.rtc_config) if self.config.rtc_config is not None else None

    def get_optim_params(self) -> dict:
        return self.model.parameters()

    def reset(self) -> None:
        """Clear observation and action queues; call on env.reset()."""
        self._queues = {key: deque(maxlen=self.config.n_obs_steps) for key in self._obs_keys}
        self._queues[ACTION] = deque(maxlen=self.config.n_action_steps)
        self._frame_features = deque(maxlen=self.config.n_obs_steps)

    def train(self, mode: bool = True) -> "FocalPolicy":
        super().train(mode)
        if self.ema_model is not None:
            self.ema_model.eval()  # the target/inference network never runs in training mode
        return self

    @torch.no_grad()
    def update(self) -> None:
        """Advance the EMA weights by one step (LeRobot calls this after every optimizer step)."""
        if self.ema_model is None:
            return
        cfg = self.config
        decay = ema_decay(
            int(self.ema_step),
            power=cfg.ema_power,
            min_decay=cfg.ema_min_decay,
            max_decay=cfg.ema_max_decay,
            update_after_step=cfg.ema_update_after_step,
        )
        ema_update_(self.ema_model, self.model, decay)
        self.ema_step += 1

    def forward(self, batch: dict[str, Tensor]) -> tuple[Tensor, dict]:
        """Training loss for a batch from LeRobotDataset (observations (B, n_obs, ...), actions (B, L, d))."""
        self._decorrelate_ranks_once()
        obs = self._observations(batch, training=True)
        m1 = self._check_actions(batch)
        cond = self.model.encode(obs)
        m0 = torch.randn_like(m1)
        tau, r = sample_times(self._sampler, m1.shape[0], device=m1.device)

        def velocity(m: Tensor, t: Tensor) -> Tensor:
            return self.model.velocity(m, t, cond)

        if self.config.consistency_target == "ema":
            assert self.ema_model is not None
            ema = self.ema_model

            def target_velocity(m: Tensor, t: Tensor) -> Tensor:
                return ema.velocity(m, t, ema.encode(obs))
        else:
            def target_velocity(m: Tensor, t: Tensor) -> Tensor:
                return self.model.velocity(m, t, cond.detach())

        loss, logs = consistency_loss(self._objective, m0, m1, tau, r, velocity, target_velocity)
        return loss, {k: v.item() for k, v in logs.items()}

    @torch.no_grad()
    def predict_action_chunk(self, batch: dict[str, Tensor], noise: Tensor | None = None,
                             inference_delay: int | None = None, prev_chunk_left_over: Tensor | None = None,
                             execution_horizon: int | None = None) -> Tensor:
        """(B, H, d) actions to execute next. Uses the observation queues when `select_action` filled them,
        otherwise the batch itself (offline use).

        With RTC on (``config.rtc_config``, set by ``lerobot-rollout --inference.type=rtc``) it returns the whole
        macro-trajectory (B, L, d), guided towards ``prev_chunk_left_over`` (the previous chunk's unexecuted
        normalised actions) over its first ``inference_delay`` … ``execution_horizon`` steps (policy/rtc.py)."""
        if any(len(self._queues[k]) > 0 for k in self._obs_keys):
            obs = {k: torch.stack(list(self._queues[k]), dim=1) for k in self._obs_keys}
            image_features = self._queued_image_features() if self._image_keys else None
        else:
            obs = self._observations(batch, training=False)
            image_features = None
        if not rtc_active(self.config):
            return self.sample_macro_trajectory(obs, noise, image_features)[:, : self.config.n_action_steps]
        if self.rtc_processor is None or self.rtc_processor.config is not self.config.rtc_config:
            self.init_rtc_processor()
        rtc = (prev_chunk_left_over, inference_delay, execution_horizon)
        return self.sample_macro_trajectory(obs, noise, image_features, rtc=rtc)

    @torch.no_grad()
    def select_action(self, batch: dict[str, Tensor], noise: Tensor | None = None) -> Tensor:
        """One action (B, d); a new chunk of H actions is generated (one network evaluation) every H calls.

        With RGB inputs each frame is encoded once, and as early as it is known to be needed: a chunk reads the
        last n_obs_steps frames, so the frames of the steps just before a chunk step are encoded on their own
        step. The chunk step then encodes only its own frame, which cuts its latency (at 848x480 with two
        108x192 crops, by one ResNet-18 pass) at the same total compute (the first step after `reset()` encodes
        its whole window of copies). Encoding is per frame (GroupNorm, no batch statistics), so the actions are
        those of encoding the whole window at once, up to float rounding. Features are kept until `reset()`:
        call it after changing the weights mid-episode, as LeRobot's eval and rollout do per episode.
        """
        current = self._observations(batch, training=False, stacked=False)
        self._queues = populate_queues(self._queues, current)
        if self._image_keys:
            self._align_frame_features()
        if len(self._queues[ACTION]) == 0:
            actions = self.predict_action_chunk(batch, noise=noise)[:, : self.config.n_action_steps]
            self._queues[ACTION].extend(actions.transpose(0, 1))
        action = self._queues[ACTION].popleft()
        # Steps left before the next chunk step; frames within n_obs_steps - 1 of it are in its window.
        if self._image_keys and len(self._queues[ACTION]) < self.config.n_obs_steps - 1:
            self._queued_image_features(only_last=True)
        return action

    @property
    def _image_keys(self) -> list[str]:
        return self.model.obs_encoder.image_keys

    def _align_frame_features(self) -> None:
        """Keep one entry per queued frame: populate_queues appended one frame (or filled the window with
        copies of the first one)."""
        k = self.config.n_obs_steps
        if not self._frame_features:
            self._frame_features.extend([None] * k)
        else:
            self._frame_features.append(None)

    def _queued_image_features(self, only_last: bool = False) -> dict[str, Tensor]:
        """{camera key: (B, n_obs, F)} of the queued frames, encoding (with the inference weights) those not yet
        encoded; with ``only_last`` just make sure the newest frame is encoded."""
        net = self._inference_net()
        frames = range(len(self._frame_features))
        for j in frames[-1:] if only_last else frames:
            if self._frame_features[j] is None:
                self._frame_features[j] = {
                    key: net.obs_encoder.encode_image(key, self._queues[key][j]) for key in self._image_keys
                }
        if only_last:
            return {}
        return {key: torch.stack([f[key] for f in self._frame_features], dim=1) for key in self._image_keys}

    def _inference_net(self) -> FocalModel:
        use_ema = self.ema_model is not None and self.config.use_ema_for_inference
        return self.ema_model if use_ema else self.model

    def _decorrelate_ranks_once(self) -> None:
        """Give each data-parallel process its own noise M_0 and times (τ, r).

        `lerobot-train` seeds every Accelerate process with the same seed, and the noise and times come from the
        global torch generator, so without this all ranks would draw identical samples on different data. Rank 0
        keeps its stream (a multi-process run's rank 0 reproduces the one-process run); rank k > 0 reseeds from
        its own stream plus k, so everything still derives from `--seed` (and the RNG state restored on resume).
        """
        if self._rank_rng_decorrelated:
            return
        self._rank_rng_decorrelated = True
        dist = torch.distributed
        if dist.is_available() and dist.is_initialized() and dist.get_rank() > 0:
            torch.manual_seed(int(torch.randint(0, 2**62, ())) + dist.get_rank())

    # --- sampling ------------------------------------------------------------------------------------------
    def sample_macro_trajectory(
        self, obs: dict[str, Tensor], noise: Tensor | None = None, image_features: dict[str, Tensor] | None = None,
        rtc: tuple | None = None,
    ) -> Tensor:
        """Integrate the learned flow from noise (τ = ε) to data (τ = 1); NFE = num_inference_steps. Noise
        passed in is used as given; drawn noise is scaled by ``inference_noise_scale``. ``rtc``: (leftover,
        delay, horizon) of RTC's guided steps (policy/rtc.py)."""
        net = self._inference_net()
        cond = net.encode(obs, image_features)
        b = cond.shape[0]
        shape = (b, self.config.horizon, self.config.action_feature.shape[0])
        # The flow state in the weights' dtype: under autocast (--policy.use_amp) `cond` is bfloat16/float16, and
        # actions in it break LeRobot's `.numpy()` of them (numpy has no bfloat16); the network still autocasts.
        dtype = next(net.parameters()).dtype
        if noise is None:
            x = torch.randn(shape, device=cond.device, dtype=dtype)
            if self.config.inference_noise_scale != 1.0:
                x = x * self.config.inference_noise_scale
        else:
            if tuple(noise.shape) != shape:
                raise ValueError(f"noise must have shape {shape} (B, L, action_dim); got {tuple(noise.shape)}.")
            x = noise.to(device=cond.device, dtype=dtype)
        times = torch.linspace(self.config.anchor.eps, 1.0, self.config.num_inference_steps + 1, device=x.device)
        guided = None
        if rtc is not None:  # None too for the first chunk (nothing to continue)
            guided = self.rtc_processor.sample(x, times, lambda m, i: net.velocity(m, times[i].expand(b), cond), *rtc)
        if guided is not None:
            x = guided
        else:
            for i in range(self.config.num_inference_steps):
                t = times[i].expand(b)
                x = x + (times[i + 1] - times[i]) * net.velocity(x, t, cond)
        if self.config.check_finite and not bool(torch.isfinite(x).all()):
            raise FloatingPointError(self._nonfinite_output_message(net, x))
        return x

    def _nonfinite_output_message(self, net: nn.Module, x: Tensor) -> str:
        """Why the policy produced NaN/inf actions from finite observations (the inputs are checked before)."""
        bad_weights = [name for name, p in net.named_parameters() if not bool(torch.isfinite(p).all())]
        source = (self.checkpoint_file or getattr(self.config, "pretrained_path", None)
                  or "weights not loaded from a file")
        which = "EMA" if net is self.ema_model else "online"
        if bad_weights:
            shown = ", ".join(bad_weights[:3]) + (f" and {len(bad_weights) - 3} more" if len(bad_weights) > 3 else "")
            cause = f"{len(bad_weights)} weight tensor(s) of the {which} network are NaN/inf ({shown})"
        else:
            cause = f"the {which} network's weights are finite, so its activations overflowed"
        return (
            f"FocalPolicy produced {int((~torch.isfinite(x)).sum())} NaN/inf action value(s) out of {x.numel()} "
            f"from finite observations: {cause}. Checkpoint: {source}. Such a checkpoint cannot act; stopping "
            "instead of sending NaN commands. Fix: use an earlier checkpoint of the run, or re-train (training "
            "diverged: lower the learning rate, check the data and its statistics)."
        )

    # --- input checking ------------------------------------------------------------------------------------
    def _observations(self, batch: dict[str, Tensor], *, training: bool, stacked: bool = True) -> dict[str, Tensor]:
        """Pick the used keys, check their shapes and values, and give each a time axis (B, n_obs, ...)."""
        obs: dict[str, Tensor] = {}
        for key in self._obs_keys:
            if key not in batch:
                raise KeyError(
                    f"FocalPolicy needs '{key}' but the batch only has {sorted(batch)}. The policy was trained with "
                    f"{self._obs_keys}; give it the same observations (or map keys with a rename step)."
                )
            x = batch[key]
            feat_shape = tuple(self.config.input_features[key].shape)
            n = len(feat_shape)
            # A cloud may hold any number of points (the encoder max-pools over them); its channels must match.
            free = 1 if key == self.config.used_pointcloud_key else 0  # leading sizes that may differ
            tail = tuple(x.shape[-n:])
            if tail[free:] != feat_shape[free:] or x.ndim not in (n + 1, n + 2):
                names = ", ".join(["P"] * free + [str(d) for d in feat_shape[free:]])
                raise ValueError(
                    f"'{key}' has shape {tuple(x.shape)}, expected (B, {names}) or (B, n_obs_steps, {names}) as in "
                    "the policy's input_features."
                )
            self._check_finite(key, x)
            if stacked and x.ndim == n + 1:
                x = x.unsqueeze(1).expand(-1, self.config.n_obs_steps, *tail)
            elif stacked and x.shape[1] != self.config.n_obs_steps:
                raise ValueError(
                    f"'{key}' carries {x.shape[1]} observation steps, the policy uses n_obs_steps="
                    f"{self.config.n_obs_steps}. Check the dataset's delta_timestamps."
                )
            obs[key] = x
        return obs

    def _check_actions(self, batch: dict[str, Tensor]) -> Tensor:
        if ACTION not in batch:
            raise KeyError(f"Training batch has no '{ACTION}' (keys: {sorted(batch)}).")
        m1 = batch[ACTION]
        expected = (self.config.horizon, self.config.action_feature.shape[0])
        if m1.ndim != 3 or tuple(m1.shape[1:]) != expected:
            raise ValueError(
                f"'{ACTION}' has shape {tuple(m1.shape)}; FocalPolicy trains on macro-trajectories of shape "
                f"(B, L={expected[0]}, d={expected[1]}). The dataset must be loaded with the policy's "
                "action_delta_indices (lerobot-train does this) and the action dimension must match the config."
            )
        self._check_finite(ACTION, m1)
        return m1

    def _check_finite(self, key: str, x: Tensor) -> None:
        if self.config.check_finite and x.is_floating_point() and not bool(torch.isfinite(x).all()):
            bad = int((~torch.isfinite(x)).sum())
            raise ValueError(
                f"'{key}' contains {bad} NaN/inf value(s) out of {x.numel()}. Fix the data source (dataset "
                "frames, sensor driver) or the normalisation stats (e.g. a std of 0); set "
                "policy.check_finite=false only if you handle this yourself."
            )
