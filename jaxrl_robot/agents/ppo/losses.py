"""PPO objectives on one mini-batch ``[B]`` (thesis Eq. 5.3-5.5, Algorithm 8).

:func:`make_actor_loss` combines them with the Gaussian actor into the loss of one actor step.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import chex
import jax
import jax.numpy as jnp

from jaxrl_robot.agents.ppo.config import PPOConfig
from jaxrl_robot.networks import (
    GaussianActor,
    apply_actor,
    gaussian_entropy,
    gaussian_kl,
    gaussian_log_prob,
    tanh_gaussian_entropy,
)

__all__ = [
    "LOG_RATIO_LIMIT",
    "adapt_kl_beta",
    "clipped_surrogate_loss",
    "kl_penalty_loss",
    "make_actor_loss",
    "value_loss",
]

LOG_RATIO_LIMIT = 20.0
"""|log r| is clipped here before ``exp``: beyond it r overflows float32 (e^88) with a narrow σ
(0.1 on an action in [-1, 1] allows |log r| up to ~200), and one inf ratio with a negative
advantage would turn the gradient into NaN. Such samples then carry no gradient."""


def _ratio(log_prob: jax.Array, old_log_prob: jax.Array) -> jax.Array:
    log_ratio = log_prob - jax.lax.stop_gradient(old_log_prob)
    return jnp.exp(jnp.clip(log_ratio, -LOG_RATIO_LIMIT, LOG_RATIO_LIMIT))


def clipped_surrogate_loss(
    log_prob: jax.Array, old_log_prob: jax.Array, advantages: jax.Array, clip_eps: float
) -> tuple[jax.Array, jax.Array]:
    """Negative clipped objective ``-mean(min(r A, clip(r, 1-ε, 1+ε) A))`` (Eq. 5.5).

    Args:
      log_prob: ``[B]`` ``log π_θ(a|s)`` (differentiated).
      old_log_prob: ``[B]`` ``log π_θold(a|s)`` (treated as a constant).
      advantages: ``[B]`` ``A_t`` (constant).
      clip_eps: ε.
    The log-ratio is clipped to ±:data:`LOG_RATIO_LIMIT` before ``exp`` (overflow guard).
    Returns:
      ``(loss [], clip_fraction [])``: the loss to minimise and the share of clipped ratios.
    """
    chex.assert_rank((log_prob, old_log_prob, advantages), 1)
    chex.assert_equal_shape((log_prob, old_log_prob, advantages))
    ratio = _ratio(log_prob, old_log_prob)
    advantages = jax.lax.stop_gradient(advantages)
    clipped = jnp.clip(ratio, 1.0 - clip_eps, 1.0 + clip_eps)
    objective = jnp.minimum(ratio * advantages, clipped * advantages)
    clip_fraction = jnp.mean((jnp.abs(ratio - 1.0) > clip_eps).astype(jnp.float32))
    return -jnp.mean(objective), clip_fraction


def kl_penalty_loss(
    log_prob: jax.Array, old_log_prob: jax.Array, advantages: jax.Array, kl: jax.Array, beta: jax.Array
) -> jax.Array:
    """Negative KL-penalised objective ``-mean(r A - β KL(π_old ‖ π_θ))`` (Eq. 5.3).

    Args:
      log_prob, old_log_prob, advantages: ``[B]`` as in :func:`clipped_surrogate_loss`.
      kl: ``[B]`` ``KL(π_θold(·|s) ‖ π_θ(·|s))`` per state (differentiated).
      beta: ``[]`` penalty coefficient β (constant).
    Returns:
      ``[]`` loss to minimise.
    """
    chex.assert_rank((log_prob, old_log_prob, advantages, kl), 1)
    chex.assert_equal_shape((log_prob, old_log_prob, advantages, kl))
    ratio = _ratio(log_prob, old_log_prob)
    objective = ratio * jax.lax.stop_gradient(advantages) - jax.lax.stop_gradient(beta) * kl
    return -jnp.mean(objective)


def adapt_kl_beta(
    beta: jax.Array, kl: jax.Array, kl_target: float, beta_min: float = 0.0, beta_max: float = float("inf")
) -> jax.Array:
    """The halve/double rule after Eq. 5.4, kept within ``[beta_min, beta_max]``.

    ``β/2`` if ``D < D_thre / 1.5``; ``2β`` if ``D > 1.5 D_thre``; otherwise unchanged. Without
    a floor, a long run of small KLs halves β towards 0 (after 130 halvings it is 0 in float32)
    and the first large step then meets no penalty; doubling back takes as many iterations.

    Args:
      beta: ``[]`` current β.
      kl: ``[]`` D, the mean KL divergence over the sampled transitions (Eq. 5.4).
      kl_target: D_thre.
      beta_min, beta_max: bounds on the result.
    """
    chex.assert_rank((beta, kl), 0)
    beta = jnp.where(kl < kl_target / 1.5, beta / 2.0, beta)
    beta = jnp.where(kl > 1.5 * kl_target, beta * 2.0, beta)
    return jnp.clip(beta, beta_min, beta_max)


def value_loss(values: jax.Array, targets: jax.Array) -> jax.Array:
    """Critic loss ``mean((R_t - V(s_t))²)`` (Algorithm 8, line 14): ``[B], [B] -> []``."""
    chex.assert_rank((values, targets), 1)
    chex.assert_equal_shape((values, targets))
    return jnp.mean((jax.lax.stop_gradient(targets) - values) ** 2)


def make_actor_loss(config: PPOConfig, actor: GaussianActor, forward: Callable | None = None) -> Callable:
    """``loss(params, stats, minibatch, beta) -> (loss, (new_stats, clip_fraction, entropy, kl))``.

    ``minibatch = (obs [B, D], action [B, A], advantage [B], old_mean [B, A], old_log_std [B, A])``
    where ``old_*`` are π_old's outputs as it acted. π_θ runs in training mode (batch
    statistics; ``new_stats`` are the advanced moving averages): ``forward(params, stats, obs) ->
    ((mean, log_std) [B, A], new_stats)``, by default ``apply_actor(actor, ..., train=True)``; a
    recurrent actor's ``forward`` takes its sequences (with their stored start states) in place of
    ``obs`` and returns ``[B, A]`` outputs, ``B`` the steps of all sequences. The ratio
    ``r = π_θ(a|s) / π_old(a|s)`` enters the clipped objective (Eq. 5.5) or the KL-penalty
    objective (Eq. 5.3) with ``kl = KL(π_old ‖ π_θ)``, mean over the mini-batch; minus
    ``entropy_coef`` times the mean entropy: the Gaussian's, or with ``tanh_actions`` that of the squashed
    action (:func:`~jaxrl_robot.networks.tanh_gaussian_entropy` at the noise that drew each stored action,
    ``(action − old_mean) / old_σ``), which keeps the mean out of tanh's flat tails.
    """

    if forward is None:

        def forward(params: Any, stats: Any, obs: jax.Array):
            return apply_actor(actor, params, stats, obs, train=True)

    def loss_fn(params: Any, stats: Any, mb: tuple, beta: jax.Array):
        inputs, action, adv, old_mean, old_log_std = mb
        (mean, log_std), new_stats = forward(params, stats, inputs)
        log_prob = gaussian_log_prob(mean, log_std, action)
        old_log_prob = gaussian_log_prob(old_mean, old_log_std, action)
        kl = gaussian_kl(old_mean, old_log_std, mean, log_std)
        if config.tanh_actions:
            noise = jax.lax.stop_gradient((action - old_mean) * jnp.exp(-old_log_std))
            entropy = jnp.mean(tanh_gaussian_entropy(mean, log_std, noise))
        else:
            entropy = jnp.mean(gaussian_entropy(log_std))
        if config.objective == "clip":
            loss, clip_frac = clipped_surrogate_loss(log_prob, old_log_prob, adv, config.clip_eps)
        else:
            loss = kl_penalty_loss(log_prob, old_log_prob, adv, kl, beta)
            log_ratio = jnp.clip(log_prob - old_log_prob, -LOG_RATIO_LIMIT, LOG_RATIO_LIMIT)
            clip_frac = jnp.mean((jnp.abs(jnp.exp(log_ratio) - 1.0) > config.clip_eps) * 1.0)
        loss = loss - config.entropy_coef * entropy
        return loss, (new_stats, clip_frac, entropy, jnp.mean(kl))

    return loss_fn
