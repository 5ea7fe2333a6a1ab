"""Distributed PPO with GAE as a pure, jit-compiled training function (thesis §5.3, Algorithms 7-8).

>>> trainer = make_trainer(PPOConfig(), env)          # any brax.envs.base.Env (unbatched)
>>> state = jax.jit(trainer.init)(key)
>>> state, metrics = jax.jit(trainer.update)(state)    # one chunk of iterations
>>> train = make_train(PPOConfig(), env)               # or the whole run at once
>>> state, metrics = jax.jit(train)(key)               # vmappable over keys

One iteration: every lane (worker) collects N steps with the current policy (Algorithm 7);
GAE advantages (Eq. 5.12) and λ-return targets (Eq. 5.14) are computed per lane, with
termination and truncation apart; then m actor and n critic Adam steps run on mini-batches
of B transitions (Algorithm 8), gradients averaged over devices. The lanes are split over
the device mesh with ``shard_map`` (``jaxrl_robot.parallel``); parameters stay replicated.

Randomness is keyed by *global* lane index (action noise, mini-batch choice, env resets), so
the result does not depend on how many devices share the lanes.
"""

from __future__ import annotations

from typing import Any

import jax
import jax.numpy as jnp
from brax.envs.base import Env, State
from flax import struct
from jax.sharding import Mesh

from jaxrl_robot import parallel
from jaxrl_robot.acting import per_lane_keys, rollout
from jaxrl_robot.agents import common
from jaxrl_robot.agents.ppo.config import PPOConfig
from jaxrl_robot.agents.ppo.losses import adapt_kl_beta, make_actor_loss, value_loss
from jaxrl_robot.networks import (
    Critic,
    GaussianActor,
    apply_actor,
    gaussian_kl,
    init_running_stats,
    normalize,
    update_running_stats,
)
from jaxrl_robot.returns import gae, lambda_returns
from jaxrl_robot.types import Metrics, Policy, RunningStats, Trainer

__all__ = ["PPOState", "make_actor_loss", "make_networks", "make_train", "make_trainer"]

_LANES = parallel.LANES


@struct.dataclass
class PPOState:
    """Everything a PPO run needs to continue exactly.

    Attributes:
      actor_params, actor_stats: actor ``params`` and ``batch_stats`` (``{}`` without batch-norm).
      critic_params: critic ``params``.
      actor_opt, critic_opt: Adam states.
      obs_stats: observation normaliser (unused unless ``normalize_obs``).
      kl_beta: ``[]`` β of the adaptive KL penalty.
      env_state: ``State [K]`` of the wrapped env (lanes split over devices).
      key: PRNG key of the run.
      iteration: ``[]`` int32 iterations done.
    """

    actor_params: Any
    actor_stats: Any
    critic_params: Any
    actor_opt: Any
    critic_opt: Any
    obs_stats: RunningStats
    kl_beta: jax.Array
    env_state: State
    key: jax.Array
    iteration: jax.Array


def make_networks(config: PPOConfig, action_size: int) -> tuple[GaussianActor, Critic]:
    """The actor and critic modules of ``config``; σ is broadcast to ``action_size``."""
    return common.make_actor_critic(config, action_size, bn_axis_name=_LANES)


