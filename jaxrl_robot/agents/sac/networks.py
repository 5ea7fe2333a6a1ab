"""SAC's policy network: a tanh-Gaussian actor (brax's ``make_sac_networks`` shape: an MLP with ReLU
whose last layer gives the mean and the pre-softplus scale of each action dimension).  The critic is the
off-policy family's twin :class:`~jaxrl_robot.agents.off_policy.networks.QCritic`."""

from __future__ import annotations

from collections.abc import Sequence

import flax.linen as nn
import jax
import jax.numpy as jnp

__all__ = ["SACActor", "mode"]


class SACActor(nn.Module):
    """``obs [..., O] -> (loc [..., A], raw scale [..., A])`` of the Gaussian before the tanh
    (σ = softplus(raw) + min_std, :func:`~jaxrl_robot.agents.sac.losses.gaussian_scale`)."""

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

