"""The off-policy family's losses and target updates (thesis §3.1, Algorithm 1, Eq. 3.4–3.6; clipped
double Q, Eq. 6.2): what DDPG, TD3 and SAC share.

Functions take mini-batch arrays ``[N]`` (``[K, N]`` for ``K`` critics) and are written for one
mini-batch; network calls stay with the caller, so the losses are independent of the architecture.
An algorithm's own objectives are in its package (``ddpg.losses``: target smoothing; ``sac.losses``:
the tanh-Gaussian policy and the temperature).
"""

from __future__ import annotations

from typing import Any

import chex
import jax
import jax.numpy as jnp
import optax

__all__ = [
    "actor_loss",
    "anchored_actor_loss",
    "clipped_double_q",
    "critic_loss",
    "linear_noise_factor",
    "soft_update",
    "td_target",
    "twin_critic_loss",
]


def td_target(reward: jax.Array, termination: jax.Array, next_q: jax.Array, gamma: float) -> jax.Array:
    """Eq. 3.5 with termination: ``y = r + γ (1 − d) Q'(s', μ'(s'))``: ``[N] -> [N]``.

    ``d`` is 1 only where ``s'`` is terminal (success or failure); a time-limit truncation
    keeps ``d = 0`` and bootstraps.  The target carries no gradient.
    """
    chex.assert_rank([reward, termination, next_q], 1)
    chex.assert_equal_shape([reward, termination, next_q])
    return jax.lax.stop_gradient(reward + gamma * (1.0 - termination) * next_q)


def critic_loss(q: jax.Array, target: jax.Array, weights: jax.Array | None = None) -> tuple[jax.Array, jax.Array]:
    """Eq. 3.4: ``L = mean_i w_i (Q_i − y_i)²``, with importance weights ``w`` under PER (Eq. 3.10).

    Args:
      q: ``[N]`` critic values ``Q(s, a)``.
      target: ``[N]`` targets ``y`` (:func:`td_target`).
      weights: optional ``[N]`` importance weights (1 without PER).
    Returns:
      ``(loss [], td_error [N])`` with ``td_error = y − Q`` (for the new priorities).
    """
    chex.assert_rank([q, target], 1)
    chex.assert_equal_shape([q, target])
    td = target - q
    sq = td**2
    if weights is not None:
        chex.assert_equal_shape([q, weights])
        sq = weights * sq
    return jnp.mean(sq), td


def clipped_double_q(next_q: jax.Array) -> jax.Array:
    """Clipped double Q (TD3, Eq. 6.2): ``min_k Q'_k(s', a')`` over the critics: ``[K, N] -> [N]``.

    With ``K = 1`` this is plain DDPG's ``Q'(s', a')``; fed to :func:`td_target` it gives
    ``y = r + γ (1 − d) min(Q1', Q2')``.
    """
    chex.assert_rank(next_q, 2)
    return jnp.min(next_q, axis=0)


def twin_critic_loss(
    q: jax.Array, target: jax.Array, weights: jax.Array | None = None
) -> tuple[jax.Array, jax.Array]:
    """Eq. 3.4 for each of ``K`` critics regressed on the same target, summed over the critics.

    Args:
      q: ``[K, N]`` values ``Q_k(s, a)``.
      target: ``[N]`` shared targets ``y``.
      weights: optional ``[N]`` importance weights.
    Returns:
      ``(Σ_k mean_i w_i (Q_k,i − y_i)² [], td_error [K, N])``.
    """
    chex.assert_rank(q, 2)
    losses, td = jax.vmap(lambda qk: critic_loss(qk, target, weights))(q)
    return jnp.sum(losses), td


def actor_loss(q_of_policy: jax.Array) -> jax.Array:
    """Eq. 3.6 as a loss: ``−mean_i Q(s_i, μ(s_i))``; its gradient is ``−∇_a Q ∇_θ μ`` averaged."""
    chex.assert_rank(q_of_policy, 1)
    return -jnp.mean(q_of_policy)


def anchored_actor_loss(q_of_policy: jax.Array, imitation: jax.Array, weight: float) -> jax.Array:
    """The actor's loss with a behaviour-cloning term, Q normalised as in TD3+BC (Fujimoto & Gu, 2021):
    ``−mean_i Q_i / mean_i |Q_i| + weight · imitation``, the scale ``mean |Q|`` held constant (no
    gradient) and kept ≥ 1e-6, so that the Q term's gradient does not grow with the size of the
    returns.  ``q_of_policy [N]``, ``imitation []`` (e.g. :func:`jaxrl_robot.imitation.imitation_loss`
    of the actor on the expert's pairs) -> ``[]``.  TD3+BC's α = 2.5 with a squared error averaged over
    the ``A`` action dimensions is ``weight = 1 / (2.5 A)`` here, the imitation loss being a sum over them."""
    chex.assert_rank(q_of_policy, 1)
    scale = jax.lax.stop_gradient(jnp.maximum(jnp.mean(jnp.abs(q_of_policy)), 1e-6))
    return actor_loss(q_of_policy) / scale + weight * imitation


def soft_update(target: Any, online: Any, tau: float) -> Any:
    """``θ' ← ε θ + (1 − ε) θ'`` for every leaf (Algorithm 1, lines 16–17)."""
    return optax.incremental_update(online, target, tau)


def linear_noise_factor(iteration: jax.Array, iterations: int, end_factor: float, decay_fraction: float) -> jax.Array:
    """Exploration-noise multiplier ``1 + (end − 1) · min(1, i / (decay_fraction · iterations))``: ``[] -> []``.

    Falls linearly from 1 at iteration 0 to ``end_factor`` after ``decay_fraction`` of the run's
    ``iterations`` and stays there.
    """
    horizon = max(decay_fraction * iterations, 1e-9)
    frac = jnp.minimum(jnp.asarray(iteration, jnp.float32) / horizon, 1.0)
    return 1.0 + (end_factor - 1.0) * frac
