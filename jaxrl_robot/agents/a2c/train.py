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

import math
from collections.abc import Callable
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import optax
from brax.envs.base import Env, State
from flax import struct

from envs_mjx.base import wrap_for_training
from envs_mjx.config import ConfigError
from jaxrl_robot import parallel
from jaxrl_robot.acting import env_step
from jaxrl_robot.agents.a2c.asynchrony import (
    PushState,
    init_push_state,
    push_in_order,
    push_order,
    staleness_histogram,
)
from jaxrl_robot.agents.a2c.config import A2CConfig, A3CConfig
from jaxrl_robot.agents.a2c.losses import actor_loss, critic_loss, worker_targets
from jaxrl_robot.networks import (
    Critic,
    GaussianActor,
    apply_actor,
    gaussian_entropy,
    gaussian_log_prob,
    gaussian_sample,
)
from jaxrl_robot.types import Metrics, Policy, Trainer, Transition

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
class A2CState:
    """Everything an A2C run needs to continue exactly.

    Attributes:
      params: global :class:`NetParams`.
      actor_opt, critic_opt: Adam states.
      env_state: ``State [K]`` of the wrapped env (lanes split over devices).
      key: PRNG key of the run.
      iteration: ``[]`` int32 rounds done.
    """

    params: NetParams
    actor_opt: Any
    critic_opt: Any
    env_state: State
    key: jax.Array
    iteration: jax.Array


@struct.dataclass
class A3CState:
    """Everything an A3C run needs to continue exactly.

    Attributes:
      push: :class:`~jaxrl_robot.agents.a2c.asynchrony.PushState` whose ``global_`` is
        ``(NetParams, actor_opt, critic_opt)`` and whose ``snapshots`` are the workers'
        :class:`NetParams` ``[W]`` (split over devices), with their sync versions.
      env_state: ``State [K]`` of the wrapped env.
      key: PRNG key of the run.
      iteration: ``[]`` int32 rounds done.
    """

    push: PushState
    env_state: State
    key: jax.Array
    iteration: jax.Array


class Buffer(NamedTuple):
    """Local buffers of the lanes: leaves ``[N, ...]`` for one lane (``[N, K, ...]`` for all).

    Attributes:
      obs, action, reward, termination, truncation, next_obs: as in
        :class:`~jaxrl_robot.types.Transition`.
      mask: 1.0 on filled slots; 0 after the lane's episode ended in this round.
    """

    obs: jax.Array
    action: jax.Array
    reward: jax.Array
    termination: jax.Array
    truncation: jax.Array
    next_obs: jax.Array
    mask: jax.Array


def make_networks(config: A2CConfig, action_size: int) -> tuple[GaussianActor, Critic]:
    """The actor (Gaussian, fixed σ, optional batch-norm) and critic of ``config`` (§4.1.3, Fig. 4.3).

    With A2C and ``bn_batch='update'`` the actor's batch statistics are averaged over the lane
    mesh axis, so it must then be trained inside ``parallel.shard_lanes``.
    """
    sigma = tuple(config.sigma)
    if len(sigma) == 1:
        sigma = sigma * action_size
    if len(sigma) != action_size:
        raise ConfigError(f"sigma={config.sigma!r} must have 1 or action_size={action_size} values")
    synchronous_update_batch = not isinstance(config, A3CConfig) and config.bn_batch == "update"
    actor = GaussianActor(
        action_size=action_size,
        hidden=tuple(config.actor_hidden),
        sigma=sigma,
        learn_std=config.learn_std,
        batch_norm=config.batch_norm,
        bn_momentum=config.bn_momentum,
        bn_mode=config.bn_mode,
        # A2C's 'update' batch spans every device's lanes.
        bn_axis_name=_LANES if synchronous_update_batch else None,
    )
    return actor, Critic(hidden=tuple(config.critic_hidden))


