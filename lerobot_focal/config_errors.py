"""One error type for every config the plugin registers, so a bad command-line value reaches the user.

draccus, LeRobot's command-line parser, replaces a ValueError or TypeError raised while it builds a config
with "Couldn't instantiate class X using the given arguments" and two tracebacks: a `lerobot-train`,
`lerobot-eval` or `lerobot-record` user never learns what was wrong. A draccus `DecodingError` with an empty
key path is printed verbatim instead (`error: ...`, exit status 1), as LeRobot prints its own parsing errors.
`ConfigError` is such an error, and `@reports_config_errors` turns the ValueError/TypeError a config's
`__post_init__` raises (its own checks, or those of a helper it calls) into one, so each config keeps plain
Python checks and every message still names the config it came from.
"""

from __future__ import annotations

import functools
import math
from collections.abc import Callable, Iterable
from typing import TypeVar

from draccus.utils import DecodingError

T = TypeVar("T", bound=type)


class ConfigError(DecodingError):
    """A config value that cannot work; the message names the field, the valid values and the fix.

    Deliberately not a ValueError: see the module docstring.
    """

    def __init__(self, message: str):
        super().__init__((), message)


def reports_config_errors(label: str, error: type[ConfigError] = ConfigError) -> Callable[[T], T]:
    """Class decorator: ValueError/TypeError from ``__post_init__`` become `error` prefixed by `label`.

    `label` is what the user typed to choose the config (e.g. ``"--env.type=focal_metaworld"``), so the message
    says which of the several configs of one command line is wrong. A `ConfigError` raised directly gets the
    prefix too. A subclass of a decorated config (``dp3`` of ``diffusion_ema``) says its parent's errors under
    its own label: the user typed the subclass's.
    """

    def decorate(cls: T) -> T:
        post_init = cls.__dict__.get("__post_init__")
        if post_init is None:
            raise TypeError(f"{cls.__name__} defines no __post_init__ to wrap")

        @functools.wraps(post_init)
        def checked_post_init(self, *args, **kwargs):
            try:
                post_init(self, *args, **kwargs)
            except ConfigError as e:
                if isinstance(e, error) and str(e).startswith(label):  # already said by a nested call
                    raise
                raise _labelled(error, label, getattr(e, "reason", str(e))) from e
            except (ValueError, TypeError) as e:
                raise _labelled(error, label, str(e)) from e

        cls.__post_init__ = checked_post_init
        return cls

    return decorate


def _labelled(error: type[ConfigError], label: str, reason: str) -> ConfigError:
    """`error` saying `reason` under `label`; the bare reason is kept for a subclass's label (see above)."""
    labelled = error(f"{label}: {reason}")
    labelled.reason = reason
    return labelled


# --- range checks shared by the configs: each raises a ValueError naming the field and the valid range -----


def require_positive(**values: float | int | None) -> None:
    """Each given value (None: not set, skipped) must be a finite number > 0 (NaN and inf are refused)."""
    for name, value in values.items():
        if value is not None and not (math.isfinite(value) and value > 0):
            raise ValueError(f"{name} must be a number > 0, got {value}.")


def require_non_negative(**values: float | int | None) -> None:
    """Each given value (None: not set, skipped) must be a finite number ≥ 0."""
    for name, value in values.items():
        if value is not None and not (math.isfinite(value) and value >= 0):
            raise ValueError(f"{name} must be a number ≥ 0, got {value}.")


def require_in_range(name: str, value: float | None, low: float, high: float, *, low_open: bool = False,
                     high_open: bool = False, why: str = "") -> None:
    """`value` within [low, high] (a side excluded where open); None is not set and skipped."""
    if value is None:
        return
    above = value > low if low_open else value >= low
    below = value < high if high_open else value <= high
    if not (math.isfinite(value) and above and below):
        interval = f"{'(' if low_open else '['}{low}, {high}{')' if high_open else ']'}"
        raise ValueError(f"{name} must be in {interval}, got {value}.{' ' + why if why else ''}")


def require_choice(name: str, value: object, choices: Iterable[object]) -> None:
    choices = list(choices)
    if value not in choices:
        raise ValueError(f"{name} must be one of {choices}, got {value!r}.")


def check_adamw(*, lr: float, betas: tuple[float, ...], eps: float, weight_decay: float, grad_clip_norm: float,
                prefix: str = "") -> None:
    """AdamW's settings, named as the config that holds them spells them (`prefix` + lr, betas, ...)."""
    require_positive(**{f"{prefix}lr": lr, f"{prefix}eps": eps, f"{prefix}grad_clip_norm": grad_clip_norm})
    require_non_negative(**{f"{prefix}weight_decay": weight_decay})
    if len(betas) != 2:
        raise ValueError(f"{prefix}betas must be two numbers (β1, β2), got {tuple(betas)}.")
    for i, beta in enumerate(betas):
        require_in_range(f"{prefix}betas[{i}]", beta, 0.0, 1.0, high_open=True)
