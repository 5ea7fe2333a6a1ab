"""One round of A2C or A3C (thesis §4.1, Algorithm 3) as steps of explicit arguments, inside
``parallel.shard_lanes`` on this device's lanes.

A round: every lane fills its local buffer (``on_policy.collect_until_done``); each worker's gradient
averages over its lanes' buffers (:func:`group_grad`, the loss ``losses.make_worker_loss``); then

* :func:`round_a2c` — the mean of every lane's gradient is applied once to the global parameters;
* :func:`round_a3c` — the workers' gradients, computed with their own snapshots, are pushed one after
  another in the push order (``asynchrony.push_in_order``), each worker re-syncing after its push.

:func:`iteration` adds the round's metrics; :func:`chunk` scans the rounds of one ``update`` and adds
the staleness metrics; :func:`worker_returns` the per-worker episode returns.
"""

from __future__ import annotations

from collections.abc import Callable
from functools import partial
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import optax
from brax.envs.base import Env

from jaxrl_robot import parallel
from jaxrl_robot.agents import core, on_policy
from jaxrl_robot.agents.a2c.asynchrony import push_in_order, push_order, staleness_histogram
from jaxrl_robot.agents.a2c.config import A2CConfig, A3CConfig
from jaxrl_robot.networks import Critic, GaussianActor, apply_actor
from jaxrl_robot.types import Metrics, Transition

__all__ = ["WORKER_FIGURE_LANES", "Workers", "actor_dist", "chunk", "group_grad", "iteration", "round_a2c",
           "round_a3c", "worker_returns"]  # fmt: skip

WORKER_FIGURE_LANES = 8
"""Per-worker episode returns are reported for this many first workers."""


class Workers(NamedTuple):
    """The pieces of a round fixed when the trainer is built (``a2c.train.make_workers``).

    Attributes:
      config: the validated :class:`A2CConfig` (an :class:`A3CConfig` for A3C).
      env: the env wrapped for training.
      actor, critic: the networks; worker_loss: ``losses.make_worker_loss`` of them.
      actor_tx, critic_tx: the Adam optimisers of the global parameters.
      local_lanes: this device's lanes; lanes_per_worker: lanes behind one gradient (A2C: all of
        the device's); num_workers: W, workers of all devices (A2C: 1).
    """

    config: A2CConfig
    env: Env
    actor: GaussianActor
    critic: Critic
    worker_loss: Callable
    actor_tx: optax.GradientTransformation
    critic_tx: optax.GradientTransformation
    local_lanes: int
    lanes_per_worker: int
    num_workers: int


def actor_dist(actor: GaussianActor, params: Any, obs: jax.Array) -> tuple[jax.Array, jax.Array]:
    """``(mean, log_std) [B, A]`` of the acting actor with ``NetParams`` ``params`` (moving averages)."""
    (mean, log_std), _ = apply_actor(actor, params.actor, params.actor_stats, obs, train=False)
    return mean, log_std


def buffers(traj: Transition) -> Transition:
    """The fields of the lanes' buffers a worker's loss reads (``done`` and ``metrics`` left out)."""
    return traj._replace(done=(), metrics=())


def group_grad(worker_loss: Callable, params: Any, traj: Transition, mask: jax.Array) -> tuple[Any, Any, Metrics]:
    """Mean gradient of the lanes in ``traj, mask [N, L]`` at ``params``; the new BN moving averages; the info."""
    grad_fn = jax.value_and_grad(worker_loss, has_aux=True)
    (_, (stats, info)), grads = grad_fn((params.actor, params.critic), params.actor_stats, traj, mask)
    return grads, stats, info


def stats_delta(momentum: float, stats: Any, old: Any) -> Any:
    """What a gradient's batch-norm moving averages add to ``momentum`` times the old ones."""
    return jax.tree.map(lambda n, o: n - momentum * o, stats, old)


def apply_grads(w: Workers, global_: tuple, grads_and_stats: tuple) -> tuple:
    """One global update of ``(NetParams, actor_opt, critic_opt)``: Adam steps of actor and critic, BN
    moving averages advanced by the gradient's ``stats_delta``."""
    params, actor_opt, critic_opt = global_
    (g_actor, g_critic), delta = grads_and_stats
    actor_p, actor_opt = core.apply_gradients(w.actor_tx, g_actor, actor_opt, params.actor)
    critic_p, critic_opt = core.apply_gradients(w.critic_tx, g_critic, critic_opt, params.critic)
    stats = jax.tree.map(lambda s, d: w.config.bn_momentum * s + d, params.actor_stats, delta)
    return params.replace(actor=actor_p, actor_stats=stats, critic=critic_p), actor_opt, critic_opt


def round_a2c(w: Workers, state: Any) -> tuple[Any, Transition, jax.Array, Metrics, jax.Array]:
    """A2C: the mean gradient of every lane, applied once. ``(state, traj, mask, info, staleness [1])``."""
    key, k_roll, _ = jax.random.split(state.key, 3)
    lane_ids = parallel.global_lane_ids(w.local_lanes)
    dist = partial(actor_dist, w.actor, state.params)
    env_state, traj, mask = on_policy.collect_until_done(k_roll, w.env, state.env_state, dist, lane_ids,
                                                         w.config.unroll_length)  # fmt: skip
    grads, stats, info = group_grad(w.worker_loss, state.params, buffers(traj), mask)
    grads, stats = parallel.pmean((grads, stats))
    delta = stats_delta(w.config.bn_momentum, stats, state.params.actor_stats)
    params, actor_opt, critic_opt = apply_grads(w, (state.params, state.actor_opt, state.critic_opt), (grads, delta))
    new_state = state.replace(params=params, actor_opt=actor_opt, critic_opt=critic_opt, env_state=env_state, key=key,
                              iteration=state.iteration + 1)  # fmt: skip
    return new_state, traj, mask, info, jnp.zeros((1,), jnp.int32)