def make_worker_loss(
    config: A2CConfig, actor: GaussianActor, critic: Critic, axis_name: str | None = None
) -> Callable[[tuple[Any, Any], Any, Buffer], tuple[jax.Array, tuple[Any, Metrics]]]:
    """``worker_loss((actor_params, critic_params), actor_stats, buffer [N, L]) -> (loss, (new_stats, info))``.

    ``loss`` is the mean over the ``L`` lanes of each lane's Eq. 4.4 (negated) + Eq. 4.5, each
    averaged over the lane's filled slots. Its gradient with respect to the actor and critic
    parameters is the mean over lanes of ``(-g_π, g_v)`` of Algorithm 3, lines 15-16 (the two
    parameter sets are disjoint, so each gets only its own loss's gradient). ``new_stats`` are
    the actor's batch-norm moving averages after normalising the buffer — per lane and then
    averaged (``bn_batch='lane'``) or over all ``L · N`` transitions (``'update'``). With
    ``normalize_advantages`` the advantages are standardised over all filled slots of the
    buffer, pooled over the mapped axis ``axis_name`` if given (A2C's devices).
    """
    per_lane = dict(in_axes=(1, 1, 1, 1, 1, None), out_axes=1)

    def worker_loss(
        diff_params: tuple[Any, Any], actor_stats: Any, buf: Buffer
    ) -> tuple[jax.Array, tuple[Any, Metrics]]:
        actor_params, critic_params = diff_params
        mask = buf.mask  # [N, L]
        values = critic.apply({"params": critic_params}, buf.obs)
        next_values = jax.lax.stop_gradient(critic.apply({"params": critic_params}, buf.next_obs))
        rewards = buf.reward * config.reward_scale
        targets = jax.vmap(worker_targets, **per_lane)(
            rewards, next_values, buf.termination, buf.truncation, mask, config.gamma
        )
        targets = jax.lax.stop_gradient(targets)
        adv = targets - jax.lax.stop_gradient(values)
        counts = jnp.maximum(jnp.sum(mask, axis=0), 1.0)  # [L]
        if config.normalize_advantages:
            # over every filled slot behind this gradient (all devices' lanes for A2C)
            total = jnp.stack([jnp.sum(mask), jnp.sum(adv * mask), jnp.sum(adv**2 * mask)])
            if axis_name is not None:
                total = jax.lax.psum(total, axis_name)
            mu = total[1] / total[0]
            std = jnp.sqrt(jnp.maximum(total[2] / total[0] - mu**2, 0.0))
            adv = (adv - mu) / (std + 1e-8)
        if config.bn_batch == "lane":
            lane_actor = lambda o, m: apply_actor(actor, actor_params, actor_stats, o, train=True, mask=m)
            (mean, log_std), new_stats = jax.vmap(lane_actor, in_axes=(1, 1), out_axes=(1, 0))(buf.obs, mask)
            new_stats = jax.tree.map(lambda x: jnp.mean(x, axis=0), new_stats)
        else:
            flat = lambda x: x.reshape((-1,) + x.shape[2:])
            (mean, log_std), new_stats = apply_actor(
                actor, actor_params, actor_stats, flat(buf.obs), train=True, mask=flat(mask)
            )
            mean, log_std = (x.reshape(mask.shape + x.shape[1:]) for x in (mean, log_std))
        log_prob = gaussian_log_prob(mean, log_std, buf.action)
        entropy = gaussian_entropy(log_std)
        lane_losses = jax.vmap(actor_loss, in_axes=(1, 1, 1, 1, None))(
            log_prob, adv, entropy, mask, config.entropy_coef
        )
        lane_c_losses = jax.vmap(critic_loss, in_axes=(1, 1, 1))(values, targets, mask)
        a_loss, c_loss = jnp.mean(lane_losses), jnp.mean(lane_c_losses)
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


