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

import math
from collections.abc import Callable
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
import optax
from brax.envs.base import Env, State
from flax import struct

from envs_mjx.base import wrap_for_training
from envs_mjx.config import ConfigError
from jaxrl_robot import parallel
from jaxrl_robot.acting import rollout
from jaxrl_robot.agents.ppo.config import PPOConfig
from jaxrl_robot.agents.ppo.losses import (
    LOG_RATIO_LIMIT,
    adapt_kl_beta,
    clipped_surrogate_loss,
    kl_penalty_loss,
    value_loss,
)
from jaxrl_robot.networks import (
    Critic,
    GaussianActor,
    apply_actor,
    gaussian_entropy,
    gaussian_kl,
    gaussian_log_prob,
    gaussian_sample,
    init_running_stats,
    normalize,
    update_running_stats,
)
from jaxrl_robot.returns import gae, lambda_returns
from jaxrl_robot.types import Metrics, Policy, RunningStats, Trainer, Transition

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
    sigma = tuple(config.sigma)
    if len(sigma) == 1:
        sigma = sigma * action_size
    if len(sigma) != action_size:
        raise ConfigError(f"sigma={config.sigma!r} must have 1 or action_size={action_size} values")
    actor = GaussianActor(
        action_size=action_size,
        hidden=tuple(config.actor_hidden),
        sigma=sigma,
        learn_std=config.learn_std,
        batch_norm=config.batch_norm,
        bn_momentum=config.bn_momentum,
        bn_mode=config.bn_mode,
        bn_axis_name=_LANES,
    )
    return actor, Critic(hidden=tuple(config.critic_hidden))


def _optimizer(lr: float, max_grad_norm: float) -> optax.GradientTransformation:
    adam = optax.adam(lr)
    return optax.chain(optax.clip_by_global_norm(max_grad_norm), adam) if max_grad_norm > 0 else adam


def _schedule_tables(config: PPOConfig, env: Env) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """``name -> (starts [S], values [S, ...])`` sorted by start; validated against the env's params."""
    if not config.schedule:
        return {}
    defaults = env.default_params() if hasattr(env, "default_params") else {}
    tables: dict[str, list] = {}
    for start, name, value in sorted(config.schedule, key=lambda e: e[0]):
        if name not in defaults:
            valid = ", ".join(sorted(defaults)) or "none"
            raise ConfigError(f"schedule: unknown episode parameter {name!r}; this env's parameters: {valid}")
        val = np.broadcast_to(np.asarray(value, np.float32), np.shape(defaults[name]))
        tables.setdefault(name, []).append((float(start), val))
    out = {}
    for name, entries in tables.items():
        if entries[0][0] != 0.0:
            raise ConfigError(f"schedule: parameter {name!r} needs an entry starting at 0.0")
        out[name] = (np.array([s for s, _ in entries], np.float32), np.stack([v for _, v in entries]))
    return out


def _schedule_values(tables: dict, progress: jax.Array) -> dict[str, jax.Array]:
    """Piecewise-constant parameter values at ``progress`` in [0, 1]."""
    out = {}
    for name, (starts, values) in tables.items():
        idx = jnp.sum(jnp.asarray(starts) <= progress) - 1
        out[name] = jnp.asarray(values)[jnp.clip(idx, 0, len(starts) - 1)]
    return out


def _per_lane_keys(key: jax.Array, lane_ids: jax.Array) -> jax.Array:
    return jax.vmap(jax.random.fold_in, in_axes=(None, 0))(key, lane_ids)


def make_actor_loss(config: PPOConfig, actor: GaussianActor) -> Callable:
    """``loss(params, stats, minibatch, beta) -> (loss, (new_stats, clip_fraction, entropy, kl))``.

    ``minibatch = (obs [B, D], action [B, A], advantage [B], old_mean [B, A], old_log_std [B, A])``
    where ``old_*`` are π_old's outputs as it acted. π_θ runs in training mode (batch
    statistics; ``new_stats`` are the advanced moving averages). The ratio
    ``r = π_θ(a|s) / π_old(a|s)`` enters the clipped objective (Eq. 5.5) or the KL-penalty
    objective (Eq. 5.3) with ``kl = KL(π_old ‖ π_θ)``, mean over the mini-batch; minus
    ``entropy_coef`` times the mean entropy.
    """

    def loss_fn(params: Any, stats: Any, mb: tuple, beta: jax.Array):
        obs, action, adv, old_mean, old_log_std = mb
        (mean, log_std), new_stats = apply_actor(actor, params, stats, obs, train=True)
        log_prob = gaussian_log_prob(mean, log_std, action)
        old_log_prob = gaussian_log_prob(old_mean, old_log_std, action)
        kl = gaussian_kl(old_mean, old_log_std, mean, log_std)
        entropy = jnp.mean(gaussian_entropy(log_std))
        if config.objective == "clip":
            loss, clip_frac = clipped_surrogate_loss(log_prob, old_log_prob, adv, config.clip_eps)
        else:
            loss = kl_penalty_loss(log_prob, old_log_prob, adv, kl, beta)
            log_ratio = jnp.clip(log_prob - old_log_prob, -LOG_RATIO_LIMIT, LOG_RATIO_LIMIT)
            clip_frac = jnp.mean((jnp.abs(jnp.exp(log_ratio) - 1.0) > config.clip_eps) * 1.0)
        loss = loss - config.entropy_coef * entropy
        return loss, (new_stats, clip_frac, entropy, jnp.mean(kl))

    return loss_fn