def round_a3c(w: Workers, state: Any) -> tuple[Any, Transition, jax.Array, Metrics, jax.Array]:
    """A3C: each worker's gradient at its own snapshot, pushed in the push order.
    ``(state, traj, mask, info, staleness [W])``."""
    key, k_roll, k_order = jax.random.split(state.key, 3)
    lane_ids = parallel.global_lane_ids(w.local_lanes)
    w_local, per_worker = w.local_lanes // w.lanes_per_worker, w.lanes_per_worker
    worker_ids = parallel.global_lane_ids(w_local)
    snaps = state.push.snapshots  # NetParams [w_local]

    def to_groups(x: jax.Array) -> jax.Array:
        """``[N, local lanes, ...] -> [N, w_local, lanes_per_worker, ...]``."""
        return x.reshape((x.shape[0], w_local, per_worker) + x.shape[2:])

    def dist(obs: jax.Array) -> tuple[jax.Array, jax.Array]:
        mean, log_std = jax.vmap(partial(actor_dist, w.actor))(
            snaps, obs.reshape((w_local, per_worker) + obs.shape[1:])
        )
        return mean.reshape((w.local_lanes,) + mean.shape[2:]), log_std.reshape((w.local_lanes,) + log_std.shape[2:])

    env_state, traj, mask = on_policy.collect_until_done(k_roll, w.env, state.env_state, dist, lane_ids,
                                                         w.config.unroll_length)  # fmt: skip
    groups = jax.tree.map(to_groups, (buffers(traj), mask))
    grads, stats, info = jax.vmap(partial(group_grad, w.worker_loss), in_axes=(0, 1, 1))(snaps, *groups)
    delta = stats_delta(w.config.bn_momentum, stats, snaps.actor_stats)
    gathered = parallel.all_gather((grads, delta))  # [W, ...] on every device
    order = push_order(k_order, w.num_workers, w.config.push_order)
    push, staleness = push_in_order(state.push, gathered, order, partial(apply_grads, w), lambda g: g[0], worker_ids)
    info = jax.tree.map(lambda x: jnp.mean(x, axis=0), info)
    new_state = state.replace(push=push, env_state=env_state, key=key, iteration=state.iteration + 1)
    return new_state, traj, mask, info, staleness


def iteration(one_round: Callable, state: Any) -> tuple[Any, tuple]:
    """One round and its metrics: ``(state, (metrics, episode sums, lane returns [B], lane episodes [B],
    staleness))``; ``reward`` per step taken, ``steps_taken`` over every device."""
    state, traj, mask, info, staleness = one_round(state)
    steps = jnp.sum(mask)
    metrics = {k: parallel.pmean(v) for k, v in info.items()}
    metrics["reward"] = parallel.psum(jnp.sum(traj.reward * mask)) / parallel.psum(steps)
    metrics["steps_taken"] = parallel.psum(steps)
    done = traj.done
    lane_returns = jnp.sum(jnp.where(done > 0, traj.metrics.get("episode_return", traj.reward), 0.0), axis=0)
    return state, (metrics, on_policy.episode_sums(traj), lane_returns, jnp.sum(done, axis=0), staleness)


def chunk(w: Workers, one_round: Callable, rounds: int, state: Any) -> tuple[Any, Metrics, jax.Array, jax.Array]:
    """``rounds`` rounds under ``lax.scan``: ``(state, metrics, lane returns [B], lane episodes [B])``
    (the lanes' episode returns and counts summed over the rounds)."""
    state, (metrics, sums, lane_ret, lane_eps, staleness) = jax.lax.scan(
        lambda s, _: iteration(one_round, s), state, None, length=rounds
    )
    out = core.chunk_metrics(metrics, sums)
    out["steps_taken"] = jnp.sum(metrics["steps_taken"])
    out["applied_gradients"] = jnp.asarray(staleness.size, jnp.float32)
    out["staleness_mean"] = jnp.mean(staleness.astype(jnp.float32))
    out["staleness_max"] = jnp.max(staleness).astype(jnp.float32)
    if isinstance(w.config, A3CConfig):
        max_staleness = (w.num_workers - 1) * (1 if w.config.push_order == "fixed" else 2)
        edges, shares = staleness_histogram(staleness, w.config.staleness_bins, max_staleness)
        for i, lo in enumerate(edges):
            out[f"staleness_hist_{lo}"] = shares[i]
    return state, out, jnp.sum(lane_ret, axis=0), jnp.sum(lane_eps, axis=0)


def worker_returns(lane_returns: jax.Array, lane_episodes: jax.Array, lanes_per_worker: int) -> Metrics:
    """``worker_return_<w>``: the mean episode return of worker ``w`` over the chunk (NaN where none
    ended), for the first :data:`WORKER_FIGURE_LANES` workers (the thesis's "episode rewards of
    different workers"); ``lane_* [K]`` every lane's sums."""
    w_returns = lane_returns.reshape(-1, lanes_per_worker).sum(axis=1)
    w_episodes = lane_episodes.reshape(-1, lanes_per_worker).sum(axis=1)
    out = {}
    for w in range(min(WORKER_FIGURE_LANES, w_returns.shape[0])):
        out[f"worker_return_{w}"] = jnp.where(
            w_episodes[w] > 0, w_returns[w] / jnp.maximum(w_episodes[w], 1.0), jnp.nan
        )
    return out
