"""Hindsight experience replay: relabel goal-conditioned episodes (thesis §3.3, Algorithm 2, §3.4.2).

An episode of goal-conditioned transitions ``(s‖g, a, r, s'‖g)`` is stored once with its
real goal and once more for each additional goal chosen by a strategy:

* ``"final"`` — the episode's final achieved goal ``m(s_L)``; skipped (masked out) when the
  final state left the feasible region, since that is not a state the agent should aim for.
* ``"future"`` with ``k`` — ``k`` achieved goals drawn uniformly from the states observed
  later in the same episode (``m(s_j)``, ``t < j <= L``); each transition is stored
  ``k + 1`` times.
* ``"random"`` with ``k`` — ``k`` goals drawn from the feasible region by the environment's
  ``sample_goal`` (the thesis's own strategy for the shaped reward).
* ``"none"`` — no relabelling.

Relabelled rewards are recomputed with the environment's ``compute_reward(achieved_next,
goal, achieved_prev)`` (sparse or shaped alike) and observations are rebuilt with
``obs_from(ee_pos, goal)``.  A relabelled transition is terminal when the episode failed at
that step (left the feasible region — independent of the goal) or, if the environment
provides ``goal_reached(achieved, goal)``, when the new goal is reached.

The relabelling works on one episode (time-major ``[T, ...]``); vmap it over lanes.  It
returns fixed-shape ``[T, C, ...]`` transitions with ``C = 1 + extra goals`` and a mask of
the copies to store (steps after the episode ended, skipped ``final`` goals), ready for the
masked ``add`` of the replay buffers.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, NamedTuple, Protocol

import chex
import jax
import jax.numpy as jnp

from jaxrl_robot.types import Transition

__all__ = ["STRATEGIES", "GoalEnv", "GoalEpisode", "Her", "flatten_copies", "make_her", "num_copies"]

STRATEGIES = ("none", "final", "future", "random")


class GoalEnv(Protocol):
    """The goal-conditioned API HER needs (``envs_mjx`` arm7 implements it)."""

    def compute_reward(self, achieved_next: jax.Array, goal: jax.Array, achieved_prev: jax.Array) -> jax.Array: ...

    def sample_goal(self, key: jax.Array) -> jax.Array: ...

    def in_feasible_region(self, pos: jax.Array) -> jax.Array: ...

    def obs_from(self, ee_pos: jax.Array, goal: jax.Array) -> jax.Array: ...


class GoalEpisode(NamedTuple):
    """One recorded episode, time-major, padded to ``T`` steps.

    Attributes:
      obs: ``[T, O]`` observations with the real goal.
      action: ``[T, A]`` actions taken (as stored for learning, in [-1, 1]).
      reward: ``[T]`` rewards for the real goal.
      next_obs: ``[T, O]`` next observations with the real goal.
      termination: ``[T]`` 1.0 where the episode terminated (success or failure), not truncation.
      failed: ``[T]`` 1.0 where it terminated by leaving the feasible region.
      valid: ``[T]`` 1.0 for steps inside the episode (a prefix of length ``L >= 1``).
      achieved: ``[T + 1, G]`` achieved goals before step 0, ..., after step T−1.
      ee_pos: ``[T + 1, 3]`` end-effector positions, same indexing (for ``obs_from``).
      goal: ``[G]`` the episode's real (desired) goal.
    """

    obs: jax.Array
    action: jax.Array
    reward: jax.Array
    next_obs: jax.Array
    termination: jax.Array
    failed: jax.Array
    valid: jax.Array
    achieved: jax.Array
    ee_pos: jax.Array
    goal: jax.Array


class Her(NamedTuple):
    """``relabel(key, episode) -> (transitions [T, C, ...], mask [T, C], goals [T, C, G])``;
    ``copies`` = C."""

    relabel: Callable[[jax.Array, GoalEpisode], tuple[Transition, jax.Array, jax.Array]]
    copies: int
    strategy: str
    k: int


def num_copies(strategy: str, k: int) -> int:
    """How many times each transition is stored: 1 + number of additional goals."""
    if strategy not in STRATEGIES:
        raise ValueError(f"her strategy={strategy!r} is not valid; choose one of {', '.join(map(repr, STRATEGIES))}")
    if strategy in ("future", "random") and int(k) < 1:
        raise ValueError(f"her k={k!r} must be >= 1 for strategy {strategy!r}")
    return {"none": 1, "final": 2, "future": 1 + int(k), "random": 1 + int(k)}[strategy]


def make_her(
    env: GoalEnv,
    strategy: str,
    k: int = 2,
    goal_reached: Callable[[jax.Array, jax.Array], jax.Array] | None = None,
) -> Her:
    """Hindsight relabelling for ``env`` with ``strategy`` (see module doc) and ``k`` goals.

    ``goal_reached(achieved, goal) -> bool`` marks relabelled transitions that reach their new
    goal as terminal; default: ``env.goal_reached`` if the env has one, else only failures are
    terminal.

    Raises:
      ValueError: an unknown strategy (the message lists the valid ones) or ``k < 1``.
    """
    copies = num_copies(strategy, k)
    extra = copies - 1
    goal_reached = goal_reached if goal_reached is not None else getattr(env, "goal_reached", None)

    def extra_goals(key: jax.Array, ep: GoalEpisode, length: jax.Array) -> tuple[jax.Array, jax.Array]:
        """Additional goals ``[T, extra, G]`` and their validity ``[T, extra]``."""
        t_max = ep.action.shape[0]
        steps = jnp.arange(t_max)
        if strategy == "final":
            final_goal = ep.achieved[length]
            ok = env.in_feasible_region(ep.ee_pos[length]).astype(bool)
            goals = jnp.broadcast_to(final_goal, (t_max, 1, final_goal.shape[-1]))
            return goals, jnp.broadcast_to(ok, (t_max, 1))
        if strategy == "future":
            # achieved index j in [t + 1, L]: a state reached later in the same episode
            j = jax.random.randint(key, (t_max, extra), steps[:, None] + 1, length + 1)
            j = jnp.minimum(j, length)
            return ep.achieved[j], jnp.ones((t_max, extra), bool)
        keys = jax.random.split(key, t_max * extra)
        goals = jax.vmap(env.sample_goal)(keys).reshape(t_max, extra, -1)
        return goals, jnp.ones((t_max, extra), bool)

    def relabel(key: jax.Array, ep: GoalEpisode) -> tuple[Transition, jax.Array, jax.Array]:
        """Relabel one episode.

        Returns:
          ``(transitions, mask, goals)``: a :class:`Transition` of ``[T, C, ...]`` arrays
          (copy 0 is the original), ``mask [T, C] bool`` (store only these) and the goal of
          every copy ``[T, C, G]``.
        """
        chex.assert_rank([ep.reward, ep.valid, ep.achieved], [1, 1, 2])
        valid = ep.valid.astype(bool)
        length = jnp.sum(valid.astype(jnp.int32))
        real_goal = jnp.broadcast_to(ep.goal, (ep.reward.shape[0], ep.goal.shape[-1]))
        original = Transition(ep.obs, ep.action, ep.reward, ep.next_obs, ep.termination)
        if extra == 0:
            add_axis = jax.tree.map(lambda x: x[:, None], original)
            return add_axis, valid[:, None], real_goal[:, None]
        goals, ok = extra_goals(key, ep, length)  # [T, E, G], [T, E]

        def rebuild(goal_t, ach_prev, ach_next, ee_prev, ee_next, failed):
            reward = env.compute_reward(ach_next, goal_t, ach_prev)
            done = failed > 0
            if goal_reached is not None:
                done = done | goal_reached(ach_next, goal_t).astype(bool)
            return env.obs_from(ee_prev, goal_t), reward, env.obs_from(ee_next, goal_t), done.astype(jnp.float32)

        per_goal = jax.vmap(rebuild, in_axes=(0, None, None, None, None, None))
        per_step = jax.vmap(per_goal)
        obs, reward, next_obs, term = per_step(
            goals, ep.achieved[:-1], ep.achieved[1:], ep.ee_pos[:-1], ep.ee_pos[1:], ep.failed
        )
        action = jnp.broadcast_to(ep.action[:, None], (ep.action.shape[0], extra, ep.action.shape[-1]))
        relabelled = Transition(obs, action, reward.astype(ep.reward.dtype), next_obs, term)
        both = jax.tree.map(lambda a, b: jnp.concatenate([a[:, None], b], axis=1), original, relabelled)
        mask = jnp.concatenate([valid[:, None], ok & valid[:, None]], axis=1)
        all_goals = jnp.concatenate([real_goal[:, None], goals], axis=1)
        return both, mask, all_goals

    return Her(relabel=relabel, copies=copies, strategy=strategy, k=int(k) if extra else 0)


def flatten_copies(tree: Any) -> Any:
    """``[T, C, ...] -> [T * C, ...]`` for every leaf (rows in time order, copies adjacent)."""
    return jax.tree.map(lambda x: x.reshape(-1, *x.shape[2:]), tree)