def _optimizer(lr: float, max_grad_norm: float, schedule: str, total_updates: int) -> optax.GradientTransformation:
    """Adam at ``lr`` (``'linear'``: annealed to 0 over ``total_updates`` applied gradients)."""
    rate = optax.linear_schedule(lr, 0.0, total_updates) if schedule == "linear" else lr
    adam = optax.adam(rate)
    return optax.chain(optax.clip_by_global_norm(max_grad_norm), adam) if max_grad_norm > 0 else adam


def _per_lane_keys(key: jax.Array, lane_ids: jax.Array) -> jax.Array:
    return jax.vmap(jax.random.fold_in, in_axes=(None, 0))(key, lane_ids)


def _lane_select(pred: jax.Array, a: Any, b: Any) -> Any:
    """Per lane ``pred [B] ? a : b`` on pytrees with a leading lane axis."""

    def pick(x, y):
        return jnp.where(pred.reshape(pred.shape + (1,) * (x.ndim - 1)), x, y)

    return jax.tree.map(pick, a, b)


def _lane_episode_sums(traj: Transition) -> tuple[dict[str, jax.Array], jax.Array, jax.Array]:
    """Sums over finished episodes: ``({episodes, metric: sum} [], returns [B], episodes [B])``."""
    done = traj.done
    sums = {"episodes": jnp.sum(done)}
    for k, v in traj.metrics.items():
        if v.shape == done.shape:
            sums[k] = jnp.sum(jnp.where(done > 0, v, 0.0))
    lane_returns = jnp.sum(jnp.where(done > 0, traj.metrics.get("episode_return", traj.reward), 0.0), axis=0)
    return sums, lane_returns, jnp.sum(done, axis=0)


