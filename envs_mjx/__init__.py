"""MJX robot environments with a brax-compatible API.

>>> import envs_mjx
>>> envs_mjx.names()            # registered environments
>>> env = envs_mjx.make("arm7", reward="path")
"""

from __future__ import annotations

import importlib
from typing import Any

from envs_mjx import xla as _xla

_xla.configure()  # before the first JAX computation: keeps MJX physics fast on XLA:CPU (envs_mjx/xla.py)
_xla.import_mjx_quietly()  # without the two "Failed to import warp" lines of MJX's optional Warp backend

from envs_mjx.base import (  # noqa: E402
    ActionRepeatWrapper,
    ActionShapeError,
    AutoResetWrapper,
    ClipActionWrapper,
    EpisodeWrapper,
    PoolResetWrapper,
    RobotEnv,
    TanhActionWrapper,
    VmapWrapper,
    sanitize_action,
    wrap_for_training,
)
from envs_mjx.config import ConfigError  # noqa: E402

# name -> "module:Class"; imported lazily so that `names()` costs nothing.
_REGISTRY: dict[str, str] = {
    "arm7": "envs_mjx.arm7:Arm7",
    "arm7_precise": "envs_mjx.arm7:Arm7Precise",
    "racecar": "envs_mjx.racecar:RaceCar",
    "scara": "envs_mjx.scara:Scara",
    "unicycle": "envs_mjx.unicycle:Unicycle",
}


def names() -> list[str]:
    """Names accepted by :func:`make`, sorted."""
    return sorted(_REGISTRY)


def env_class(name: str) -> type[RobotEnv]:
    """The environment class registered under ``name``."""
    if name not in _REGISTRY:
        raise ValueError(f"unknown environment {name!r}; valid names: {', '.join(names())}")
    module, cls = _REGISTRY[name].split(":")
    return getattr(importlib.import_module(module), cls)


def make(name: str, **overrides: Any) -> RobotEnv:
    """Build the environment ``name`` with config ``overrides`` (keyword = config field)."""
    return env_class(name)(**overrides)


__all__ = [
    "ActionRepeatWrapper",
    "ActionShapeError",
    "AutoResetWrapper",
    "ClipActionWrapper",
    "ConfigError",
    "EpisodeWrapper",
    "PoolResetWrapper",
    "RobotEnv",
    "TanhActionWrapper",
    "VmapWrapper",
    "env_class",
    "make",
    "names",
    "sanitize_action",
    "wrap_for_training",
]
