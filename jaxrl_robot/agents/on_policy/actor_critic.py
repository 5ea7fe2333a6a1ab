"""The on-policy family's Gaussian actor and critic (:func:`make_actor_critic`, :func:`init_actor_critic`,
σ per action dimension :func:`action_sigma`) and the lanes' Gaussian draws (:func:`sample_lanes`)."""

from __future__ import annotations

from typing import Any

import jax
import jax.numpy as jnp

from jaxrl_robot.acting import per_lane_keys
from jaxrl_robot.agents.on_policy.config import ActorCriticConfig
from jaxrl_robot.networks import Critic, GaussianActor, gaussian_sample
from jaxrl_robot.validation import ConfigError

__all__ = ["action_sigma", "init_actor_critic", "make_actor_critic", "sample_lanes"]


def make_actor_critic(
    config: ActorCriticConfig, action_size: int, bn_axis_name: str | None = None, squash: bool = True
) -> tuple[GaussianActor, Critic]:
    """The Gaussian actor and the critic of ``config``; σ is broadcast to ``action_size``.

    ``bn_axis_name``: the mapped axis the actor's batch statistics are averaged over (the lanes'
    mesh axis when one batch spans every device's lanes), or None. ``squash``: ``tanh`` on the
    actor's mean (False: a linear mean, for actions squashed on the env's side).
    """
    actor = GaussianActor(
        action_size=action_size,
        hidden=tuple(config.actor_hidden),
        sigma=action_sigma(config, action_size),
        learn_std=config.learn_std,
        batch_norm=config.batch_norm,
        bn_momentum=config.bn_momentum,
        bn_mode=config.bn_mode,
        bn_axis_name=bn_axis_name,
        state_std=config.state_std,
        squash=squash,
        activation=config.activation,
    )
    return actor, Critic(hidden=tuple(config.critic_hidden), activation=config.activation)


def action_sigma(config: ActorCriticConfig, action_size: int) -> tuple[float, ...]:
    """``config.sigma`` with one value per action dimension (a single value is broadcast)."""
    sigma = tuple(config.sigma)
    if len(sigma) == 1:
        sigma = sigma * action_size
    if len(sigma) != action_size:
        raise ConfigError(f"sigma={config.sigma!r} must have 1 or action_size={action_size} values")
    return sigma


def init_actor_critic(
    key_actor: jax.Array, key_critic: jax.Array, actor: GaussianActor, critic: Critic, obs_size: int
) -> tuple[Any, Any, Any]:
    """``(actor params, actor batch_stats ({} without batch-norm), critic params)``."""
    dummy = jnp.zeros((1, obs_size), jnp.float32)
    actor_vars = actor.init(key_actor, dummy)
    return actor_vars["params"], actor_vars.get("batch_stats", {}), critic.init(key_critic, dummy)["params"]


def sample_lanes(key: jax.Array, lane_ids: jax.Array, mean: jax.Array, log_std: jax.Array) -> jax.Array:
    """Gaussian actions ``[B, A]``, lane ``i`` drawing with ``fold_in(key, lane_ids[i])``."""
    return jax.vmap(gaussian_sample)(per_lane_keys(key, lane_ids), mean, log_std)
