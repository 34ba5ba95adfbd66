"""Reading a policy `config.json` saved before one of its fields moved into a nested group.

LeRobot decodes a saved config with draccus, which refuses a key the class no longer has: a checkpoint saved
with ``"pointcloud_from_depth": …`` would not load once that field became ``depth_cloud.from_depth``. A config
class that moved fields lists them in ``MOVED_FIELDS`` (old flat key → (group, field)), and they are moved
before draccus decodes the class, wherever LeRobot reads a policy config: `--policy.path`
(`PreTrainedConfig.from_pretrained`), a resumed run's `train_config.json`, `lerobot-eval`. A value given the new
way (e.g. a command-line ``--policy.depth_cloud.crop_min``) wins over the old key in the file; other classes
pass through unchanged.

draccus has no hook for this: a decoder registered for a class makes draccus treat it as one command-line value
(and it refuses one on a choice type such as LeRobot's policy configs), so this wraps draccus' dataclass decoder,
the single function every one of those paths ends in. It is the plugin's one change to a library at import
(`tests/test_plugin_contract.py` checks it is the only one, and that other classes decode as before): it acts
only on a class that declares ``MOVED_FIELDS`` and otherwise calls draccus' own function with the same
arguments. Where a draccus release has no such function, nothing is wrapped and an old `config.json` is refused
by draccus, naming the key. `tests/policy/test_depth_pointcloud.py` loads a real pre-change `config.json`.
"""

from __future__ import annotations

import typing
from collections.abc import Mapping
from typing import Any

from draccus.parsers import decoding


def move_flat_keys(raw: Mapping[str, Any], moved: Mapping[str, tuple[str, str]]) -> dict[str, Any]:
    """`raw` with every old flat key of `moved` put into its group (a new dict; `raw` is not changed)."""
    out = {k: v for k, v in raw.items() if k not in moved}
    for old, (group, name) in moved.items():
        if old not in raw:
            continue
        nested = dict(out.get(group) or {})
        nested.setdefault(name, raw[old])
        out[group] = nested
    return out


def _decoder_moving_flat_keys(decode_dataclass: Any) -> Any:
    def decode(cls: Any, d: Any, path: Any = ()) -> Any:
        moved = getattr(typing.get_origin(cls) or cls, "MOVED_FIELDS", None)
        if moved and isinstance(d, Mapping):
            d = move_flat_keys(d, moved)
        return decode_dataclass(cls, d, path)

    decode.moves_flat_keys = True
    decode.__wrapped__ = decode_dataclass
    return decode


def install() -> None:
    """Wrap draccus' dataclass decoder once (idempotent)."""
    original = getattr(decoding, "decode_dataclass", None)
    if original is None or getattr(original, "moves_flat_keys", False):
        return
    decoding.decode_dataclass = _decoder_moving_flat_keys(original)
    decoding.get_decoding_fn.cache_clear()  # cached decoders hold the function they were built with
