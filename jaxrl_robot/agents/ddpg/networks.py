"""DDPG actor and critic (thesis Fig. 3.4 and Fig. 3.10).

* Manipulator (§3.4.1): actor 3 × 100 ReLU with a ``tanh`` output; critic 3 × 100 ReLU with
  a linear output.  ``tanh`` gives actions in [-1, 1], which the environment multiplies by its
  scale vector C (``tanh · C``).
* Tracking (§3.5.2): actor 300–100 ReLU with a ``sigmoid`` output (actions in [0, 1], i.e.
  ``sigmoid · C`` after the environment's scaling); critic with the same widths.

The critic is the off-policy family's :class:`~jaxrl_robot.agents.off_policy.networks.QCritic`
(``DDPGCritic``).  The actor's last layer starts small (uniform ±3e-3, as in the DDPG paper) so the
initial policy is near the centre of the action range.
"""

from __future__ import annotations

from collections.abc import Sequence

import flax.linen as nn
import jax
import jax.numpy as jnp

from jaxrl_robot.agents.off_policy.networks import QCritic, final_layer

__all__ = ["OUTPUTS", "DDPGActor", "DDPGCritic"]

OUTPUTS = ("tanh", "sigmoid")

DDPGCritic = QCritic
"""DDPG's critic ``Q(s, a)``: the family's :class:`~jaxrl_robot.agents.off_policy.networks.QCritic`."""


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
        z = final_layer(self.action_size)(x)
        return jnp.tanh(z) if self.output == "tanh" else jax.nn.sigmoid(z)