def make_trainer(
    config: A2CConfig,
    env: Env,
    *,
    mesh: jax.sharding.Mesh | None = None,
    iterations_per_update: int = 1,
) -> Trainer:
    """Build the A2C (``A2CConfig``) or A3C (``A3CConfig``) :class:`~jaxrl_robot.types.Trainer`.

    Args:
      config: hyper-parameters (validated here); an :class:`A3CConfig` selects A3C.
      env: an *unbatched* ``brax.envs.base.Env``; wrapped with ``envs_mjx.wrap_for_training``.
      mesh: device mesh from ``parallel.lane_mesh`` (default: all devices).
      iterations_per_update: rounds per ``update`` call (one chunk).

    Metrics of a chunk (scalars): ``actor_loss``, ``critic_loss``, ``entropy``, ``value``,
    ``advantage`` (means over rounds), ``reward`` (per step taken), ``steps_taken`` (env steps
    taken; ``env_steps_per_update`` counts slots, idle ones included), ``episodes`` and every env
    episode metric (means over finished episodes, NaN if none), ``worker_return_<w>`` (mean
    episode return of worker ``w``, first 8 workers), ``applied_gradients``, ``staleness_mean``,
    ``staleness_max`` and for A3C ``staleness_hist_<lower edge>`` (share of the chunk's pushes).
    """
    config.validate()
    if iterations_per_update < 1:
        raise ConfigError(f"iterations_per_update={iterations_per_update} must be >= 1")
    asynchronous = isinstance(config, A3CConfig)
    mesh = parallel.lane_mesh() if mesh is None else mesh
    K, N = config.num_envs, config.unroll_length
    k_local = parallel.local_lane_count(K, mesh)
    L = config.lanes_per_worker if asynchronous else k_local
    if k_local % L:
        raise ConfigError(
            f"lanes_per_worker={L} must divide the lanes per device ({k_local} = num_envs / {mesh.shape[_LANES]})"
        )
    w_local = k_local // L
    W = K // L if asynchronous else 1
    episode_length = config.episode_length or getattr(env, "episode_length", None)
    if not episode_length:
        raise ConfigError("episode_length=0: this env has no default episode_length; set episode_length >= 1")
    wrapped = wrap_for_training(env, episode_length=int(episode_length))
    obs_size, action_size = int(env.observation_size), int(env.action_size)
    actor, critic = make_networks(config, action_size)
    worker_loss = make_worker_loss(config, actor, critic, axis_name=None if asynchronous else _LANES)
    steps_per_iteration = K * N
    total_iterations = max(1, math.ceil(config.total_steps / steps_per_iteration))
    num_updates = math.ceil(total_iterations / iterations_per_update)
    applied = num_updates * iterations_per_update * W  # global updates of the whole run
    actor_tx = _optimizer(config.actor_lr, config.max_grad_norm, config.lr_schedule, applied)
    critic_tx = _optimizer(config.critic_lr, config.max_grad_norm, config.lr_schedule, applied)
    momentum = config.bn_momentum
    if asynchronous:
        max_staleness = (W - 1) if config.push_order == "fixed" else 2 * (W - 1)

    # ---- init ----------------------------------------------------------------------------
    def reset_lanes(keys: jax.Array) -> State:
        return wrapped.reset(keys)

    def init(key: jax.Array) -> A2CState | A3CState:
        k_actor, k_critic, k_env, k_run = jax.random.split(key, 4)
        dummy = jnp.zeros((1, obs_size), jnp.float32)
        actor_vars = actor.init(k_actor, dummy)
        params = NetParams(
            actor=actor_vars["params"],
            actor_stats=actor_vars.get("batch_stats", {}),
            critic=critic.init(k_critic, dummy)["params"],
        )
        env_keys = jax.random.split(k_env, K)
        env_state = parallel.shard_lanes(reset_lanes, mesh, parallel.P(_LANES), parallel.P(_LANES))(env_keys)
        actor_opt, critic_opt = actor_tx.init(params.actor), critic_tx.init(params.critic)
        if asynchronous:
            push = init_push_state((params, actor_opt, critic_opt), params, W)
            return A3CState(push=push, env_state=env_state, key=k_run, iteration=jnp.zeros((), jnp.int32))
        return A2CState(
            params=params,
            actor_opt=actor_opt,
            critic_opt=critic_opt,
            env_state=env_state,
            key=k_run,
            iteration=jnp.zeros((), jnp.int32),
        )

    # ---- pieces of a round (inside shard_map: this device's k_local lanes) ----------------
    def collect(key: jax.Array, env_state: State, dist: Callable, lane_ids: jax.Array):
        """Fill every lane's buffer: up to N steps, stopping (idle) after the lane's episode ends."""

        def body(carry, k):
            s, active = carry
            mean, log_std = dist(s.obs)
            action = jax.vmap(gaussian_sample)(_per_lane_keys(k, lane_ids), mean, log_std)
            ns, tr = env_step(wrapped, s, action)
            s = _lane_select(active > 0, ns, s)
            tr = tr._replace(
                termination=tr.termination * active, truncation=tr.truncation * active, done=tr.done * active
            )
            return (s, active * (1.0 - tr.done)), (tr, active)

        init_carry = (env_state, jnp.ones((k_local,), jnp.float32))
        (env_state, _), (traj, mask) = jax.lax.scan(body, init_carry, jax.random.split(key, N))
        buf = Buffer(
            obs=traj.obs,
            action=traj.action,
            reward=traj.reward,
            termination=traj.termination,
            truncation=traj.truncation,
            next_obs=traj.next_obs,
            mask=mask,
        )
        return env_state, traj, buf

    def group_grad(params: NetParams, buf: Buffer) -> tuple[Any, Any, Metrics]:
        """Mean gradient of the lanes in ``buf [N, L]`` at ``params``; the new BN moving averages."""
        grad_fn = jax.value_and_grad(worker_loss, has_aux=True)
        (_, (stats, info)), grads = grad_fn((params.actor, params.critic), params.actor_stats, buf)
        return grads, stats, info

    def apply_grads(global_, grads_and_stats):
        """One global update: Adam steps of actor and critic, BN moving averages advanced."""
        params, actor_opt, critic_opt = global_
        (g_actor, g_critic), stats_delta = grads_and_stats
        upd, actor_opt = actor_tx.update(g_actor, actor_opt, params.actor)
        actor_p = optax.apply_updates(params.actor, upd)
        upd, critic_opt = critic_tx.update(g_critic, critic_opt, params.critic)
        critic_p = optax.apply_updates(params.critic, upd)
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
        new_state = A2CState(
            params=params,
            actor_opt=actor_opt,
            critic_opt=critic_opt,
            env_state=env_state,
            key=key,
            iteration=state.iteration + 1,
        )
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
        sums, lane_returns, lane_episodes = _lane_episode_sums(traj)
        return state, (metrics, sums, lane_returns, lane_episodes, staleness)

    def chunk(state):
        state, (metrics, sums, lane_ret, lane_eps, staleness) = jax.lax.scan(
            lambda s, _: iteration(s), state, None, length=iterations_per_update
        )
        out = {k: jnp.mean(v) for k, v in metrics.items()}
        out["steps_taken"] = jnp.sum(metrics["steps_taken"])
        sums = parallel.psum(jax.tree.map(lambda x: jnp.sum(x, axis=0), sums))
        episodes = sums.pop("episodes")
        out["episodes"] = episodes
        for k, v in sums.items():
            out[k] = jnp.where(episodes > 0, v / jnp.maximum(episodes, 1.0), jnp.nan)
        out["applied_gradients"] = jnp.asarray(staleness.size, jnp.float32)
        out["staleness_mean"] = jnp.mean(staleness.astype(jnp.float32))
        out["staleness_max"] = jnp.max(staleness).astype(jnp.float32)
        if asynchronous:
            edges, shares = staleness_histogram(staleness, config.staleness_bins, max_staleness)
            for i, lo in enumerate(edges):
                out[f"staleness_hist_{lo}"] = shares[i]
        return state, out, jnp.sum(lane_ret, axis=0), jnp.sum(lane_eps, axis=0)

    if asynchronous:
        push_specs = PushState(
            global_=parallel.P(), snapshots=parallel.P(_LANES), versions=parallel.P(), pushes=parallel.P()
        )
        specs = A3CState(push=push_specs, env_state=parallel.P(_LANES), key=parallel.P(), iteration=parallel.P())
    else:
        specs = A2CState(
            params=parallel.P(),
            actor_opt=parallel.P(),
            critic_opt=parallel.P(),
            env_state=parallel.P(_LANES),
            key=parallel.P(),
            iteration=parallel.P(),
        )
    sharded_chunk = parallel.shard_lanes(
        chunk, mesh, in_specs=(specs,), out_specs=(specs, parallel.P(), parallel.P(_LANES), parallel.P(_LANES))
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

    def global_params(state) -> NetParams:
        return state.push.global_[0] if asynchronous else state.params

    def policy(state) -> Policy:
        params = global_params(state)

        def act(obs: jax.Array) -> jax.Array:
            return actor_dist(params, obs)[0]

        return act

    return Trainer(
        init=init,
        update=update,
        policy=policy,
        num_updates=num_updates,
        env_steps_per_update=steps_per_iteration * iterations_per_update,
    )


def make_train(
    config: A2CConfig, env: Env, *, mesh: jax.sharding.Mesh | None = None, iterations_per_update: int = 1
) -> Callable[[jax.Array], tuple[A2CState | A3CState, Metrics]]:
    """``train(key) -> (final state, metrics [num_updates])``: the whole run, pure and jittable.

    ``jax.jit(jax.vmap(train))(keys)`` trains one agent per key.
    """
    trainer = make_trainer(config, env, mesh=mesh, iterations_per_update=iterations_per_update)

    def train(key: jax.Array):
        state = trainer.init(key)
        return jax.lax.scan(lambda s, _: trainer.update(s), state, None, length=trainer.num_updates)

    return train
