"""Supervised pre-training of the actor by action search (thesis §5.6, Algorithm 9).

At every visited state, :func:`action_search` tries ``M`` uniform random actions through the
env's known kinematics (``env.model_reward(state, action) -> reward``) and keeps the best; where
its reward beats the reward the policy's own action earned, the pair ``(s, a*)`` is a training
example.  The actor's mean is fitted to those examples by plain SGD on :func:`imitation_loss`;
the critic keeps fitting λ-returns (Eq. 5.14) as in PPO.  ``jaxrl_robot.agents.ppo`` runs this
in place of its actor update for the first ``pretrain_episodes`` worth of steps
(``PPOConfig.pretrain='action-search'``), then PPO fine-tunes the pre-trained networks.

Envs that offer ``model_reward``: ``unicycle`` (one Euler step of Eq. 3.18 scored by Eq. 3.23).
"""

from __future__ import annotations

from collections.abc import Callable

import jax
import jax.numpy as jnp
import optax
from brax.envs.base import State

from jaxrl_robot import parallel
from jaxrl_robot.acting import per_lane_keys
from jaxrl_robot.imitation import imitation_loss
from jaxrl_robot.networks import gaussian_entropy

__all__ = ["action_search", "imitation_loss", "make_imitation_update", "model_reward_of"]


def model_reward_of(env: object) -> Callable[[State, jax.Array], jax.Array] | None:
    """The env's ``model_reward(state, action) -> reward`` (unbatched), or None if it has none."""
    return getattr(env, "model_reward", None)


def action_search(
    key: jax.Array,
    lane_ids: jax.Array,
    model_reward: Callable[[State, jax.Array], jax.Array],
    state: State,
    num_candidates: int,
    action_size: int,
) -> tuple[jax.Array, jax.Array]:
    """The best of ``M`` random actions per lane by the model's reward (Algorithm 9, lines 7-9).

    Args:
      key: PRNG key; lane ``i`` draws its candidates ``U[-1, 1]^{M × A}`` with
        ``fold_in(key, lane_ids[i])``.
      lane_ids: ``[B]`` global lane indices.
      model_reward: ``(state, action [A]) -> []`` for one lane (the env's known kinematics).
      state: ``State [B]`` the lanes are in.
      num_candidates: M.
      action_size: A.
    Returns:
      ``(best action [B, A], its reward [B])``.
    """
    keys = per_lane_keys(key, lane_ids)
    candidates = jax.vmap(lambda k: jax.random.uniform(k, (num_candidates, action_size), minval=-1.0, maxval=1.0))(
        keys
    )  # [B, M, A]
    rewards = jax.vmap(lambda s, c: jax.vmap(lambda a: model_reward(s, a))(c))(state, candidates)  # [B, M]
    best = jnp.argmax(rewards, axis=1)
    action = jnp.take_along_axis(candidates, best[:, None, None], axis=1)[:, 0]
    return action, jnp.max(rewards, axis=1)


def make_imitation_update(
    actor_forward: Callable, minibatch: Callable, num_steps: int, learning_rate: float
) -> Callable:
    """The actor's supervised update of one pre-training iteration (Algorithm 9, line 17).

    Args:
      actor_forward: ``(params, stats, inputs) -> ((mean, log_std) [B, A], new stats)`` in training mode.
      minibatch: ``(key, lane_ids, data [N, K_local, ...]) -> data [1, B, ...]``, the trainer's
        mini-batch draw (inside ``shard_lanes``).
      num_steps: SGD steps.
      learning_rate: plain SGD step size.
    Returns:
      ``update(key, lane_ids, params, stats, inputs, target [N, K_local, A], mask [N, K_local]) ->
      ((params, stats), (loss [], entropy []))``: ``num_steps`` SGD steps on
      :func:`imitation_loss` (gradients summed over devices), its mean loss and the policy's entropy.
    """
    sgd = optax.sgd(learning_rate)

    def update(key, lane_ids, params, stats, inputs, target, mask):
        def step(carry, k):
            params, stats = carry
            inputs_mb, target_mb, mask_mb = minibatch(k, lane_ids, (inputs, target, mask))
            target_mb, mask_mb = target_mb.reshape((-1,) + target_mb.shape[2:]), mask_mb.reshape(-1)
            count = parallel.psum(jnp.sum(mask_mb))

            def loss_fn(p, s):
                (mean, log_std), s = actor_forward(p, s, inputs_mb)
                return imitation_loss(mean, target_mb, mask_mb, count), (s, log_std)

            (loss, (stats, log_std)), grads = jax.value_and_grad(loss_fn, has_aux=True)(params, stats)
            updates, _ = sgd.update(parallel.psum(grads), sgd.init(params), params)
            entropy = jnp.mean(gaussian_entropy(log_std))
            return (optax.apply_updates(params, updates), stats), (parallel.psum(loss), entropy)

        (params, stats), (loss, entropy) = jax.lax.scan(step, (params, stats), jax.random.split(key, num_steps))
        return (params, stats), (jnp.mean(loss), jnp.mean(entropy))

    return update
