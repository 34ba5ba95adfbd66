"""What the policy does differently on the LeRobot versions it runs on: 0.6.1 (CI's pin) and LeRobot's main branch
(0.6.2.dev, tested by ``scripts/test_lerobot_main.sh``). Each difference is detected by what LeRobot has, never by
its version number; docs/compatibility.md lists them.

* Model card: 0.6.1 renders it in ``PreTrainedPolicy.generate_model_card(dataset_repo_id, model_type, license,
  tags, cfg, dataset_meta)``; main removed that method for a free function
  ``lerobot.common.train_utils.generate_model_card(model_cfg, cfg, dataset_meta)`` that reads license and tags from
  the config.
* EMA: main's ``lerobot-train`` has a global ``--ema.enable`` that keeps a shadow of *all* ``policy.parameters()``
  (focal's own ``ema_model`` included) and evaluates and pushes it. focal keeps its own EMA as the paper's
  consistency target θ⁻ and its inference weights (diffusion_ema as its inference weights), so the two would
  average each other silently: :func:`refuse_stacked_ema` stops such a run.
"""

from __future__ import annotations

import copy
import sys
from typing import Any


def lerobot_model_card(parent: Any, config: Any, dataset_repo_id: str | None, model_type: str, license: str,
                       tags: list[str], cfg: Any = None, dataset_meta: Any = None):
    """LeRobot's own model card, on either API. ``parent`` is ``super()`` of the calling policy (0.6.1's method is
    used when it has one); otherwise LeRobot's free function renders ``config`` with this ``license`` and ``tags``
    (on a copy: the policy's config is left as it is)."""
    if hasattr(parent, "generate_model_card"):
        return parent.generate_model_card(dataset_repo_id, model_type, license, tags, cfg=cfg,
                                          dataset_meta=dataset_meta)
    from lerobot.common.train_utils import generate_model_card

    card_cfg = copy.copy(config)
    card_cfg.license, card_cfg.tags = license, list(tags)
    card = generate_model_card(card_cfg, cfg=cfg, dataset_meta=dataset_meta)
    if cfg is None and dataset_repo_id:
        card.data.datasets = dataset_repo_id  # 0.6.1 took it as an argument; main only from the train config
    return card


def running_train_config(policy_config: Any) -> Any | None:
    """The ``TrainPipelineConfig`` of the ``lerobot-train`` run that is building ``policy_config``, or None
    (evaluation, rollout, a script). Read-only: looks up the callers' frames for LeRobot's train config whose
    policy is this very config object."""
    frame = sys._getframe(1)
    while frame is not None:
        cfg = frame.f_locals.get("cfg")
        if cfg is not None and type(cfg).__name__ == "TrainPipelineConfig" and (
            getattr(cfg, "policy", None) is policy_config
        ):
            return cfg
        frame = frame.f_back
    return None


# Per policy type with an EMA of its own: what that EMA is for, and the flags that leave LeRobot's EMA alone.
_OWN_EMA = {
    "focal": ("the paper's consistency target and the weights focal acts with",
              "--policy.use_ema=false --policy.consistency_target=online"),
    "diffusion_ema": ("the weights diffusion_ema acts with", "--policy.use_ema=false"),
}


def refuse_stacked_ema(policy_config: Any) -> None:
    """Stop a ``lerobot-train`` run that has LeRobot's ``--ema.enable=true`` (LeRobot main) and the policy's own
    EMA (``use_ema``, the default of focal and diffusion_ema) on, instead of keeping two EMAs of one network.
    No-op on 0.6.1, which has no ``--ema``, and outside ``lerobot-train``."""
    if not getattr(policy_config, "use_ema", False):
        return
    cfg = running_train_config(policy_config)
    ema = getattr(cfg, "ema", None)
    if ema is None or not getattr(ema, "enable", False):
        return
    kind = policy_config.type
    role, alone = _OWN_EMA.get(kind, (f"the weights {kind} acts with", "--policy.use_ema=false"))
    raise ValueError(
        f"--ema.enable=true adds LeRobot's EMA of every policy parameter beside {kind}'s own EMA "
        f"(--policy.use_ema=true, the default: {role}). Two EMAs of one network do not stack: LeRobot's would "
        "also average the policy's EMA copy, and evaluate and push a shadow of it. Fix: drop --ema.enable=true "
        f"(the policy's EMA is saved in model.safetensors and used for evaluation already), or use LeRobot's EMA "
        f"alone with {alone}."
    )
