"""The off-policy family's critic: ``Q(s, a)`` (thesis Fig. 3.4 and Fig. 3.10), one or ``K`` of them.

The critic takes ``[s, a]``; with ``action_layer = k > 0`` the action is concatenated after the k-th
hidden layer instead (the driving critic of §6.1.1 uses k = 1).  Its last layer starts small (uniform
±3e-3, as in the DDPG paper) so that the initial Q-values are near 0.  Twin critics (TD3's and SAC's)
are two parameter sets stacked on a leading axis of size 2 (:func:`init_critics`, :func:`critic_values`).
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any

import flax.linen as nn
import jax
import jax.numpy as jnp

__all__ = ["QCritic", "critic_values", "final_layer", "first_critic", "init_critics"]


def final_layer(features: int) -> nn.Dense:
    """A dense output layer with weights and biases drawn uniformly from ±3e-3."""
    init = nn.initializers.uniform(6e-3)
    return nn.Dense(features, kernel_init=lambda k, s, d=jnp.float32: init(k, s, d) - 3e-3,
                    bias_init=lambda k, s, d=jnp.float32: init(k, s, d) - 3e-3)


class QCritic(nn.Module):
    """Action value ``Q(s, a)``: ``([..., O], [..., A]) -> [...]``."""

    hidden: Sequence[int] = (100, 100, 100)
    action_layer: int = 0

    @nn.compact
    def __call__(self, obs: jax.Array, action: jax.Array) -> jax.Array:
        x = obs
        for i, width in enumerate(self.hidden):
            if i == self.action_layer:
                x = jnp.concatenate([x, action], axis=-1)
            x = nn.relu(nn.Dense(width)(x))
        if self.action_layer >= len(self.hidden):
            x = jnp.concatenate([x, action], axis=-1)
        return final_layer(1)(x)[..., 0]


def init_critics(critic: QCritic, key: jax.Array, obs_size: int, action_size: int, twin: bool) -> Any:
    """The critic's parameters; with ``twin``, two sets (keys ``split(key, 2)``) stacked on a leading axis of 2."""
    dummy_obs = jnp.zeros((1, obs_size), jnp.float32)
    dummy_act = jnp.zeros((1, action_size), jnp.float32)
    if twin:
        return jax.vmap(lambda k: critic.init(k, dummy_obs, dummy_act))(jax.random.split(key, 2))
    return critic.init(key, dummy_obs, dummy_act)


def critic_values(critic: QCritic, twin: bool) -> Callable[[Any, jax.Array, jax.Array], jax.Array]:
    """``(params, obs [N, O], action [N, A]) -> [K, N]``: every critic's ``Q_k(s, a)`` (``K`` = 2 with ``twin``)."""

    def values(params: Any, obs: jax.Array, action: jax.Array) -> jax.Array:
        if twin:
            return jax.vmap(critic.apply, in_axes=(0, None, None))(params, obs, action)
        return critic.apply(params, obs, action)[None]

    return values


def first_critic(critic: QCritic, twin: bool) -> Callable[[Any, jax.Array, jax.Array], jax.Array]:
    """``(params, obs [N, O], action [N, A]) -> [N]``: ``Q1(s, a)``, the first critic's value."""

    def value(params: Any, obs: jax.Array, action: jax.Array) -> jax.Array:
        if twin:
            return critic.apply(jax.tree.map(lambda x: x[0], params), obs, action)
        return critic.apply(params, obs, action)

    return value
