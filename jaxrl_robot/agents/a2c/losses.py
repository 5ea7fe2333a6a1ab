"""Advantage actor-critic losses on one worker's local buffer ``[N]`` (thesis Eq. 4.3-4.5, Algorithm 3).

Every function takes a ``mask [N]`` of the buffer's filled slots (a buffer closes early at the
end of its episode, Algorithm 3 line 8) and averages over the filled slots only.
"""

from __future__ import annotations

import chex
import jax
import jax.numpy as jnp

from jaxrl_robot.returns import n_step_returns

__all__ = ["actor_loss", "critic_loss", "worker_targets"]


def _masked_mean(x: jax.Array, mask: jax.Array) -> jax.Array:
    return jnp.sum(x * mask) / jnp.maximum(jnp.sum(mask), 1.0)


def worker_targets(
    rewards: jax.Array,
    next_values: jax.Array,
    terminations: jax.Array,
    truncations: jax.Array,
    mask: jax.Array,
    gamma: float,
) -> jax.Array:
    """Targets ``R_t`` of Algorithm 3, lines 9-13: ``R ← r + γR`` backwards from the buffer end.

    ``R`` starts at 0 after a termination and at ``V(s_{t+1})`` otherwise (a time-limit
    truncation or a full buffer), i.e. the n-step return of Eq. 4.3 with ``n`` reaching to the
    buffer end. Slots past the buffer end (``mask = 0``) are cut from the recursion.

    Args:
      rewards, next_values, terminations, truncations: ``[N]`` as in ``returns.gae``;
        ``next_values[t] = V(s'_t)`` of the true successor.
      mask: ``[N]`` 1.0 on the filled slots.
      gamma: γ.
    Returns:
      ``[N]`` targets (garbage but finite on empty slots).
    """
    chex.assert_rank((rewards, next_values, terminations, truncations, mask), 1)
    # An empty slot ends the recursion like a truncation whose bootstrap is never read.
    cut = jnp.maximum(truncations, 1.0 - mask)
    return n_step_returns(rewards, next_values, terminations, cut, gamma, None)


def actor_loss(
    log_prob: jax.Array,
    advantages: jax.Array,
    entropy: jax.Array,
    mask: jax.Array,
    entropy_coef: float,
) -> jax.Array:
    """Negative objective of Eq. 4.4: ``-(1/N) Σ_t [log π(a_t|s_t) A_t + β H(π(·|s_t))]``.

    Its gradient is ``-g_π`` of Algorithm 3, line 15.

    Args:
      log_prob: ``[N]`` ``log π(a_t|s_t; θ'_π)`` (differentiated).
      advantages: ``[N]`` ``A_t = R_t - V(s_t)`` (Eq. 4.3; treated as a constant).
      entropy: ``[N]`` ``H(π(·|s_t; θ'_π))`` (differentiated).
      mask: ``[N]`` filled slots.
      entropy_coef: β.
    Returns:
      ``[]`` loss to minimise.
    """
    chex.assert_rank((log_prob, advantages, entropy, mask), 1)
    chex.assert_equal_shape((log_prob, advantages, entropy, mask))
    objective = log_prob * jax.lax.stop_gradient(advantages) + entropy_coef * entropy
    return -_masked_mean(objective, mask)


def critic_loss(values: jax.Array, targets: jax.Array, mask: jax.Array) -> jax.Array:
    """Eq. 4.5: ``(1/N) Σ_t (R_t - V(s_t; θ'_v))²`` (Algorithm 3, line 16).

    Args:
      values: ``[N]`` ``V(s_t)`` (differentiated).
      targets: ``[N]`` ``R_t`` (constant).
      mask: ``[N]`` filled slots.
    Returns:
      ``[]`` loss.
    """
    chex.assert_rank((values, targets, mask), 1)
    chex.assert_equal_shape((values, targets, mask))
    return _masked_mean((jax.lax.stop_gradient(targets) - values) ** 2, mask)
