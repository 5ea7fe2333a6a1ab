"""DDPG actor and critic (SPEC §A1; thesis Fig. 3.4 and Fig. 3.10).

* Manipulator (§3.4.1): actor 3 × 100 ReLU with a ``tanh`` output; critic 3 × 100 ReLU with
  a linear output.  ``tanh`` gives actions in [-1, 1], which the environment multiplies by its
  scale vector C (``tanh · C``).
* Tracking (§3.5.2): actor 300–100 ReLU with a ``sigmoid`` output (actions in [0, 1], i.e.
  ``sigmoid · C`` after the environment's scaling); critic with the same widths.

The critic takes ``[s, a]``; with ``action_layer = k > 0`` the action is concatenated after
the k-th hidden layer instead (the driving critic of §6.1.1 uses k = 1).
The last layer of both networks starts small (uniform ±3e-3, as in the DDPG paper) so the
initial policy is near the centre of the action range and initial Q-values near 0.
"""

from __future__ import annotations

from collections.abc import Sequence

import flax.linen as nn
import jax
import jax.numpy as jnp

__all__ = ["OUTPUTS", "DDPGActor", "DDPGCritic"]

OUTPUTS = ("tanh", "sigmoid")


def _final(features: int) -> nn.Dense:
    init = nn.initializers.uniform(6e-3)
    return nn.Dense(features, kernel_init=lambda k, s, d=jnp.float32: init(k, s, d) - 3e-3,
                    bias_init=lambda k, s, d=jnp.float32: init(k, s, d) - 3e-3)


class DDPGActor(nn.Module):
    """Deterministic policy ``μ(s)``: ``[..., O] -> [..., A]``."""

    action_size: int
    hidden: Sequence[int] = (100, 100, 100)
    output: str = "tanh"

    @nn.compact
    def __call__(self, obs: jax.Array) -> jax.Array:
        x = obs
        for width in self.hidden:
            x = nn.relu(nn.Dense(width)(x))
        z = _final(self.action_size)(x)
        return jnp.tanh(z) if self.output == "tanh" else jax.nn.sigmoid(z)


class DDPGCritic(nn.Module):
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
        return _final(1)(x)[..., 0]
