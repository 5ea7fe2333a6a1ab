"""Advantage actor-critic losses on one worker's local buffer ``[N]`` (thesis Eq. 4.3-4.5, Algorithm 3).

Every function takes a ``mask [N]`` of the buffer's filled slots (a buffer closes early at the
end of its episode, Algorithm 3 line 8) and averages over the filled slots only.
:func:`make_worker_loss` combines them over the lanes of a buffer — a
:class:`~jaxrl_robot.types.Transition` ``[N, L]`` and its ``mask [N, L]`` — into the loss whose
gradient a worker pushes.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import chex
import jax
import jax.numpy as jnp

from jaxrl_robot import parallel
from jaxrl_robot.agents.a2c.config import A2CConfig
from jaxrl_robot.networks import Critic, GaussianActor, apply_actor, gaussian_entropy, gaussian_log_prob
from jaxrl_robot.returns import n_step_returns
from jaxrl_robot.types import Metrics, Transition

__all__ = ["actor_loss", "critic_loss", "make_worker_loss", "worker_targets"]


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


def make_worker_loss(
    config: A2CConfig, actor: GaussianActor, critic: Critic, axis_name: str | None = None
) -> Callable[[tuple[Any, Any], Any, Transition, jax.Array], tuple[jax.Array, tuple[Any, Metrics]]]:
    """``worker_loss((actor_params, critic_params), actor_stats, traj [N, L], mask [N, L]) -> (loss,
    (new_stats, info))`` on the lanes' buffers: the transitions ``traj`` (its ``obs``, ``action``,
    ``reward``, ``next_obs``, ``termination`` and ``truncation``) and ``mask``, 1.0 on the filled slots.

    ``loss`` is the mean over the ``L`` lanes of each lane's Eq. 4.4 (negated) + Eq. 4.5, each
    averaged over the lane's filled slots. Its gradient with respect to the actor and critic
    parameters is the mean over lanes of ``(-g_π, g_v)`` of Algorithm 3, lines 15-16 (the two
    parameter sets are disjoint, so each gets only its own loss's gradient). ``new_stats`` are
    the actor's batch-norm moving averages after normalising the buffer — per lane and then
    averaged (``bn_batch='lane'``) or over all ``L · N`` transitions (``'update'``). With
    ``normalize_advantages`` the advantages are standardised over all filled slots of the
    buffer, pooled over the mapped axis ``axis_name`` if given (A2C's devices).
    """

    def worker_loss(
        diff_params: tuple[Any, Any], actor_stats: Any, traj: Transition, mask: jax.Array
    ) -> tuple[jax.Array, tuple[Any, Metrics]]:
        actor_params, critic_params = diff_params
        values = critic.apply({"params": critic_params}, traj.obs)
        next_values = jax.lax.stop_gradient(critic.apply({"params": critic_params}, traj.next_obs))
        rewards = traj.reward * config.reward_scale
        targets = jax.vmap(worker_targets, in_axes=(1, 1, 1, 1, 1, None), out_axes=1)(
            rewards, next_values, traj.termination, traj.truncation, mask, config.gamma
        )
        targets = jax.lax.stop_gradient(targets)
        adv = targets - jax.lax.stop_gradient(values)
        if config.normalize_advantages:
            adv = _standardize(adv, mask, axis_name)
        (mean, log_std), new_stats = _train_actor(config, actor, actor_params, actor_stats, traj.obs, mask)
        log_prob = gaussian_log_prob(mean, log_std, traj.action)
        entropy = gaussian_entropy(log_std)
        lane_losses = jax.vmap(actor_loss, in_axes=(1, 1, 1, 1, None))(
            log_prob, adv, entropy, mask, config.entropy_coef
        )
        lane_c_losses = jax.vmap(critic_loss, in_axes=(1, 1, 1))(values, targets, mask)
        a_loss, c_loss = jnp.mean(lane_losses), jnp.mean(lane_c_losses)
        counts = jnp.maximum(jnp.sum(mask, axis=0), 1.0)  # [L]
        lane_mean = lambda x: jnp.mean(jnp.sum(x * mask, axis=0) / counts)
        info = {
            "actor_loss": a_loss,
            "critic_loss": c_loss,
            "entropy": lane_mean(entropy),
            "value": lane_mean(values),
            "advantage": lane_mean(adv),
        }
        return a_loss + c_loss, (new_stats, info)

    return worker_loss


def _standardize(adv: jax.Array, mask: jax.Array, axis_name: str | None) -> jax.Array:
    """``adv [N, L]`` to zero mean and unit variance over every filled slot behind one gradient (all
    devices' lanes for A2C: summed over ``axis_name``)."""
    total = jnp.stack([jnp.sum(mask), jnp.sum(adv * mask), jnp.sum(adv**2 * mask)])
    if axis_name is not None:
        total = parallel.psum(total, axis_name)
    mu = total[1] / total[0]
    std = jnp.sqrt(jnp.maximum(total[2] / total[0] - mu**2, 0.0))
    return (adv - mu) / (std + 1e-8)


def _train_actor(
    config: A2CConfig, actor: GaussianActor, params: Any, stats: Any, obs: jax.Array, mask: jax.Array
) -> tuple[tuple[jax.Array, jax.Array], Any]:
    """The actor in training mode on the buffers ``obs [N, L, D]``: ``((mean, log_std) [N, L, A], new
    moving averages)``, batch statistics of each lane's filled slots (``bn_batch='lane'``, the lanes'
    moving averages then averaged) or of all of them (``'update'``)."""
    if config.bn_batch == "lane":
        lane_actor = lambda o, m: apply_actor(actor, params, stats, o, train=True, mask=m)
        (mean, log_std), new_stats = jax.vmap(lane_actor, in_axes=(1, 1), out_axes=(1, 0))(obs, mask)
        return (mean, log_std), jax.tree.map(lambda x: jnp.mean(x, axis=0), new_stats)
    flat = lambda x: x.reshape((-1,) + x.shape[2:])
    (mean, log_std), new_stats = apply_actor(actor, params, stats, flat(obs), train=True, mask=flat(mask))
    return tuple(x.reshape(mask.shape + x.shape[1:]) for x in (mean, log_std)), new_stats
