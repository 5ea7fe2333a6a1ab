"""DDPG's own loss pieces: target policy smoothing (TD3, Eq. 6.3).

The losses DDPG shares with its family (the TD target, Eq. 3.5; the critic loss, Eq. 3.4; the actor
loss, Eq. 3.6; clipped double Q, Eq. 6.2; soft target updates) are
:mod:`jaxrl_robot.agents.off_policy.losses`.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

__all__ = ["smooth_target_action"]


def smooth_target_action(key: jax.Array, action: jax.Array, noise: float, noise_clip: float) -> jax.Array:
    """Target policy smoothing: ``clip(a + clip(ξ, −c, c), −1, 1)`` with ``ξ ~ N(0, noise²)``: ``[N, A] -> [N, A]``.

    Applied to the target actor's action ``μ'(s')`` before ``Q'`` in the critic target, so the
    target is an average of ``Q'`` over nearby actions (Fujimoto et al. 2018).
    """
    xi = noise * jax.random.normal(key, action.shape, action.dtype)
    return jnp.clip(action + jnp.clip(xi, -noise_clip, noise_clip), -1.0, 1.0)
