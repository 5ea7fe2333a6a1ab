"""Shared data types: the one transition type, the trainer interface, running statistics.

``Trainer`` is the contract between an algorithm (``jaxrl_robot.agents.<algo>``) and the
command-line driver (``train/run.py``): the algorithm supplies pure functions, the
driver jits them, calls ``update`` chunk after chunk, logs, checkpoints and evaluates.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, NamedTuple

import jax
from flax import struct

__all__ = ["Metrics", "Policy", "RecurrentPolicy", "RunningStats", "Trainer", "Transition", "as_recurrent"]

Metrics = dict[str, jax.Array]
"""Scalar metrics of one update chunk (name -> ``[]`` array)."""

Policy = Callable[[jax.Array], jax.Array]
"""A deterministic policy ``obs [..., D] -> action [..., A]`` in the env's action space [-1, 1]."""


class RecurrentPolicy(NamedTuple):
    """A policy with memory: a recurrent network's carry, or the PRNG key of a policy that samples
    (:func:`jaxrl_robot.evaluation.sampling_policy`).

    Attributes:
      carry: the memory one episode starts from, unbatched (``[...]`` leaves; a batch of ``E``
        episodes broadcasts it to ``[E, ...]``).
      step: ``(carry, obs [..., D]) -> (carry, action [..., A])``, the action as the env receives it.
    """

    carry: Any
    step: Callable[[Any, jax.Array], tuple[Any, jax.Array]]


def as_recurrent(policy: Policy | RecurrentPolicy) -> RecurrentPolicy:
    """``policy`` as a :class:`RecurrentPolicy` (a memoryless one gets the empty carry ``()``)."""
    if isinstance(policy, RecurrentPolicy):
        return policy
    return RecurrentPolicy(carry=(), step=lambda carry, obs: (carry, policy(obs)))


class Transition(NamedTuple):
    """One environment step per lane — what a rollout produces and what a replay memory stores; leaves
    are ``[...]`` (``[T, B]`` after a rollout, ``[capacity]`` in a replay memory).

    Attributes:
      obs: ``[..., D]`` observation ``s_t`` the action was chosen from.
      action: ``[..., A]`` action ``a_t`` as sampled (before the env clips it to [-1, 1]; an
        off-policy agent stores it in [-1, 1], before the env's scale C).
      reward: ``[...]`` reward ``r_t``.
      next_obs: ``[..., D]`` the true successor ``s'_t`` (the final observation at an episode end,
        not the next episode's first observation).
      termination: ``[...]`` 1.0 where ``s'_t`` is terminal (success or failure): no bootstrap.
      truncation: ``[...]`` 1.0 where the time limit cut the episode at ``t``: bootstrap from ``V(s'_t)``.
      done: ``[...]`` 1.0 where the episode ended at ``t`` (termination or truncation).
      metrics: env metrics of the step (final values where ``done``), plus ``episode_return``
        and ``episode_length`` (totals of the finished episode where ``done``).

    The last three default to ``()`` (no arrays): a replay memory's rows (``jaxrl_robot.replay``) hold
    only what the off-policy critic target needs, ``(s, a, r, s', d)`` with ``d`` the termination.
    """

    obs: jax.Array
    action: jax.Array
    reward: jax.Array
    next_obs: jax.Array
    termination: jax.Array
    truncation: Any = ()
    done: Any = ()
    metrics: Any = ()


@struct.dataclass
class RunningStats:
    """Running mean and variance of observations (parallel Welford); see ``networks.normalize``.

    Attributes:
      count: ``[]`` number of samples seen (float, starts at a tiny value to avoid 0/0).
      mean: ``[D]``.
      var: ``[D]`` population variance.
    """

    count: jax.Array
    mean: jax.Array
    var: jax.Array


class Trainer(NamedTuple):
    """The "chunked jitted update + train state + metrics" interface used by ``train/run.py``.

    All callables are pure; the caller jits them. ``state`` is any pytree of arrays (a
    ``flax.struct.dataclass``) holding *everything* a run needs to continue exactly —
    parameters, optimiser states, normaliser, environment states, RNG key, counters — so
    that a checkpoint of it is a complete resume point.

    Attributes:
      init: ``key -> state``.
      update: ``state -> (state, metrics)``: one chunk of ``iterations_per_update`` training
        iterations; ``metrics`` are scalars (means over the chunk; episode statistics over the
        episodes that finished in the chunk, NaN where none did).
      policy: ``state -> Policy`` (or a :class:`RecurrentPolicy`): the deterministic (mean)
        action for evaluation.
      num_updates: chunks in the whole run.
      env_steps_per_update: environment steps consumed by one ``update``.
      sample_policy: ``(state, key) -> RecurrentPolicy`` acting as in training (actions drawn from the
        stochastic policy, passed on as the env receives them), or None for a trainer without one.
    """

    init: Callable[[jax.Array], Any]
    update: Callable[[Any], tuple[Any, Metrics]]
    policy: Callable[[Any], Policy | RecurrentPolicy]
    num_updates: int
    env_steps_per_update: int
    sample_policy: Callable[[Any, jax.Array], RecurrentPolicy] | None = None
