"""The env of a ``python -m train.<algo>`` run: its settings from the command line (``--reward``,
``--env-config KEY=VALUE``), the env built from a name (ours, ``brax:<name>``, ``playground:<Name>``) and
``config.json``'s record of it.
"""

from __future__ import annotations

import dataclasses
import json
from collections.abc import Mapping
from typing import Any

from brax.envs.base import Env

__all__ = [
    "BRAX_PREFIX",
    "PLAYGROUND_PREFIX",
    "BuiltEnv",
    "check_backend_devices",
    "env_overrides",
    "env_record",
    "episode_length",
    "make_env",
    "parse_value",
]

BRAX_PREFIX = "brax:"
PLAYGROUND_PREFIX = "playground:"


def parse_value(text: str) -> Any:
    """A ``--env-config`` value: JSON where it parses (lists become tuples), else the text."""
    try:
        value = json.loads(text)
    except json.JSONDecodeError:
        return text
    return tuple(value) if isinstance(value, list) else value


def env_overrides(args: Any) -> dict[str, Any]:
    """Env settings from ``--reward`` and ``--env-config KEY=VALUE``."""
    out: dict[str, Any] = {}
    if args.reward is not None:
        out["reward"] = args.reward
    for item in args.env_config or ():
        if "=" not in item:
            raise ValueError(f"--env-config {item!r}: expected KEY=VALUE")
        k, v = item.split("=", 1)
        out[k.strip().replace("-", "_")] = parse_value(v.strip())
    return out


def env_record(name: str, env: Any) -> dict[str, Any]:
    """``config.json``'s record of the env a run built: its name and every field of its config (the env's
    defaults with the preset's and the command line's settings over them; None for an env without a config
    dataclass, e.g. brax's), so that a run's setting can be read back whole."""
    config = getattr(env, "config", None)
    return {"name": name, "config": dataclasses.asdict(config) if dataclasses.is_dataclass(config) else None}


def check_backend_devices(overrides: Mapping[str, Any], devices: int) -> None:
    """Raise ``ValueError`` (one line, naming ``--devices``) when the env's physics runs on MuJoCo Warp
    (``impl=warp``) and the lanes would be spread over several devices: a Warp data shares some fields by
    all its lanes, which splitting the lanes over devices does not keep."""
    if str(overrides.get("impl", "jax")) == "warp" and devices > 1:
        raise ValueError(f"--env-config impl=warp runs its lanes on one device; add --devices 1 (the lanes "
                         f"would be spread over {devices})")  # fmt: skip


def make_env(name: str, overrides: dict[str, Any]) -> Env:
    """An unbatched env: ``envs_mjx.make(name, **overrides)``, ``brax.envs.get_environment`` (``brax:<name>``)
    or MuJoCo Playground's (``playground:<Name>``: ``envs_mjx.playground.load``, the overrides its
    ``config_overrides``, ``impl`` defaulting to ``jax``).

    Raises:
      ValueError: an unknown name (the message lists the valid ones), bad overrides, or ``playground:``
        without MuJoCo Playground installed (``PlaygroundMissingError``, naming the extra).
    """
    import envs_mjx

    if name.startswith(PLAYGROUND_PREFIX):
        from envs_mjx import playground

        playground.require(f"--env {name}")
        return playground.load(name, **overrides)
    if name.startswith(BRAX_PREFIX):
        from brax import envs as brax_envs

        bname = name[len(BRAX_PREFIX) :]
        if bname not in brax_envs._envs:
            raise ValueError(f"unknown brax environment {bname!r}; valid: {', '.join(sorted(brax_envs._envs))}")
        return brax_envs.get_environment(bname, **overrides)
    if name not in envs_mjx.names():
        raise ValueError(f"unknown environment {name!r}; valid names: {', '.join(envs_mjx.names())} "
                         f"(or {BRAX_PREFIX}<name>, {PLAYGROUND_PREFIX}<Name>)")
    return envs_mjx.make(name, **overrides)


@dataclasses.dataclass(frozen=True)
class BuiltEnv:
    """An env :func:`make_env` built from ``name`` and ``overrides``: the command line builds the env once,
    for the preset's defaults, and the run takes it where its own settings are the same (:meth:`fits`)."""

    name: str
    overrides: dict[str, Any]
    env: Env

    def fits(self, name: str, overrides: Mapping[str, Any]) -> bool:
        """Whether ``make_env(name, overrides)`` is this env: the same name and settings (each value of the
        same type: ``1`` is not ``1.0`` nor ``True``)."""
        return name == self.name and _settings(overrides) == _settings(self.overrides)


def _settings(overrides: Mapping[str, Any]) -> str:
    return repr(sorted(overrides.items()))


def episode_length(env: Env, cfg_len: int = 0) -> int:
    """The configured time limit, else the env's ``episode_length``, else 1000 (brax's default)."""
    return int(cfg_len or getattr(env, "episode_length", 0) or 1000)
