"""A2C and A3C as pure, jit-compiled training functions (thesis §4.1, Algorithm 3).

>>> trainer = make_trainer(A2CConfig(), env)            # A3CConfig() for A3C; env unbatched
>>> state = jax.jit(trainer.init)(key)
>>> state, metrics = jax.jit(trainer.update)(state)      # one chunk of rounds
>>> state, metrics = jax.jit(make_train(A3CConfig(), env))(key)   # the whole run

One round: every lane (a worker's environment) fills its local buffer with up to N
transitions, closing it early at the end of its episode (Algorithm 3, line 8); the n-step
targets run backwards from the buffer end, bootstrapping unless the episode terminated
(lines 9-13, Eq. 4.3); each lane's actor (Eq. 4.4) and critic (Eq. 4.5) gradients average
over its own buffer, with batch-norm statistics of that buffer.

* **A2C** (§4.1.2): all lanes act with the global parameters; the mean of the lanes'
  gradients is applied once per round. Every applied gradient has staleness 0.
* **A3C** (§4.1.1): workers (groups of ``lanes_per_worker`` lanes) act and compute gradients
  with their own parameter snapshots; the gradients are pushed one after another in the push
  order and each worker re-syncs right after its own push (``asynchrony.push_in_order``). The
  staleness of every push is measured and reported (mean, max, histogram).

Lanes are split over the device mesh with ``shard_map`` (``jaxrl_robot.parallel``); global
parameters are replicated, A3C snapshots are split with their workers. Randomness is keyed by
global lane index, so results do not depend on how many devices share the lanes.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import jax
import jax.numpy as jnp
from brax.envs.base import Env, State
from flax import struct
from jax.sharding import Mesh

from envs_mjx.config import ConfigError
from envs_mjx.playground import adapt
from jaxrl_robot import parallel
from jaxrl_robot.acting import rollout_until_done
from jaxrl_robot.agents import core, on_policy
from jaxrl_robot.agents.a2c.asynchrony import PushState, init_push_state, push_in_order, push_order, staleness_histogram
from jaxrl_robot.agents.a2c.config import A2CConfig, A3CConfig
from jaxrl_robot.agents.a2c.losses import Buffer, make_worker_loss
from jaxrl_robot.networks import Critic, GaussianActor, apply_actor
from jaxrl_robot.types import Metrics, Policy, Trainer

__all__ = [
    "A2CState",
    "A3CState",
    "Buffer",
    "NetParams",
    "make_worker_loss",
    "make_networks",
    "make_train",
    "make_trainer",
]

_LANES = parallel.LANES
_WORKER_FIGURE_LANES = 8  # per-worker episode returns are reported for the first few workers


@struct.dataclass
class NetParams:
    """The parameters a worker acts and learns with.

    Attributes:
      actor: actor ``params``.
      actor_stats: actor ``batch_stats`` (``{}`` without batch-norm).
      critic: critic ``params``.
    """

    actor: Any
    actor_stats: Any
    critic: Any


@struct.dataclass
class A2CState(core.RunState):
    """Everything an A2C run needs to continue exactly: the lanes' ``env_state [K]``, ``key`` and
    ``iteration`` (rounds done) of :class:`~jaxrl_robot.agents.core.RunState`, and

    Attributes:
      params: global :class:`NetParams`.
      actor_opt, critic_opt: Adam states.
    """

    params: NetParams
    actor_opt: Any
    critic_opt: Any


@struct.dataclass
class A3CState(core.RunState):
    """Everything an A3C run needs to continue exactly: the lanes' ``env_state [K]``, ``key`` and
    ``iteration`` (rounds done) of :class:`~jaxrl_robot.agents.core.RunState`, and

    Attributes:
      push: :class:`~jaxrl_robot.agents.a2c.asynchrony.PushState` whose ``global_`` is
        ``(NetParams, actor_opt, critic_opt)`` and whose ``snapshots`` are the workers'
        :class:`NetParams` ``[W]`` (split over devices), with their sync versions.
    """

    push: PushState


def make_networks(config: A2CConfig, action_size: int) -> tuple[GaussianActor, Critic]:
    """The actor (Gaussian, fixed σ, optional batch-norm) and critic of ``config`` (§4.1.3, Fig. 4.3).

    With A2C and ``bn_batch='update'`` the actor's batch statistics are averaged over the lane
    mesh axis, so it must then be trained inside ``parallel.shard_lanes``.
    """
    # A2C's 'update' batch spans every device's lanes.
    synchronous_update_batch = not isinstance(config, A3CConfig) and config.bn_batch == "update"
    return on_policy.make_actor_critic(config, action_size, bn_axis_name=_LANES if synchronous_update_batch else None)


def make_trainer(config: A2CConfig, env: Env, *, mesh: Mesh | None = None, iterations_per_update: int = 1) -> Trainer:
    """Build the A2C (``A2CConfig``) or A3C (``A3CConfig``) :class:`~jaxrl_robot.types.Trainer`.

    ``config`` is validated (an :class:`A3CConfig` selects A3C); the *unbatched* ``env`` (a brax
    ``Env`` or a MuJoCo Playground env, ``envs_mjx.playground.adapt``) is wrapped for training; the lanes
    are split over ``mesh`` (default: all devices); one ``update`` call runs ``iterations_per_update``
    rounds (see :func:`~jaxrl_robot.agents.core.setup`).

    Metrics of a chunk (scalars): ``actor_loss``, ``critic_loss``, ``entropy``, ``value``,
    ``advantage`` (means over rounds), ``reward`` (per step taken), ``steps_taken`` (env steps
    taken; ``env_steps_per_update`` counts slots, idle ones included), ``episodes`` and every env
    episode metric (means over finished episodes, NaN if none), ``worker_return_<w>`` (mean
    episode return of worker ``w``, first 8 workers), ``applied_gradients``, ``staleness_mean``,
    ``staleness_max`` and for A3C ``staleness_hist_<lower edge>`` (share of the chunk's pushes).
    """
    asynchronous = isinstance(config, A3CConfig)
    env = adapt(env)
    run = core.setup(config, env, mesh, iterations_per_update)
    K, N, k_local = config.num_envs, config.unroll_length, run.local_lanes
    L = config.lanes_per_worker if asynchronous else k_local
    if k_local % L:
        raise ConfigError(
            f"lanes_per_worker={L} must divide the lanes per device ({k_local} = num_envs / {run.mesh.shape[_LANES]})"
        )
    w_local = k_local // L
    W = K // L if asynchronous else 1
    actor, critic = make_networks(config, run.action_size)
    worker_loss = make_worker_loss(config, actor, critic, axis_name=None if asynchronous else _LANES)
    applied = run.num_updates * iterations_per_update * W  # global updates of the whole run
    end = on_policy.lr_end_factor(config)  # "linear": annealed to 0 over the applied updates
    actor_tx = core.make_optimizer(config.actor_lr, config.max_grad_norm, end, applied)
    critic_tx = core.make_optimizer(config.critic_lr, config.max_grad_norm, end, applied)
    momentum = config.bn_momentum
    if asynchronous:
        max_staleness = (W - 1) if config.push_order == "fixed" else 2 * (W - 1)

    # ---- init ----------------------------------------------------------------------------
    def init(key: jax.Array) -> A2CState | A3CState:
        k_actor, k_critic, k_env, k_run = jax.random.split(key, 4)
        params = NetParams(*on_policy.init_actor_critic(k_actor, k_critic, actor, critic, run.obs_size))
        env_state = run.reset(k_env)
        actor_opt, critic_opt = actor_tx.init(params.actor), critic_tx.init(params.critic)
        zero = jnp.zeros((), jnp.int32)
        if asynchronous:
            push = init_push_state((params, actor_opt, critic_opt), params, W)
            return A3CState(push=push, env_state=env_state, key=k_run, iteration=zero)
        return A2CState(params, actor_opt, critic_opt, env_state=env_state, key=k_run, iteration=zero)

    # ---- pieces of a round (inside shard_map: this device's k_local lanes) ----------------
    def collect(key: jax.Array, env_state: State, dist: Callable, lane_ids: jax.Array):
        """Fill every lane's buffer: up to N steps, stopping (idle) after the lane's episode ends."""

        def policy(k: jax.Array, obs: jax.Array) -> jax.Array:
            return on_policy.sample_lanes(k, lane_ids, *dist(obs))

        env_state, traj, mask = rollout_until_done(key, run.env, env_state, policy, N)
        return env_state, traj, Buffer.of(traj, mask)

    def group_grad(params: NetParams, buf: Buffer) -> tuple[Any, Any, Metrics]:
        """Mean gradient of the lanes in ``buf [N, L]`` at ``params``; the new BN moving averages."""
        grad_fn = jax.value_and_grad(worker_loss, has_aux=True)
        (_, (stats, info)), grads = grad_fn((params.actor, params.critic), params.actor_stats, buf)
        return grads, stats, info

    def apply_grads(global_, grads_and_stats):
        """One global update: Adam steps of actor and critic, BN moving averages advanced."""
        params, actor_opt, critic_opt = global_
        (g_actor, g_critic), stats_delta = grads_and_stats
        actor_p, actor_opt = core.apply_gradients(actor_tx, g_actor, actor_opt, params.actor)
        critic_p, critic_opt = core.apply_gradients(critic_tx, g_critic, critic_opt, params.critic)
        stats = jax.tree.map(lambda s, d: momentum * s + d, params.actor_stats, stats_delta)
        return NetParams(actor=actor_p, actor_stats=stats, critic=critic_p), actor_opt, critic_opt

    def actor_dist(params: NetParams, obs: jax.Array) -> tuple[jax.Array, jax.Array]:
        (mean, log_std), _ = apply_actor(actor, params.actor, params.actor_stats, obs, train=False)
        return mean, log_std

    def to_groups(x: jax.Array) -> jax.Array:
        """``[N, k_local, ...] -> [N, w_local, L, ...]``."""
        return x.reshape((x.shape[0], w_local, L) + x.shape[2:])

    def round_a2c(state: A2CState):
        key, k_roll, _ = jax.random.split(state.key, 3)
        lane_ids = parallel.global_lane_ids(k_local)
        env_state, traj, buf = collect(k_roll, state.env_state, lambda o: actor_dist(state.params, o), lane_ids)
        grads, stats, info = group_grad(state.params, buf)
        grads, stats = parallel.pmean((grads, stats))
        delta = jax.tree.map(lambda n, o: n - momentum * o, stats, state.params.actor_stats)
        params, actor_opt, critic_opt = apply_grads((state.params, state.actor_opt, state.critic_opt), (grads, delta))
        new_state = A2CState(params, actor_opt, critic_opt, env_state=env_state, key=key, iteration=state.iteration + 1)
        return new_state, traj, buf, info, jnp.zeros((1,), jnp.int32)

    def round_a3c(state: A3CState):
        key, k_roll, k_order = jax.random.split(state.key, 3)
        lane_ids = parallel.global_lane_ids(k_local)
        worker_ids = parallel.global_lane_ids(w_local)
        snaps = state.push.snapshots  # NetParams [w_local]

        def dist(obs: jax.Array) -> tuple[jax.Array, jax.Array]:
            mean, log_std = jax.vmap(actor_dist)(snaps, obs.reshape((w_local, L) + obs.shape[1:]))
            return mean.reshape((k_local,) + mean.shape[2:]), log_std.reshape((k_local,) + log_std.shape[2:])

        env_state, traj, buf = collect(k_roll, state.env_state, dist, lane_ids)
        grads, stats, info = jax.vmap(group_grad, in_axes=(0, 1))(snaps, jax.tree.map(to_groups, buf))
        delta = jax.tree.map(lambda n, o: n - momentum * o, stats, snaps.actor_stats)
        gathered = parallel.all_gather((grads, delta))  # [W, ...] on every device
        order = push_order(k_order, W, config.push_order)
        push, staleness = push_in_order(state.push, gathered, order, apply_grads, lambda g: g[0], worker_ids)
        info = jax.tree.map(lambda x: jnp.mean(x, axis=0), info)
        new_state = A3CState(push=push, env_state=env_state, key=key, iteration=state.iteration + 1)
        return new_state, traj, buf, info, staleness

    one_round = round_a3c if asynchronous else round_a2c

    def iteration(state):
        state, traj, buf, info, staleness = one_round(state)
        steps = jnp.sum(buf.mask)
        metrics = {k: parallel.pmean(v) for k, v in info.items()}
        metrics["reward"] = parallel.psum(jnp.sum(traj.reward * buf.mask)) / parallel.psum(steps)
        metrics["steps_taken"] = parallel.psum(steps)
        done = traj.done
        lane_returns = jnp.sum(jnp.where(done > 0, traj.metrics.get("episode_return", traj.reward), 0.0), axis=0)
        return state, (metrics, on_policy.episode_sums(traj), lane_returns, jnp.sum(done, axis=0), staleness)

    def chunk(state):
        state, (metrics, sums, lane_ret, lane_eps, staleness) = jax.lax.scan(
            lambda s, _: iteration(s), state, None, length=iterations_per_update
        )
        out = core.chunk_metrics(metrics, sums)
        out["steps_taken"] = jnp.sum(metrics["steps_taken"])
        out["applied_gradients"] = jnp.asarray(staleness.size, jnp.float32)
        out["staleness_mean"] = jnp.mean(staleness.astype(jnp.float32))
        out["staleness_max"] = jnp.max(staleness).astype(jnp.float32)
        if asynchronous:
            edges, shares = staleness_histogram(staleness, config.staleness_bins, max_staleness)
            for i, lo in enumerate(edges):
                out[f"staleness_hist_{lo}"] = shares[i]
        return state, out, jnp.sum(lane_ret, axis=0), jnp.sum(lane_eps, axis=0)

    lanes = parallel.P(_LANES)
    if asynchronous:
        specs = core.state_specs(A3CState, push=core.state_specs(PushState, snapshots=lanes), env_state=lanes)
    else:
        specs = core.state_specs(A2CState, env_state=lanes)
    sharded_chunk = parallel.shard_lanes(
        chunk, run.mesh, in_specs=(specs,), out_specs=(specs, parallel.P(), lanes, lanes)
    )

    def update(state):
        state, metrics, lane_returns, lane_episodes = sharded_chunk(state)
        # Per-worker mean episode return (the thesis's "episode rewards of different workers").
        per_worker = L if asynchronous else 1
        w_returns = lane_returns.reshape(-1, per_worker).sum(axis=1)
        w_episodes = lane_episodes.reshape(-1, per_worker).sum(axis=1)
        for w in range(min(_WORKER_FIGURE_LANES, w_returns.shape[0])):
            metrics[f"worker_return_{w}"] = jnp.where(
                w_episodes[w] > 0, w_returns[w] / jnp.maximum(w_episodes[w], 1.0), jnp.nan
            )
        return state, metrics

    def policy(state) -> Policy:
        params = state.push.global_[0] if asynchronous else state.params
        return lambda obs: actor_dist(params, obs)[0]

    return run.trainer(init, update, policy)


make_train = core.make_train_for(make_trainer)
"""``make_train(config, env, *, mesh=None, iterations_per_update=1) -> train``: ``train(key) -> (final
A2CState | A3CState, metrics [num_updates])``, the whole run, pure and jittable (vmappable over keys)."""
