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
With ``advantage_segment`` S > 0 (brax's update) each mini-batch is whole S-step segments whose
advantages and targets come from the critic of that moment, and one actor and one critic step follow.

``policy='lstm'`` (thesis §5.7) runs the same iteration with recurrent networks
(:mod:`jaxrl_robot.agents.ppo.nets`): lanes carry the LSTM states of actor and critic, every
step records the states it started from, updates run on mini-batches of whole sequences of
``seq_length`` steps from those records, and an episode that RSI starts at reference step ``k``
starts from the state the start-state table holds for ``k`` (:mod:`jaxrl_robot.recurrent`).

Randomness is keyed by *global* lane index (action noise, mini-batch choice, env resets), so
the result does not depend on how many devices share the lanes (except the segments' draws).
"""

from __future__ import annotations

import math
from typing import Any

import jax
import jax.numpy as jnp
from brax.envs.base import Env, State
from flax import struct
from jax.sharding import Mesh

from envs_mjx.base import ClipActionWrapper, TanhActionWrapper
from envs_mjx.config import ConfigError
from envs_mjx.playground import adapt
from jaxrl_robot import parallel
from jaxrl_robot.acting import per_lane_keys, rollout_with_memory
from jaxrl_robot.agents import core, on_policy
from jaxrl_robot.agents.ppo.config import PPOConfig
from jaxrl_robot.agents.ppo.losses import adapt_kl_beta, make_actor_loss, value_loss
from jaxrl_robot.agents.ppo.nets import make_ppo_nets
from jaxrl_robot.agents.ppo.pretrain import action_search, make_imitation_update, model_reward_of
from jaxrl_robot.evaluation import sampling_policy
from jaxrl_robot.networks import gaussian_kl, init_running_stats, normalize, update_running_stats
from jaxrl_robot.recurrent import table_lookup, table_update
from jaxrl_robot.returns import gae, lambda_returns
from jaxrl_robot.types import Metrics, Policy, RecurrentPolicy, RunningStats, Trainer

__all__ = ["PPOState", "make_actor_loss", "make_networks", "make_train", "make_trainer", "optimizer_steps"]

_LANES = parallel.LANES


@struct.dataclass
class PPOState(core.RunState):
    """Everything a PPO run needs to continue exactly: the lanes' ``env_state [K]``, ``key`` and
    ``iteration`` (iterations done) of :class:`~jaxrl_robot.agents.core.RunState`, and

    Attributes:
      actor_params, actor_stats: actor ``params`` and ``batch_stats`` (``{}`` without batch-norm).
      critic_params: critic ``params``.
      actor_opt, critic_opt: Adam states.
      obs_stats: observation normaliser (unused unless ``normalize_obs``).
      kl_beta: ``[]`` β of the adaptive KL penalty.
      memory: ``[K, ...]`` per-lane LSTM states ``{"actor": (c, h), "critic": (c, h)}`` (``()`` for the MLP).
      start_table: ``[max_steps + 1, ...]`` the start-state table (``()`` unless policy='lstm'
        with lstm_start 'table').
    """

    actor_params: Any
    actor_stats: Any
    critic_params: Any
    actor_opt: Any
    critic_opt: Any
    obs_stats: RunningStats
    kl_beta: jax.Array
    memory: Any
    start_table: Any


def make_networks(config: PPOConfig, action_size: int) -> tuple[Any, Any]:
    """The actor and critic modules of ``config``; σ is broadcast to ``action_size``."""
    nets = make_ppo_nets(config, action_size, bn_axis_name=_LANES)
    return nets.actor, nets.critic


def uses_start_table(config: PPOConfig, env: Env) -> bool:
    """Whether episodes start from the start-state table (policy 'lstm'; ``config.lstm_start``):
    the env must report its reference step in ``info["k"]`` and have ``max_steps``."""
    if config.policy != "lstm" or config.lstm_start == "zero":
        return False
    reports_k = hasattr(env, "max_steps") and "k" in jax.eval_shape(env.reset, jax.random.PRNGKey(0)).info
    if config.lstm_start == "table" and not reports_k:
        raise ConfigError(
            "lstm_start='table' needs an env that reports its reference step (info['k'], max_steps); "
            "valid here: 'zero' or 'auto'"
        )
    return reports_k


def pretrain_iterations(config: PPOConfig, env: Env) -> int:
    """Iterations of action-search pre-training (0 unless ``config.pretrain``): ``pretrain_episodes``
    episodes of the time limit, rounded up to whole iterations of K·N steps."""
    if config.pretrain == "none":
        return 0
    if model_reward_of(env) is None:
        raise ConfigError(
            f"pretrain={config.pretrain!r} needs an env with known kinematics (model_reward); "
            f"{type(env).__name__} has none. Envs that have it: unicycle; valid here: pretrain='none'"
        )
    episode_length = config.episode_length or env.episode_length
    iterations = math.ceil(config.pretrain_episodes * episode_length / (config.num_envs * config.unroll_length))
    if iterations >= config.total_iterations:
        raise ConfigError(
            f"pretrain_episodes={config.pretrain_episodes} ({iterations} iterations) leaves no PPO iterations "
            f"of total_steps={config.total_steps} ({config.total_iterations} iterations)"
        )
    return iterations


def optimizer_steps(config: PPOConfig, iterations: int, pretrain_iters: int = 0) -> tuple[int, int]:
    """``(actor, critic)`` Adam steps of a run of ``iterations``: ``actor_updates`` per iteration for the
    actor, save in the ``pretrain_iters`` of imitation (which fit the actor without its optimiser), and
    ``critic_updates`` for the critic (with ``advantage_segment``, the same count as the actor's)."""
    return (iterations - pretrain_iters) * config.actor_updates, iterations * config.critic_updates


def make_trainer(config: PPOConfig, env: Env, *, mesh: Mesh | None = None, iterations_per_update: int = 1) -> Trainer:
    """Build the PPO :class:`~jaxrl_robot.types.Trainer` for the *unbatched* ``env``: a brax ``Env``
    (brax's or ours) or a MuJoCo Playground env (any env ``envs_mjx.playground.adapt`` takes; the
    policy sees the ``"state"`` entry of a dict observation).

    ``config`` is validated; ``env`` is wrapped for training (lanes, time limit, true auto-reset,
    the reset pool and lane groups of ``config``); the lanes are split over ``mesh`` (default: all
    devices); one ``update`` call runs ``iterations_per_update`` iterations (see
    :func:`~jaxrl_robot.agents.core.setup`).
    """
    env = adapt(env)
    acting_env = ClipActionWrapper(env) if config.clip_actions else env
    acting_env = TanhActionWrapper(acting_env) if config.tanh_actions else acting_env
    run = core.setup(
        config,
        acting_env,
        mesh,
        iterations_per_update,
        reset_refresh=config.reset_refresh,
        reset_group=config.reset_group,
        lane_group=config.lane_group,
    )
    N, k_local, obs_size = config.unroll_length, run.local_lanes, run.obs_size
    nets = make_ppo_nets(config, run.action_size, bn_axis_name=_LANES)
    L = nets.seq_length  # steps per training sequence (1: the MLP)
    b_seq = config.minibatch_size // (config.num_envs * L)  # sequences per lane in each mini-batch
    S = config.advantage_segment  # steps per advantage segment (0: advantages once per batch)
    use_table = uses_start_table(config, env)
    pretrain_iters = pretrain_iterations(config, env)
    tables = on_policy.schedule_tables(config.schedule, env)
    iterations = run.num_updates * iterations_per_update
    schedule_len = float(iterations)
    end = on_policy.lr_end_factor(config)
    actor_steps, critic_steps = optimizer_steps(config, iterations, pretrain_iters)
    actor_tx = core.make_optimizer(config.actor_lr, config.max_grad_norm, end, actor_steps)
    critic_tx = core.make_optimizer(config.critic_lr, config.max_grad_norm, end, critic_steps)

    def obs_norm(stats: RunningStats, obs: jax.Array) -> jax.Array:
        return normalize(stats if config.normalize_obs else None, obs)

    def act(state: PPOState, memory: Any, obs: jax.Array) -> tuple[Any, tuple[jax.Array, jax.Array]]:
        """``(memory, (mean, log_std))`` of the acting policy (moving batch-norm statistics, normalised obs)."""
        obs = obs_norm(state.obs_stats, obs)
        return nets.act(state.actor_params, state.actor_stats, state.critic_params, memory, obs)

    def start_memory(state: PPOState, env_state: State) -> Any:
        """The memory of episodes starting in ``env_state`` ``[B]``: their table entries, or zeros."""
        if use_table:
            return table_lookup(state.start_table, env_state.info["k"])
        return nets.memory(env_state.done.shape)

    # ---- init --------------------------------------------------------------------------
    def init(key: jax.Array) -> PPOState:
        k_actor, k_critic, k_env, k_run = jax.random.split(key, 4)
        actor_params, actor_stats, critic_params = nets.init(k_actor, k_critic, obs_size)
        return PPOState(
            actor_params=actor_params,
            actor_stats=actor_stats,
            critic_params=critic_params,
            actor_opt=actor_tx.init(actor_params),
            critic_opt=critic_tx.init(critic_params),
            obs_stats=init_running_stats(obs_size),
            kl_beta=jnp.asarray(config.kl_beta, jnp.float32),
            env_state=run.reset(k_env, lambda: on_policy.initial_env_params(env, tables)),
            memory=nets.memory((config.num_envs,)),
            start_table=nets.memory((env.max_steps + 1,)) if use_table else (),
            key=k_run,
            iteration=jnp.zeros((), jnp.int32),
        )

    # ---- one iteration (inside shard_map: this device's k_local lanes) -----------------
    def minibatch(key: jax.Array, lane_ids: jax.Array, data: Any) -> Any:
        """``b_seq`` whole sequences of ``L`` steps from every lane (drawn without replacement):
        ``[N, k_local, ...] -> [L, b_seq * k_local, ...]``."""
        keys = per_lane_keys(key, lane_ids)
        idx = jax.vmap(lambda k: jax.random.permutation(k, N // L)[:b_seq], out_axes=1)(keys)  # [b_seq, k_local]

        def take(x: jax.Array) -> jax.Array:
            seqs = x.reshape((N // L, L) + x.shape[1:])
            ix = idx.reshape((b_seq, 1) + idx.shape[1:] + (1,) * (x.ndim - 2))
            picked = jnp.moveaxis(jnp.take_along_axis(seqs, ix, axis=0), 1, 0)  # [L, b_seq, k_local, ...]
            return picked.reshape((L, b_seq * k_local) + x.shape[2:])

        return jax.tree.map(take, data)

    devices = config.num_envs // k_local
    if S and (config.minibatch_size // S) % devices:
        raise ConfigError(f"minibatch_size={config.minibatch_size} / advantage_segment={S} segments must split "
                          f"evenly over the {devices} devices")  # fmt: skip

    def segments(key: jax.Array, lane_ids: jax.Array, data: Any) -> Any:
        """``m = minibatch_size / (S · devices)`` whole segments of ``S`` steps drawn without replacement
        from all of this device's lanes (as brax draws its unrolls): ``[N, k_local, ...] -> [S, m, ...]``."""
        m = config.minibatch_size // (S * devices)
        idx = jax.random.permutation(jax.random.fold_in(key, lane_ids[0]), (N // S) * k_local)[:m]
        seg, lane = idx // k_local, idx % k_local

        def take(x: jax.Array) -> jax.Array:
            picked = x.reshape((N // S, S) + x.shape[1:])[seg, :, lane]  # [m, S, ...]
            return jnp.moveaxis(picked, 0, 1)

        return jax.tree.map(take, data)

    def flat(x: jax.Array) -> jax.Array:
        """``[L, B, ...] -> [L * B, ...]``."""
        return x.reshape((-1,) + x.shape[2:])

    def actor_forward(params, stats, inputs):
        (mean, log_std), stats = nets.actor_forward(params, stats, *inputs, train=True)
        return (flat(mean), flat(log_std)), stats

    actor_loss_fn = make_actor_loss(config, nets.actor, actor_forward)
    if pretrain_iters:
        steps = max(1, config.pretrain_epochs * config.num_envs * N // config.minibatch_size)
        imitate = make_imitation_update(actor_forward, minibatch, steps, config.pretrain_lr)

    def critic_loss_fn(params, mb):
        inputs, targets = mb
        return value_loss(flat(nets.critic_forward(params, *inputs)[0]), flat(targets))

    def advantages(rewards, values, next_values, terminations, truncations) -> jax.Array:
        """GAE (Eq. 5.12) of every lane's stream ``[T, B]`` (each truncated at its end)."""
        per_lane = jax.vmap(gae, in_axes=(1, 1, 1, 1, 1, None, None), out_axes=1)
        return per_lane(rewards, values, next_values, terminations, truncations, config.gamma, config.gae_lambda)

    def normalized(adv: jax.Array) -> jax.Array:
        """``adv`` to zero mean and unit variance over all devices' lanes (``normalize_advantages``)."""
        if not config.normalize_advantages:
            return adv
        mu = parallel.pmean(jnp.mean(adv))
        var = parallel.pmean(jnp.mean((adv - mu) ** 2))
        return (adv - mu) / (jnp.sqrt(var) + 1e-8)

    def iteration(state: PPOState) -> tuple[PPOState, Metrics]:
        key, k_roll, k_actor, k_critic = jax.random.split(state.key, 4)
        lane_ids = parallel.global_lane_ids(k_local)
        progress = state.iteration.astype(jnp.float32) / schedule_len
        env_state = on_policy.apply_schedule(state.env_state, tables, progress)

        pretraining = state.iteration < pretrain_iters

        def search(k: jax.Array, s: State) -> tuple[jax.Array, jax.Array]:
            """Action search at every visited state while pre-training (Algorithm 9, lines 7-9)."""
            if not pretrain_iters:
                return ()

            def best() -> tuple[jax.Array, jax.Array]:
                model = model_reward_of(env)
                return action_search(k, lane_ids, model, s, config.pretrain_candidates, run.action_size)

            def skip() -> tuple[jax.Array, jax.Array]:
                return jnp.zeros((k_local, run.action_size)), jnp.full((k_local,), -jnp.inf)

            return jax.lax.cond(pretraining, best, skip)

        def policy(k: jax.Array, memory: Any, s: State) -> tuple[Any, jax.Array, Any]:
            memory_next, (mean, log_std) = act(state, memory, s.obs)
            record = (memory, s.info["k"] if use_table else (), search(jax.random.fold_in(k, 1), s))
            return memory_next, on_policy.sample_lanes(k, lane_ids, mean, log_std), record

        first_done = env_state.done.astype(jnp.float32)
        env_state, memory, (traj, (mem_seq, k_seq, searched)) = rollout_with_memory(
            k_roll, run.env, env_state, state.memory, policy, N, lambda ns: start_memory(state, ns)
        )  # [N, k_local]
        # A step restarts from its recorded memory at an episode start and at a sequence start.
        starts = jnp.concatenate([first_done[None], traj.done[:-1]])
        reset = jnp.maximum(starts, (jnp.arange(N) % L == 0).astype(jnp.float32)[:, None])
        start_table = state.start_table
        if use_table:
            start_table = table_update(start_table, k_seq, mem_seq, 1.0 - starts, config.start_table_rate)
        obs_stats = state.obs_stats
        if config.normalize_obs:
            obs_stats = update_running_stats(obs_stats, traj.obs, _LANES)
        obs = obs_norm(obs_stats, traj.obs)
        next_obs = obs_norm(obs_stats, traj.next_obs)
        inputs = (mem_seq, reset, obs)

        rewards = traj.reward * config.reward_scale

        def values_of(critic_params: Any) -> tuple[jax.Array, jax.Array]:
            """``(V(s), V(s'))`` ``[N, k_local]`` of the batch under ``critic_params``."""
            values, after = nets.critic_forward(critic_params, *inputs)
            return values, nets.next_values(critic_params, after, next_obs)

        values, next_values = values_of(state.critic_params)
        targets = jax.vmap(lambda_returns, in_axes=(1, 1, 1, 1, None, None), out_axes=1)(
            rewards, next_values, traj.termination, traj.truncation, config.gamma, config.gae_lambda
        )

        # n critic updates on λ-return targets (Algorithm 8, lines 11-16).
        def critic_step(carry, k):
            params, opt = carry
            mb = minibatch(k, lane_ids, (inputs, targets))
            loss, grads = jax.value_and_grad(critic_loss_fn)(params, mb)
            return core.apply_gradients(critic_tx, parallel.pmean(grads), opt, params), loss

        def critic_update():
            return jax.lax.scan(
                critic_step, (state.critic_params, state.critic_opt), jax.random.split(k_critic, config.critic_updates)
            )

        if config.critic_first:
            # The critic learns from this batch first; the advantages then come from the updated critic.
            (critic_params, critic_opt), c_loss = critic_update()
            adv_values, adv_next_values = values_of(critic_params)
        else:
            adv_values, adv_next_values = values, next_values
        adv = normalized(advantages(rewards, adv_values, adv_next_values, traj.termination, traj.truncation))

        # m actor updates (Algorithm 8, lines 4-10); π_old is the policy that collected the data,
        # exactly as it acted (moving batch-norm statistics, the observation normaliser it saw).
        old_inputs = (mem_seq, reset, obs_norm(state.obs_stats, traj.obs))
        (old_mean, old_log_std), _ = nets.actor_forward(state.actor_params, state.actor_stats, *old_inputs, False)

        def actor_step(carry, k):
            params, stats, opt = carry
            inputs_mb, *rest = minibatch(k, lane_ids, (inputs, traj.action, adv, old_mean, old_log_std))
            mb = (inputs_mb, *map(flat, rest))
            grad_fn = jax.value_and_grad(actor_loss_fn, has_aux=True)
            (loss, (stats, clip_frac, entropy, _)), grads = grad_fn(params, stats, mb, state.kl_beta)
            params, opt = core.apply_gradients(actor_tx, parallel.pmean(grads), opt, params)
            return (params, stats, opt), (loss, clip_frac, entropy)

        def ppo_actor_update():
            carry = (state.actor_params, state.actor_stats, state.actor_opt)
            carry, losses = jax.lax.scan(actor_step, carry, jax.random.split(k_actor, config.actor_updates))
            return carry, tuple(map(jnp.mean, losses))

        def imitation_update():
            """Pre-training: the actor's mean fitted to the searched actions that beat its own (Algorithm 9)."""
            target, best_reward = searched
            better = (best_reward > traj.reward).astype(jnp.float32)
            args = (state.actor_params, state.actor_stats, inputs, target, better)
            (params, stats), (loss, entropy) = imitate(k_actor, lane_ids, *args)
            return (params, stats, state.actor_opt), (loss, jnp.zeros(()), entropy)

        def joint_step(carry, k):
            """One mini-batch of whole segments: advantages and λ-returns from the current critic
            (Eq. 5.12, 5.14; ``lambda_returns = gae + values``), then one actor and one critic step."""
            (a_params, a_stats, a_opt), (c_params, c_opt) = carry
            data = (inputs, traj.action, rewards, next_obs, traj.termination, traj.truncation, old_mean, old_log_std)
            mb_inputs, action, reward, mb_next_obs, term, trunc, mb_mean, mb_log_std = segments(k, lane_ids, data)
            v, after = nets.critic_forward(c_params, *mb_inputs)  # [S, m]
            adv = advantages(reward, v, nets.next_values(c_params, after, mb_next_obs), term, trunc)
            mb = (mb_inputs, *map(flat, (action, normalized(adv), mb_mean, mb_log_std)))
            grad_fn = jax.value_and_grad(actor_loss_fn, has_aux=True)
            (loss, (a_stats, clip_frac, entropy, _)), grads = grad_fn(a_params, a_stats, mb, state.kl_beta)
            a_params, a_opt = core.apply_gradients(actor_tx, parallel.pmean(grads), a_opt, a_params)
            c_loss, grads = jax.value_and_grad(critic_loss_fn)(c_params, (mb_inputs, adv + v))
            c_params, c_opt = core.apply_gradients(critic_tx, parallel.pmean(grads), c_opt, c_params)
            return ((a_params, a_stats, a_opt), (c_params, c_opt)), (loss, clip_frac, entropy, c_loss)

        def joint_update():
            carry = ((state.actor_params, state.actor_stats, state.actor_opt), (state.critic_params, state.critic_opt))
            (actor_carry, critic_carry), (*losses, c_loss) = jax.lax.scan(
                joint_step, carry, jax.random.split(k_actor, config.actor_updates)
            )
            return (actor_carry, tuple(map(jnp.mean, losses))), critic_carry, c_loss

        if S:
            actor_out, (critic_params, critic_opt), c_loss = joint_update()
        elif pretrain_iters:
            actor_out = jax.lax.cond(pretraining, imitation_update, ppo_actor_update)
        else:
            actor_out = ppo_actor_update()
        (actor_params, actor_stats, actor_opt), (a_loss, clip_frac, entropy) = actor_out

        # D of Eq. 5.4 on all K·N transitions: π_old as it acted vs π_θ as it will act; then β's
        # halve/double rule.
        (new_mean, new_log_std), _ = nets.actor_forward(actor_params, actor_stats, *inputs, False)
        kl = parallel.pmean(jnp.mean(gaussian_kl(old_mean, old_log_std, new_mean, new_log_std)))
        kl_beta = state.kl_beta
        if config.objective == "kl":
            adapted = adapt_kl_beta(kl_beta, kl, config.kl_target, config.kl_beta_min, config.kl_beta_max)
            kl_beta = jnp.where(pretraining, kl_beta, adapted)

        if not (config.critic_first or S):
            (critic_params, critic_opt), c_loss = critic_update()

        # Same dtypes in as out (an env may return weak-typed metrics), so the jitted chunk never retraces.
        env_state = core.cast_like(env_state, state.env_state)
        new_state = state.replace(
            actor_params=actor_params, actor_stats=actor_stats, actor_opt=actor_opt,
            critic_params=critic_params, critic_opt=critic_opt, obs_stats=obs_stats, kl_beta=kl_beta,
            env_state=env_state, memory=memory, start_table=start_table, key=key, iteration=state.iteration + 1,
        )  # fmt: skip
        metrics = {
            "actor_loss": parallel.pmean(jnp.mean(a_loss)),
            "critic_loss": parallel.pmean(jnp.mean(c_loss)),
            "kl": kl,
            "kl_beta": kl_beta,
            "clip_fraction": parallel.pmean(jnp.mean(clip_frac)),
            "entropy": jnp.mean(entropy),
            "policy_std": parallel.pmean(jnp.mean(jnp.exp(old_log_std))),
            "value": parallel.pmean(jnp.mean(values)),
            "reward": parallel.pmean(jnp.mean(traj.reward)),
        }
        if pretrain_iters:
            metrics["pretraining"] = pretraining.astype(jnp.float32)
            metrics["search_better"] = parallel.pmean(jnp.mean((searched[1] > traj.reward).astype(jnp.float32)))
        return new_state, (metrics, on_policy.episode_sums(traj))

    def chunk(state: PPOState) -> tuple[PPOState, Metrics]:
        state, (metrics, sums) = jax.lax.scan(lambda s, _: iteration(s), state, None, length=iterations_per_update)
        return state, core.chunk_metrics(metrics, sums)

    specs = core.state_specs(PPOState, env_state=parallel.P(_LANES), memory=parallel.P(_LANES))
    update = parallel.shard_lanes(chunk, run.mesh, in_specs=(specs,), out_specs=(specs, parallel.P()))

    def acted(action: jax.Array) -> jax.Array:
        """``action`` as the env receives it: clipped or squashed (``clip_actions``, ``tanh_actions``)."""
        if config.tanh_actions:
            return jnp.tanh(action)
        return jnp.clip(action, -1.0, 1.0) if config.clip_actions else action

    def episode_start(state: PPOState) -> Any:
        """The memory one episode starts from at t = 0: the table's entry for step 0 (zeros), or ``()``."""
        return jax.tree.map(lambda x: x[0], state.start_table) if use_table else nets.memory(())

    def policy(state: PPOState) -> Policy | RecurrentPolicy:
        if config.policy == "mlp":
            return lambda obs: acted(act(state, (), obs)[1][0])

        def step(memory: Any, obs: jax.Array) -> tuple[Any, jax.Array]:
            memory, (mean, _) = act(state, memory, obs)
            return memory, acted(mean)

        return RecurrentPolicy(episode_start(state), step)

    def sample_policy(state: PPOState, key: jax.Array) -> RecurrentPolicy:
        return sampling_policy(lambda memory, obs: act(state, memory, obs), episode_start(state), key, acted)

    return run.trainer(init, update, policy, sample_policy)


make_train = core.make_train_for(make_trainer)
"""``make_train(config, env, *, mesh=None, iterations_per_update=1) -> train``: ``train(key) -> (final
PPOState, metrics [num_updates])``, the whole run, pure and jittable (vmappable over keys)."""
