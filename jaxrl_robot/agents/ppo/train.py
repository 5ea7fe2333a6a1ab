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

This module builds the trainer (:func:`make_learner`, :func:`init_state`, the policies of a state);
the iteration's steps are :mod:`jaxrl_robot.agents.ppo.iteration`, those the on-policy family shares
:mod:`jaxrl_robot.agents.on_policy`.
"""

from __future__ import annotations

import math
from functools import partial
from typing import Any

import jax
import jax.numpy as jnp
from brax.envs.base import Env
from flax import struct
from jax.sharding import Mesh

from envs_mjx.base import ClipActionWrapper, TanhActionWrapper
from envs_mjx.playground import adapt
from jaxrl_robot import parallel
from jaxrl_robot.agents import core, on_policy
from jaxrl_robot.agents.ppo.config import PPOConfig
from jaxrl_robot.agents.ppo.iteration import (
    Learner,
    act,
    critic_first_order,
    iteration,
    segment_order,
    thesis_order,
    train_forward,
)
from jaxrl_robot.agents.ppo.losses import make_actor_loss
from jaxrl_robot.agents.ppo.nets import make_ppo_nets
from jaxrl_robot.agents.ppo.pretrain import make_imitation_update, model_reward_of
from jaxrl_robot.evaluation import sampling_policy
from jaxrl_robot.networks import init_running_stats
from jaxrl_robot.types import Metrics, Policy, RecurrentPolicy, RunningStats, Trainer
from jaxrl_robot.validation import ConfigError

__all__ = [
    "PPOState",
    "make_actor_loss",
    "make_learner",
    "make_networks",
    "make_train",
    "make_trainer",
    "optimizer_steps",
    "pretrain_iterations",
    "uses_start_table",
]


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
    nets = make_ppo_nets(config, action_size, bn_axis_name=parallel.LANES)
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


def make_learner(config: PPOConfig, env: Env, run: core.Setup) -> Learner:
    """The :class:`~jaxrl_robot.agents.ppo.iteration.Learner` of ``config`` on the adapted, unwrapped
    ``env`` and the run's :class:`~jaxrl_robot.agents.core.Setup` (raises ``ConfigError``)."""
    nets = make_ppo_nets(config, run.action_size, bn_axis_name=parallel.LANES)
    starts = on_policy.StartStates(nets.memory, uses_start_table(config, env), config.start_table_rate)
    pretrain_iters = pretrain_iterations(config, env)
    tables = on_policy.schedule_tables(config.schedule, env)
    iterations = run.num_updates * run.iterations_per_update
    end = on_policy.lr_end_factor(config)
    actor_steps, critic_steps = optimizer_steps(config, iterations, pretrain_iters)
    S, devices = config.advantage_segment, config.num_envs // run.local_lanes
    if S and (config.minibatch_size // S) % devices:
        raise ConfigError(f"minibatch_size={config.minibatch_size} / advantage_segment={S} segments must split "
                          f"evenly over the {devices} devices")  # fmt: skip
    per_lane = config.minibatch_size // (config.num_envs * nets.seq_length)
    forward = partial(train_forward, nets)
    imitate = None
    if pretrain_iters:
        steps = max(1, config.pretrain_epochs * config.num_envs * config.unroll_length // config.minibatch_size)
        draw = partial(on_policy.draw_sequences, seq_length=nets.seq_length, per_lane=per_lane)
        imitate = make_imitation_update(forward, draw, steps, config.pretrain_lr)
    return Learner(
        config=config,
        env=run.env,
        nets=nets,
        actor_tx=core.make_optimizer(config.actor_lr, config.max_grad_norm, end, actor_steps),
        critic_tx=core.make_optimizer(config.critic_lr, config.max_grad_norm, end, critic_steps),
        actor_loss=make_actor_loss(config, nets.actor, forward),
        starts=starts,
        tables=tables,
        schedule_len=float(iterations),
        local_lanes=run.local_lanes,
        action_size=run.action_size,
        per_lane=per_lane,
        segment_count=config.minibatch_size // (S * devices) if S else 0,
        pretrain_iters=pretrain_iters,
        model_reward=model_reward_of(env),
        imitate=imitate,
        order=segment_order if S else critic_first_order if config.critic_first else thesis_order,
    )


def init_state(learner: Learner, run: core.Setup, env: Env, key: jax.Array) -> PPOState:
    """The :class:`PPOState` a run starts from (networks of ``key``, env states over the mesh)."""
    k_actor, k_critic, k_env, k_run = jax.random.split(key, 4)
    config, nets = learner.config, learner.nets
    actor_params, actor_stats, critic_params = nets.init(k_actor, k_critic, run.obs_size)
    return PPOState(
        actor_params=actor_params,
        actor_stats=actor_stats,
        critic_params=critic_params,
        actor_opt=learner.actor_tx.init(actor_params),
        critic_opt=learner.critic_tx.init(critic_params),
        obs_stats=init_running_stats(run.obs_size),
        kl_beta=jnp.asarray(config.kl_beta, jnp.float32),
        env_state=run.reset(k_env, lambda: on_policy.initial_env_params(env, learner.tables)),
        # split over the lanes as the chunk returns it, so the chunk's second call reuses its first program
        memory=jax.lax.with_sharding_constraint(nets.memory((config.num_envs,)), parallel.lane_sharding(run.mesh)),
        start_table=learner.starts.table(env),
        key=k_run,
        iteration=jnp.zeros((), jnp.int32),
    )


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
    learner = make_learner(config, env, run)

    def chunk(state: PPOState) -> tuple[PPOState, Metrics]:
        step = partial(iteration, learner)
        state, (metrics, sums) = jax.lax.scan(lambda s, _: step(s), state, None, length=iterations_per_update)
        return state, core.chunk_metrics(metrics, sums)

    specs = core.state_specs(PPOState, env_state=parallel.P(parallel.LANES), memory=parallel.P(parallel.LANES))
    init = partial(init_state, learner, run, env)
    return run.trainer(init, run.shard(chunk, specs), partial(policy, learner), partial(sample_policy, learner))


# ---- policies of a state ------------------------------------------------------------------------
def acted(config: PPOConfig, action: jax.Array) -> jax.Array:
    """``action`` as the env receives it: clipped or squashed (``clip_actions``, ``tanh_actions``)."""
    if config.tanh_actions:
        return jnp.tanh(action)
    return jnp.clip(action, -1.0, 1.0) if config.clip_actions else action


def policy(learner: Learner, state: PPOState) -> Policy | RecurrentPolicy:
    """The deterministic policy of ``state`` (the Gaussian's mean, as the env receives it); a
    :class:`~jaxrl_robot.types.RecurrentPolicy` from the episode-start memory for policy='lstm'."""
    config = learner.config
    if config.policy == "mlp":
        return lambda obs: acted(config, act(learner, state, (), obs)[1][0])

    def step(memory: Any, obs: jax.Array) -> tuple[Any, jax.Array]:
        memory, (mean, _) = act(learner, state, memory, obs)
        return memory, acted(config, mean)

    return RecurrentPolicy(learner.starts.first(state.start_table), step)


def sample_policy(learner: Learner, state: PPOState, key: jax.Array) -> RecurrentPolicy:
    """The policy of ``state`` acting as in training (Gaussian draws), for evaluations in that mode."""
    start = learner.starts.first(state.start_table)
    return sampling_policy(partial(act, learner, state), start, key, partial(acted, learner.config))


make_train = core.make_train_for(make_trainer)
"""``make_train(config, env, *, mesh=None, iterations_per_update=1) -> train``: ``train(key) -> (final
PPOState, metrics [num_updates])``, the whole run, pure and jittable (vmappable over keys)."""