def make_trainer(config: PPOConfig, env: Env, *, mesh: Mesh | None = None, iterations_per_update: int = 1) -> Trainer:
    """Build the PPO :class:`~jaxrl_robot.types.Trainer` for the *unbatched* ``env``.

    ``config`` is validated; ``env`` is wrapped for training (lanes, time limit, true auto-reset,
    the reset pool and lane groups of ``config``); the lanes are split over ``mesh`` (default: all
    devices); one ``update`` call runs ``iterations_per_update`` iterations (see
    :func:`~jaxrl_robot.agents.common.setup`).
    """
    run = common.setup(
        config,
        env,
        mesh,
        iterations_per_update,
        reset_refresh=config.reset_refresh,
        reset_group=config.reset_group,
        lane_group=config.lane_group,
    )
    N, k_local, obs_size = config.unroll_length, run.local_lanes, run.obs_size
    b_lane = config.minibatch_size // config.num_envs  # transitions per lane in each mini-batch
    actor, critic = make_networks(config, run.action_size)
    actor_tx = common.make_optimizer(config.actor_lr, config.max_grad_norm)
    critic_tx = common.make_optimizer(config.critic_lr, config.max_grad_norm)
    tables = common.schedule_tables(config.schedule, env)
    schedule_len = float(run.num_updates * iterations_per_update)

    def obs_norm(stats: RunningStats, obs: jax.Array) -> jax.Array:
        return normalize(stats if config.normalize_obs else None, obs)

    def act(state: PPOState, obs: jax.Array) -> tuple[jax.Array, jax.Array]:
        """The acting policy's ``(mean, log_std)`` (moving batch-norm statistics, normalised obs)."""
        (mean, log_std), _ = apply_actor(actor, state.actor_params, state.actor_stats, obs_norm(state.obs_stats, obs))
        return mean, log_std

    # ---- init --------------------------------------------------------------------------
    def init(key: jax.Array) -> PPOState:
        k_actor, k_critic, k_env, k_run = jax.random.split(key, 4)
        actor_params, actor_stats, critic_params = common.init_actor_critic(k_actor, k_critic, actor, critic, obs_size)
        return PPOState(
            actor_params=actor_params,
            actor_stats=actor_stats,
            critic_params=critic_params,
            actor_opt=actor_tx.init(actor_params),
            critic_opt=critic_tx.init(critic_params),
            obs_stats=init_running_stats(obs_size),
            kl_beta=jnp.asarray(config.kl_beta, jnp.float32),
            env_state=run.reset(k_env, lambda: common.initial_env_params(env, tables)),
            key=k_run,
            iteration=jnp.zeros((), jnp.int32),
        )

    # ---- one iteration (inside shard_map: this device's k_local lanes) -----------------
    def minibatch(key: jax.Array, lane_ids: jax.Array, data: Any) -> Any:
        """``b_lane`` steps from every lane: ``[N, k_local, ...] -> [b_lane * k_local, ...]``."""
        keys = per_lane_keys(key, lane_ids)
        idx = jax.vmap(lambda k: jax.random.permutation(k, N)[:b_lane], out_axes=1)(keys)  # [b, k_local]

        def take(x: jax.Array) -> jax.Array:
            ix = idx.reshape(idx.shape + (1,) * (x.ndim - 2))
            picked = jnp.take_along_axis(x, ix, axis=0)
            return picked.reshape((b_lane * k_local,) + x.shape[2:])

        return jax.tree.map(take, data)

    actor_loss_fn = make_actor_loss(config, actor)

    def critic_loss_fn(params, mb):
        obs, targets = mb
        return value_loss(critic.apply({"params": params}, obs), targets)

    def iteration(state: PPOState) -> tuple[PPOState, Metrics]:
        key, k_roll, k_actor, k_critic = jax.random.split(state.key, 4)
        lane_ids = parallel.global_lane_ids(k_local)
        progress = state.iteration.astype(jnp.float32) / schedule_len
        env_state = common.apply_schedule(state.env_state, tables, progress)

        def policy(k: jax.Array, obs: jax.Array) -> jax.Array:
            return common.sample_lanes(k, lane_ids, *act(state, obs))

        env_state, traj = rollout(k_roll, run.env, env_state, policy, N)  # [N, k_local]
        obs_stats = state.obs_stats
        if config.normalize_obs:
            obs_stats = update_running_stats(obs_stats, traj.obs, _LANES)
        obs = obs_norm(obs_stats, traj.obs)
        next_obs = obs_norm(obs_stats, traj.next_obs)

        values = critic.apply({"params": state.critic_params}, obs)
        next_values = critic.apply({"params": state.critic_params}, next_obs)
        rewards = traj.reward * config.reward_scale
        per_lane = dict(in_axes=(1, 1, 1, 1, 1, None, None), out_axes=1)
        adv = jax.vmap(gae, **per_lane)(
            rewards, values, next_values, traj.termination, traj.truncation, config.gamma, config.gae_lambda
        )
        targets = jax.vmap(lambda_returns, in_axes=(1, 1, 1, 1, None, None), out_axes=1)(
            rewards, next_values, traj.termination, traj.truncation, config.gamma, config.gae_lambda
        )
        if config.normalize_advantages:
            mu = parallel.pmean(jnp.mean(adv))
            var = parallel.pmean(jnp.mean((adv - mu) ** 2))
            adv = (adv - mu) / (jnp.sqrt(var) + 1e-8)

        # m actor updates (Algorithm 8, lines 4-10); π_old is the policy that collected the data,
        # exactly as it acted (moving batch-norm statistics, the observation normaliser it saw).
        old_mean, old_log_std = act(state, traj.obs)

        def actor_step(carry, k):
            params, stats, opt = carry
            mb = minibatch(k, lane_ids, (obs, traj.action, adv, old_mean, old_log_std))
            grad_fn = jax.value_and_grad(actor_loss_fn, has_aux=True)
            (loss, (stats, clip_frac, entropy, _)), grads = grad_fn(params, stats, mb, state.kl_beta)
            params, opt = common.apply_gradients(actor_tx, parallel.pmean(grads), opt, params)
            return (params, stats, opt), (loss, clip_frac, entropy)

        carry = (state.actor_params, state.actor_stats, state.actor_opt)
        (actor_params, actor_stats, actor_opt), (a_loss, clip_frac, entropy) = jax.lax.scan(
            actor_step, carry, jax.random.split(k_actor, config.actor_updates)
        )

        # D of Eq. 5.4 on all K·N transitions: π_old as it acted vs π_θ as it will act; then β's
        # halve/double rule.
        (new_mean, new_log_std), _ = apply_actor(actor, actor_params, actor_stats, obs)
        kl = parallel.pmean(jnp.mean(gaussian_kl(old_mean, old_log_std, new_mean, new_log_std)))
        kl_beta = state.kl_beta
        if config.objective == "kl":
            kl_beta = adapt_kl_beta(kl_beta, kl, config.kl_target, config.kl_beta_min, config.kl_beta_max)

        # n critic updates on λ-return targets (Algorithm 8, lines 11-16).
        def critic_step(carry, k):
            params, opt = carry
            mb = minibatch(k, lane_ids, (obs, targets))
            loss, grads = jax.value_and_grad(critic_loss_fn)(params, mb)
            return common.apply_gradients(critic_tx, parallel.pmean(grads), opt, params), loss

        (critic_params, critic_opt), c_loss = jax.lax.scan(
            critic_step, (state.critic_params, state.critic_opt), jax.random.split(k_critic, config.critic_updates)
        )

        # Same dtypes in as out (an env may return weak-typed metrics), so the jitted chunk never retraces.
        env_state = common.cast_like(env_state, state.env_state)
        new_state = state.replace(
            actor_params=actor_params, actor_stats=actor_stats, actor_opt=actor_opt,
            critic_params=critic_params, critic_opt=critic_opt, obs_stats=obs_stats, kl_beta=kl_beta,
            env_state=env_state, key=key, iteration=state.iteration + 1,
        )  # fmt: skip
        metrics = {
            "actor_loss": parallel.pmean(jnp.mean(a_loss)),
            "critic_loss": parallel.pmean(jnp.mean(c_loss)),
            "kl": kl,
            "kl_beta": kl_beta,
            "clip_fraction": parallel.pmean(jnp.mean(clip_frac)),
            "entropy": jnp.mean(entropy),
            "value": parallel.pmean(jnp.mean(values)),
            "reward": parallel.pmean(jnp.mean(traj.reward)),
        }
        return new_state, (metrics, common.episode_sums(traj))

    def chunk(state: PPOState) -> tuple[PPOState, Metrics]:
        state, (metrics, sums) = jax.lax.scan(lambda s, _: iteration(s), state, None, length=iterations_per_update)
        return state, common.chunk_metrics(metrics, sums)

    specs = common.state_specs(PPOState, env_state=parallel.P(_LANES))
    update = parallel.shard_lanes(chunk, run.mesh, in_specs=(specs,), out_specs=(specs, parallel.P()))

    def policy(state: PPOState) -> Policy:
        return lambda obs: act(state, obs)[0]

    return run.trainer(init, update, policy)


make_train = common.make_train_for(make_trainer)
"""``make_train(config, env, *, mesh=None, iterations_per_update=1) -> train``: ``train(key) -> (final
PPOState, metrics [num_updates])``, the whole run, pure and jittable (vmappable over keys)."""
