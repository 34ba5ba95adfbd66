"""LeRobot's plugin contract. Every lerobot-* command imports this plugin, so importing it must only register
classes: no environment variable set, no global RNG drawn from, no LeRobot class or function replaced — unless
the user opts in. The one library function wrapped is draccus' dataclass decoder, so that a focal config.json
saved before some fields moved into groups still loads (`policy/saved_config_upgrade.py`); it changes nothing
for any other class. Policy classes follow the conventions LeRobot's tooling checks."""

from __future__ import annotations

import inspect
import json
import os
import subprocess
import sys

import pytest

PROBE = r'''
import json, os, random, sys, types
import numpy as np
import torch
import lerobot.datasets.dataset_reader, lerobot.datasets.lerobot_dataset, lerobot.envs.factory, lerobot.envs.utils
import lerobot.policies.factory, lerobot.processor, lerobot.scripts.lerobot_eval, lerobot.scripts.lerobot_train
import lerobot.policies.diffusion.modeling_diffusion, lerobot.policies.diffusion.configuration_diffusion

import draccus.parsers.decoding
MODULES = [m for name, m in sorted(sys.modules.items())
           if (name.startswith("lerobot.") or name.startswith("draccus.")) and m is not None]

def snapshot():
    ids = {}
    for m in MODULES:
        for name, value in list(vars(m).items()):
            ids[f"{m.__name__}.{name}"] = id(value)
            if isinstance(value, type) and value.__module__ == m.__name__:
                for attr, member in list(vars(value).items()):
                    if not isinstance(member, dict):  # registries are dicts filled in place: allowed
                        ids[f"{m.__name__}.{name}.{attr}"] = id(member)
    return ids

def rng():
    return [repr(random.getstate()), repr(np.random.get_state()[1].tolist()), torch.random.get_rng_state().tolist()]

env0, ids0, rng0 = dict(os.environ), snapshot(), rng()
import lerobot_policy_focal  # what LeRobot's plugin discovery does
env1, ids1, rng1 = dict(os.environ), snapshot(), rng()
print(json.dumps({
    "env_changed": sorted(k for k in set(env0) | set(env1) if env0.get(k) != env1.get(k)),
    "replaced": sorted(k for k in ids0 if k in ids1 and ids0[k] != ids1[k]),
    "rng_changed": rng0 != rng1,
    "policy_registered": "focal" in lerobot.configs.policies.PreTrainedConfig.get_known_choices(),
}))
'''


def _probe(**env_extra: str) -> dict:
    env = {k: v for k, v in os.environ.items() if k not in ("MUJOCO_GL", "PYOPENGL_PLATFORM")}
    env.pop("LEROBOT_FOCAL_FAST_READER", None)
    env.update(env_extra)
    out = subprocess.run([sys.executable, "-c", PROBE], capture_output=True, text=True, timeout=300, env=env)
    assert out.returncode == 0, out.stderr[-3000:]
    return json.loads(out.stdout.strip().splitlines()[-1])


@pytest.mark.subprocess
def test_importing_the_plugin_changes_nothing_global():
    result = _probe()
    assert result["policy_registered"]
    assert result["env_changed"] == []  # e.g. MUJOCO_GL is chosen when a simulator starts, not at import
    assert result["rng_changed"] is False
    assert result["replaced"] == ["draccus.parsers.decoding.decode_dataclass"]  # saved_config_upgrade's wrapper


def test_the_config_decoder_wrapper_leaves_other_classes_as_draccus_decodes_them():
    """The wrapped decoder moves flat keys only for a class that declares MOVED_FIELDS: LeRobot's own configs
    decode to the same object, and an unknown key is refused by draccus with its own message, as before."""
    from draccus.parsers import decoding
    from draccus.utils import DecodingError
    from lerobot.policies.diffusion.configuration_diffusion import DiffusionConfig

    import lerobot_focal.policy  # noqa: F401  (installs the wrapper)

    assert decoding.decode_dataclass.moves_flat_keys
    raw = {"n_obs_steps": 3, "horizon": 32, "down_dims": [64, 128], "device": "cpu"}
    assert decoding.decode_dataclass(DiffusionConfig, raw) == decoding.decode_dataclass.__wrapped__(
        DiffusionConfig, raw)
    with pytest.raises(DecodingError, match="pointcloud_num_points"):
        decoding.decode_dataclass(DiffusionConfig, {**raw, "pointcloud_num_points": 3})


@pytest.mark.subprocess
def test_the_opt_in_fast_reader_is_the_one_visible_change():
    from lerobot_focal.datasets.fast_loading.fast_reader import compatible

    result = _probe(LEROBOT_FOCAL_FAST_READER="1")
    if not compatible()[0]:
        # Another LeRobot (e.g. its main branch, docs/compatibility.md): the reader differs from the verified one,
        # so even the opt-in replaces nothing and training reads through LeRobot's own reader.
        assert result["replaced"] == ["draccus.parsers.decoding.decode_dataclass"]
        assert result["env_changed"] == [] and result["rng_changed"] is False
        return
    replaced = [k for k in result["replaced"] if k != "draccus.parsers.decoding.decode_dataclass"]
    assert replaced, "the probe sees a patched LeRobot method: it would catch an unasked one"
    assert all(k.startswith("lerobot.datasets.dataset_reader.DatasetReader.") for k in replaced)
    assert result["env_changed"] == [] and result["rng_changed"] is False


def test_policy_classes_honour_lerobots_config_annotation_contract():
    """LeRobot's tooling checks `issubclass(cfg.__class__, <annotation of __init__'s config>)`: the annotation
    must be the config class itself at run time, not a string."""
    from lerobot_focal.policy import FocalConfig, FocalPolicy
    from lerobot_focal.policy.diffusion_fco.configuration_diffusion_fco import DiffusionFcoConfig
    from lerobot_focal.policy.diffusion_fco.modeling_diffusion_fco import DiffusionFcoPolicy

    for policy_cls, config_cls in ((FocalPolicy, FocalConfig), (DiffusionFcoPolicy, DiffusionFcoConfig)):
        annotation = inspect.signature(policy_cls.__init__).parameters["config"].annotation
        assert annotation is config_cls
        assert issubclass(policy_cls.config_class, annotation)


def test_focal_config_documents_every_field_in_its_args_block():
    import dataclasses
    import re

    from lerobot.configs import PreTrainedConfig

    from lerobot_focal.policy import FocalConfig

    inherited = {f.name for f in dataclasses.fields(PreTrainedConfig)} - {"n_obs_steps"}  # focal sets its own
    own = {f.name for f in dataclasses.fields(FocalConfig)} - inherited
    documented = set(re.findall(r"^        (\w+):", FocalConfig.__doc__ or "", re.M))
    assert own - documented == set(), "fields without an Args: entry"
    assert documented - own == set(), "Args: entries for fields that do not exist"
