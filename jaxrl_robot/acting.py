"""Rollouts: ``N`` steps of a batched, auto-resetting environment under ``lax.scan``.

The environment is one wrapped by ``envs_mjx.wrap_for_training`` (vmapped lanes, time limit
with ``info["truncation"]``, true auto-reset with ``info["final_obs"]``).  :func:`rollout_with_memory`
runs every lane for all ``N`` steps, carrying a policy's memory per lane (a new episode's from
``start_memory``; ``()`` for a memoryless policy); :func:`rollout_until_done` stops each lane at the
end of its episode (a local buffer that closes early, thesis Algorithm 3, line 8).  Randomness per lane is
keyed by global lane index (:func:`per_lane_keys`), so results do not depend on how lanes are
spread over devices.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import jax
import jax.numpy as jnp
from brax.envs.base import Env, State

from jaxrl_robot.types import Transition

__all__ = [
    "RecurrentStochasticPolicy",
    "StochasticPolicy",
    "env_step",
    "lane_select",
    "per_lane_keys",
    "rollout_until_done",
    "rollout_with_memory",
]

StochasticPolicy = Callable[[jax.Array, jax.Array], jax.Array]
"""``(key, obs [B, D]) -> action [B, A]``."""
RecurrentStochasticPolicy = Callable[[jax.Array, Any, State], tuple[Any, jax.Array, Any]]
"""``(key, memory [B, ...], state [B]) -> (memory [B, ...], action [B, A], record [B, ...])``."""


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


def rollout_with_memory(
    key: jax.Array,
    env: Env,
    state: State,
    memory: Any,
    policy: RecurrentStochasticPolicy,
    num_steps: int,
    start_memory: Callable[[State], Any],
) -> tuple[State, Any, tuple[Transition, Any]]:
    """Run ``policy`` for ``num_steps`` steps in every lane, carrying its memory (a recurrent network's carry,
    per lane).

    Args:
      key: PRNG key; step ``t`` gives the policy ``split(key, num_steps)[t]``.
      env: a batched env from ``envs_mjx.wrap_for_training``.
      state: its current ``State`` ``[B]``.
      num_steps: N.
      memory: ``[B, ...]`` pytree the policy starts the first step from.
      policy: ``(key, memory [B, ...], state [B]) -> (memory, action [B, A], record)``; ``record``
        is any pytree ``[B, ...]`` kept per step (e.g. the memory the step started from).
      start_memory: ``state [B] -> memory [B, ...]`` of episodes starting in ``state`` (called on
        the state after each step; lanes whose episode ended take it, the others keep the policy's).
    Returns:
      ``(final state, final memory, (Transition [N, B], record [N, B, ...]))``.
    """

    def body(carry: tuple[State, Any], k: jax.Array):
        s, mem = carry
        mem, action, record = policy(k, mem, s)
        ns, transition = env_step(env, s, action)
        mem = lane_select(ns.done > 0, start_memory(ns), mem)
        return (ns, mem), (transition, record)

    (state, memory), out = jax.lax.scan(body, (state, memory), jax.random.split(key, num_steps))
    return state, memory, out


def rollout_until_done(
    key: jax.Array, env: Env, state: State, policy: StochasticPolicy, num_steps: int
) -> tuple[State, Transition, jax.Array]:
    """Run ``policy`` for up to ``num_steps`` steps per lane, each lane stopping at its episode's end.

    A lane whose episode ends at step ``t`` idles for the remaining steps: its state is held and
    its later transitions carry ``termination = truncation = done = 0`` and ``mask = 0``.

    Args:
      key, env, state, num_steps: as :func:`rollout_with_memory`.
      policy: ``(key, obs [B, D]) -> action [B, A]``.
    Returns:
      ``(final state [B], Transition [N, B], mask [N, B])``; ``mask`` is 1.0 on the steps taken.
    """

    def body(carry: tuple[State, jax.Array], k: jax.Array):
        s, active = carry
        ns, tr = env_step(env, s, policy(k, s.obs))
        s = lane_select(active > 0, ns, s)
        tr = tr._replace(termination=tr.termination * active, truncation=tr.truncation * active, done=tr.done * active)
        return (s, active * (1.0 - tr.done)), (tr, active)

    init = (state, jnp.ones(state.done.shape, jnp.float32))
    (state, _), (traj, mask) = jax.lax.scan(body, init, jax.random.split(key, num_steps))
    return state, traj, mask


def per_lane_keys(key: jax.Array, lane_ids: jax.Array) -> jax.Array:
    """Keys ``[B]``: ``fold_in(key, lane_ids[i])`` for lane ``i`` (``lane_ids`` global lane indices)."""
    return jax.vmap(jax.random.fold_in, in_axes=(None, 0))(key, lane_ids)


def lane_select(pred: jax.Array, a: Any, b: Any) -> Any:
    """Per lane ``pred [B] ? a : b`` on pytrees with a leading lane axis."""

    def pick(x: jax.Array, y: jax.Array) -> jax.Array:
        return jnp.where(pred.reshape(pred.shape + (1,) * (x.ndim - 1)), x, y)

    return jax.tree.map(pick, a, b)