def make_trainer(
    config: PPOConfig,
    env: Env,
    *,
    mesh: jax.sharding.Mesh | None = None,
    iterations_per_update: int = 1,
) -> Trainer:
    """Build the PPO :class:`~jaxrl_robot.types.Trainer` for ``env``.

    Args:
      config: hyper-parameters (validated here).
      env: an *unbatched* ``brax.envs.base.Env``; it is wrapped with
        ``envs_mjx.wrap_for_training`` (lanes, time limit, true auto-reset).
      mesh: device mesh from ``parallel.lane_mesh`` (default: all devices).
      iterations_per_update: iterations per ``update`` call (one chunk).
    """
    config.validate()
    if iterations_per_update < 1:
        raise ConfigError(f"iterations_per_update={iterations_per_update} must be >= 1")
    mesh = parallel.lane_mesh() if mesh is None else mesh
    K, N = config.num_envs, config.unroll_length
    k_local = parallel.local_lane_count(K, mesh)
    b_lane = config.minibatch_size // K  # transitions per lane in each mini-batch
    episode_length = config.episode_length or getattr(env, "episode_length", None)
    if not episode_length:
        raise ConfigError("episode_length=0: this env has no default episode_length; set episode_length >= 1")
    if config.lane_group and k_local % config.lane_group:
        raise ConfigError(f"lane_group={config.lane_group} must divide the lanes per device ({k_local})")
    wrapped = wrap_for_training(
        env,
        episode_length=int(episode_length),
        reset_refresh=config.reset_refresh,
        reset_group=config.reset_group,
        lane_group=config.lane_group,
    )
    obs_size, action_size = int(env.observation_size), int(env.action_size)
    actor, critic = make_networks(config, action_size)
    actor_tx = _optimizer(config.actor_lr, config.max_grad_norm)
    critic_tx = _optimizer(config.critic_lr, config.max_grad_norm)
    tables = _schedule_tables(config, env)
    steps_per_iteration = K * N
    total_iterations = max(1, math.ceil(config.total_steps / steps_per_iteration))
    num_updates = math.ceil(total_iterations / iterations_per_update)
    schedule_len = float(num_updates * iterations_per_update)

    def obs_norm(stats: RunningStats, obs: jax.Array) -> jax.Array:
        return normalize(stats if config.normalize_obs else None, obs)

    def initial_params() -> dict[str, jax.Array] | None:
        if not tables:
            return None
        params = dict(env.default_params())
        params.update(_schedule_values(tables, jnp.asarray(0.0)))
        return params

    # ---- init --------------------------------------------------------------------------
    def reset_lanes(keys: jax.Array) -> State:
        return wrapped.reset(keys, initial_params())

    def init(key: jax.Array) -> PPOState:
        k_actor, k_critic, k_env, k_run = jax.random.split(key, 4)
        dummy = jnp.zeros((1, obs_size), jnp.float32)
        actor_vars = actor.init(k_actor, dummy)
        actor_params = actor_vars["params"]
        actor_stats = actor_vars.get("batch_stats", {})
        critic_params = critic.init(k_critic, dummy)["params"]
        env_keys = jax.random.split(k_env, K)
        env_state = parallel.shard_lanes(reset_lanes, mesh, parallel.P(_LANES), parallel.P(_LANES))(env_keys)
        return PPOState(
            actor_params=actor_params,
            actor_stats=actor_stats,
            critic_params=critic_params,
            actor_opt=actor_tx.init(actor_params),
            critic_opt=critic_tx.init(critic_params),
            obs_stats=init_running_stats(obs_size),
            kl_beta=jnp.asarray(config.kl_beta, jnp.float32),
            env_state=env_state,
            key=k_run,
            iteration=jnp.zeros((), jnp.int32),
        )

    # ---- one iteration (inside shard_map: this device's k_local lanes) -----------------
    def apply_schedule(env_state: State, iteration: jax.Array) -> State:
        if not tables:
            return env_state
        values = _schedule_values(tables, iteration.astype(jnp.float32) / schedule_len)
        params = dict(env_state.info["params"])
        for name, v in values.items():
            params[name] = jnp.broadcast_to(v, params[name].shape).astype(params[name].dtype)
        return env_state.replace(info={**env_state.info, "params": params})

    def minibatch(key: jax.Array, lane_ids: jax.Array, data: Any) -> Any:
        """``b_lane`` steps from every lane: ``[N, k_local, ...] -> [b_lane * k_local, ...]``."""
        keys = _per_lane_keys(key, lane_ids)
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
        env_state = apply_schedule(state.env_state, state.iteration)

        def policy(k: jax.Array, obs: jax.Array) -> jax.Array:
            x = obs_norm(state.obs_stats, obs)
            (mean, log_std), _ = apply_actor(actor, state.actor_params, state.actor_stats, x, train=False)
            return jax.vmap(gaussian_sample)(_per_lane_keys(k, lane_ids), mean, log_std)

        env_state, traj = rollout(k_roll, wrapped, env_state, policy, N)  # [N, k_local]
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
        behaviour_obs = obs_norm(state.obs_stats, traj.obs)
        (old_mean, old_log_std), _ = apply_actor(actor, state.actor_params, state.actor_stats, behaviour_obs)

        def actor_step(carry, k):
            params, stats, opt = carry
            mb = minibatch(k, lane_ids, (obs, traj.action, adv, old_mean, old_log_std))
            grad_fn = jax.value_and_grad(actor_loss_fn, has_aux=True)
            (loss, (stats, clip_frac, entropy, _)), grads = grad_fn(params, stats, mb, state.kl_beta)
            grads = parallel.pmean(grads)
            updates, opt = actor_tx.update(grads, opt, params)
            params = optax.apply_updates(params, updates)
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
            grads = parallel.pmean(grads)
            updates, opt = critic_tx.update(grads, opt, params)
            return (optax.apply_updates(params, updates), opt), loss

        (critic_params, critic_opt), c_loss = jax.lax.scan(
            critic_step, (state.critic_params, state.critic_opt), jax.random.split(k_critic, config.critic_updates)
        )

        # Same dtypes in as out (an env may return weak-typed metrics), so the jitted chunk never retraces.
        env_state = _like(env_state, state.env_state)
        new_state = PPOState(
            actor_params=actor_params,
            actor_stats=actor_stats,
            critic_params=critic_params,
            actor_opt=actor_opt,
            critic_opt=critic_opt,
            obs_stats=obs_stats,
            kl_beta=kl_beta,
            env_state=env_state,
            key=key,
            iteration=state.iteration + 1,
        )
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
        return new_state, (metrics, _episode_sums(traj))

    def chunk(state: PPOState) -> tuple[PPOState, Metrics]:
        state, (metrics, sums) = jax.lax.scan(lambda s, _: iteration(s), state, None, length=iterations_per_update)
        out = {k: jnp.mean(v) for k, v in metrics.items()}
        sums = parallel.psum(jax.tree.map(lambda x: jnp.sum(x, axis=0), sums))
        episodes = sums.pop("episodes")
        out["episodes"] = episodes
        for k, v in sums.items():
            out[k] = jnp.where(episodes > 0, v / jnp.maximum(episodes, 1.0), jnp.nan)
        return state, out

    state_specs = PPOState(
        actor_params=parallel.P(),
        actor_stats=parallel.P(),
        critic_params=parallel.P(),
        actor_opt=parallel.P(),
        critic_opt=parallel.P(),
        obs_stats=parallel.P(),
        kl_beta=parallel.P(),
        env_state=parallel.P(_LANES),
        key=parallel.P(),
        iteration=parallel.P(),
    )
    update = parallel.shard_lanes(chunk, mesh, in_specs=(state_specs,), out_specs=(state_specs, parallel.P()))

    def policy(state: PPOState) -> Policy:
        def act(obs: jax.Array) -> jax.Array:
            x = obs_norm(state.obs_stats, obs)
            (mean, _), _ = apply_actor(actor, state.actor_params, state.actor_stats, x, train=False)
            return mean

        return act

    return Trainer(
        init=init,
        update=update,
        policy=policy,
        num_updates=num_updates,
        env_steps_per_update=steps_per_iteration * iterations_per_update,
    )


