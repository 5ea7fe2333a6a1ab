"""SAC's policy and objectives (Haarnoja et al. 2018, "Soft Actor-Critic Algorithms and Applications"; brax's
``sac/networks.py`` and ``sac/losses.py``): the tanh-Gaussian actor (:class:`SACActor`), its draws,
log-probabilities and mode, the soft value of the critic target, the actor loss and the temperature loss.
Mini-batch arrays ``[N]``; the caller holds the networks.  The critic loss and the target's reward, discount
and clipping are the off-policy family's (:func:`~jaxrl_robot.agents.off_policy.losses.twin_critic_loss`,
:func:`~jaxrl_robot.agents.off_policy.learner.critic_target`).
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import chex
import flax.linen as nn
import jax
import jax.numpy as jnp

__all__ = [
    "SACActor",
    "actor_loss",
    "alpha_loss",
    "gaussian_scale",
    "mode",
    "soft_value",
    "tanh_gaussian_log_prob",
    "tanh_gaussian_sample",
]

_LOG_2PI = math.log(2.0 * math.pi)


class SACActor(nn.Module):
    """The tanh-Gaussian policy's network (brax's ``make_sac_networks`` shape: an MLP with ReLU whose last
    layer gives the mean and the pre-softplus scale of each action dimension):
    ``obs [..., O] -> (loc [..., A], raw scale [..., A])`` of the Gaussian before the tanh
    (σ = softplus(raw) + min_std, :func:`gaussian_scale`)."""

    action_size: int
    hidden: Sequence[int] = (256, 256)

    @nn.compact
    def __call__(self, obs: jax.Array) -> tuple[jax.Array, jax.Array]:
        x = obs
        for width in self.hidden:
            x = nn.relu(nn.Dense(width)(x))
        out = nn.Dense(2 * self.action_size)(x)
        return out[..., : self.action_size], out[..., self.action_size :]


def mode(loc: jax.Array) -> jax.Array:
    """The deterministic action ``tanh(loc)`` (the tanh of the Gaussian's mean): ``[..., A] -> [..., A]``."""
    return jnp.tanh(loc)


def gaussian_scale(raw: jax.Array, min_std: float) -> jax.Array:
    """σ = softplus(raw) + min_std (brax's ``NormalTanhDistribution``): ``[..., A] -> [..., A]``."""
    return jax.nn.softplus(raw) + min_std


def tanh_gaussian_log_prob(u: jax.Array, loc: jax.Array, scale: jax.Array) -> jax.Array:
    """``log π(a)`` of ``a = tanh(u)``, ``u ~ N(loc, scale²)`` (the paper's Eq. 26, the change of variables):
    ``Σ_i [log N(u_i; loc_i, σ_i) − log(1 − tanh²(u_i))]`` with ``log(1 − tanh² u) = 2 (log 2 − u −
    softplus(−2u))`` (exact and finite for any u): ``[..., A] -> [...]``."""
    chex.assert_equal_shape([u, loc, scale])
    z = (u - loc) / scale
    log_normal = -0.5 * z**2 - jnp.log(scale) - 0.5 * _LOG_2PI
    log_det = 2.0 * (jnp.log(2.0) - u - jax.nn.softplus(-2.0 * u))
    return jnp.sum(log_normal - log_det, axis=-1)


def tanh_gaussian_sample(key: jax.Array, loc: jax.Array, scale: jax.Array) -> tuple[jax.Array, jax.Array]:
    """A draw ``a = tanh(loc + σ ξ)``, ``ξ ~ N(0, 1)``, and its ``log π(a)`` (reparametrised: the gradient
    flows into ``loc`` and ``σ``): ``[..., A] -> ([..., A], [...])``."""
    u = loc + scale * jax.random.normal(key, loc.shape, loc.dtype)
    return jnp.tanh(u), tanh_gaussian_log_prob(u, loc, scale)


def soft_value(next_q: jax.Array, next_log_prob: jax.Array, alpha: jax.Array) -> jax.Array:
    """The soft value of ``s'`` in the critic target, ``min_k Q'_k(s', a') − α log π(a'|s')`` with ``a'`` a
    draw of the policy (the paper's Eq. 3 with clipped double Q): ``([K, N], [N], []) -> [N]``."""
    chex.assert_rank([next_q, next_log_prob], [2, 1])
    return jnp.min(next_q, axis=0) - alpha * next_log_prob


def actor_loss(q: jax.Array, log_prob: jax.Array, alpha: jax.Array) -> jax.Array:
    """The policy's loss ``mean_i (α log π(a_i|s_i) − min_k Q_k(s_i, a_i))`` with ``a_i`` reparametrised
    draws (the paper's Eq. 7; α held constant): ``([N], [N], []) -> []``."""
    chex.assert_rank([q, log_prob], 1)
    return jnp.mean(jax.lax.stop_gradient(alpha) * log_prob - q)


def alpha_loss(log_alpha: jax.Array, log_prob: jax.Array, target_entropy: float) -> jax.Array:
    """The temperature's loss ``mean_i α (−log π(a_i|s_i) − H̄)`` with ``α = exp(log_alpha)`` and the policy's
    log-probabilities held constant (the paper's Eq. 18, as brax writes it): below the target entropy ``H̄``
    its gradient raises α, above it lowers α.  ``([], [N]) -> []``."""
    chex.assert_rank([log_alpha, log_prob], [0, 1])
    return jnp.mean(jnp.exp(log_alpha) * jax.lax.stop_gradient(-log_prob - target_entropy))
