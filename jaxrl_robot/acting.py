"""Rollouts: ``N`` steps of a batched, auto-resetting environment under ``lax.scan``.

The environment is one wrapped by ``envs_mjx.wrap_for_training`` (vmapped lanes, time limit
with ``info["truncation"]``, true auto-reset with ``info["final_obs"]``).
"""

from __future__ import annotations

from collections.abc import Callable

import jax
import jax.numpy as jnp
from brax.envs.base import Env, State

from jaxrl_robot.types import Transition

__all__ = ["StochasticPolicy", "env_step", "rollout"]

StochasticPolicy = Callable[[jax.Array, jax.Array], jax.Array]
"""``(key, obs [B, D]) -> action [B, A]``."""


def env_step(env: Env, state: State, action: jax.Array) -> tuple[State, Transition]:
    """Step the batched ``env`` once and describe the step as a :class:`Transition` ``[B]``."""
    nstate = env.step(state, action)
    done = nstate.done.astype(jnp.float32)
    truncation = nstate.info["truncation"].astype(jnp.float32)
    metrics = dict(nstate.metrics)
    for k in ("episode_return", "episode_length"):
        if k in nstate.info:
            metrics[k] = nstate.info[k]
    transition = Transition(
        obs=state.obs,
        action=action,
        reward=nstate.reward,
        termination=done * (1.0 - truncation),
        truncation=truncation,
        next_obs=nstate.info["final_obs"],
        done=done,
        metrics=metrics,
    )
    return nstate, transition


def rollout(
    key: jax.Array, env: Env, state: State, policy: StochasticPolicy, num_steps: int
) -> tuple[State, Transition]:
    """Run ``policy`` for ``num_steps`` steps in every lane.

    Args:
      key: PRNG key; step ``t`` gives the policy ``split(key, num_steps)[t]``.
      env: a batched env from ``envs_mjx.wrap_for_training``.
      state: its current ``State`` ``[B]``.
      policy: ``(key, obs [B, D]) -> action [B, A]``.
      num_steps: N.
    Returns:
      ``(final state, Transition [N, B])``.
    """

    def body(s: State, k: jax.Array) -> tuple[State, Transition]:
        return env_step(env, s, policy(k, s.obs))

    return jax.lax.scan(body, state, jax.random.split(key, num_steps))