def _like(tree: Any, reference: Any) -> Any:
    """``tree`` with every leaf cast to the dtype of ``reference``'s leaf (drops weak types)."""
    return jax.tree.map(lambda x, r: jnp.asarray(x).astype(r.dtype), tree, reference)


def _episode_sums(traj: Transition) -> dict[str, jax.Array]:
    """Sums over finished episodes of this device's lanes: ``episodes`` and every episode metric."""
    done = traj.done
    sums = {"episodes": jnp.sum(done)}
    for k, v in traj.metrics.items():
        if v.shape == done.shape:
            sums[k] = jnp.sum(jnp.where(done > 0, v, 0.0))
    return sums


def make_train(
    config: PPOConfig, env: Env, *, mesh: jax.sharding.Mesh | None = None, iterations_per_update: int = 1
) -> Callable[[jax.Array], tuple[PPOState, Metrics]]:
    """``train(key) -> (final state, metrics [num_updates])``: the whole run, pure and jittable.

    ``jax.jit(jax.vmap(train))(keys)`` trains one agent per key.
    """
    trainer = make_trainer(config, env, mesh=mesh, iterations_per_update=iterations_per_update)

    def train(key: jax.Array) -> tuple[PPOState, Metrics]:
        state = trainer.init(key)
        return jax.lax.scan(lambda s, _: trainer.update(s), state, None, length=trainer.num_updates)

    return train
