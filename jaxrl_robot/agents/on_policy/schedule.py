"""Episode-parameter schedules (the RSI window and early-termination limit of the tracking envs, thesis
§3.5.2): piecewise-constant values by training progress, written into each lane's ``info["params"]``."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
from brax.envs.base import Env, State

from jaxrl_robot.validation import ConfigError

__all__ = ["apply_schedule", "initial_env_params", "schedule_tables", "schedule_values"]


def schedule_tables(
    schedule: tuple[tuple[float, str, float], ...], env: Env
) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """``name -> (starts [S], values [S, ...])`` sorted by start; validated against the env's params.

    ``schedule``: entries ``(start fraction of training, name in state.info["params"], value)``;
    every named parameter needs an entry starting at 0.0; values are broadcast to its shape.
    """
    if not schedule:
        return {}
    defaults = env.default_params() if hasattr(env, "default_params") else {}
    tables: dict[str, list] = {}
    for start, name, value in sorted(schedule, key=lambda e: e[0]):
        if name not in defaults:
            valid = ", ".join(sorted(defaults)) or "none"
            raise ConfigError(f"schedule: unknown episode parameter {name!r}; this env's parameters: {valid}")
        val = np.broadcast_to(np.asarray(value, np.float32), np.shape(defaults[name]))
        tables.setdefault(name, []).append((float(start), val))
    out = {}
    for name, entries in tables.items():
        if entries[0][0] != 0.0:
            raise ConfigError(f"schedule: parameter {name!r} needs an entry starting at 0.0")
        out[name] = (np.array([s for s, _ in entries], np.float32), np.stack([v for _, v in entries]))
    return out


def schedule_values(tables: dict, progress: jax.Array) -> dict[str, jax.Array]:
    """Piecewise-constant parameter values at ``progress`` in [0, 1]."""
    out = {}
    for name, (starts, values) in tables.items():
        idx = jnp.sum(jnp.asarray(starts) <= progress) - 1
        out[name] = jnp.asarray(values)[jnp.clip(idx, 0, len(starts) - 1)]
    return out


def initial_env_params(env: Env, tables: dict) -> dict[str, jax.Array] | None:
    """The env's default episode parameters with the schedule's values at progress 0 (None without a schedule)."""
    if not tables:
        return None
    params = dict(env.default_params())
    params.update(schedule_values(tables, jnp.asarray(0.0)))
    return params


def apply_schedule(env_state: State, tables: dict, progress: jax.Array) -> State:
    """``env_state`` ``[B]`` with the scheduled parameters at ``progress`` written into ``info["params"]``
    (same shapes and dtypes, so nothing recompiles)."""
    if not tables:
        return env_state
    params = dict(env_state.info["params"])
    for name, v in schedule_values(tables, progress).items():
        params[name] = jnp.broadcast_to(v, params[name].shape).astype(params[name].dtype)
    return env_state.replace(info={**env_state.info, "params": params})
