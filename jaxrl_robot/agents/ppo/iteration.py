"""One PPO iteration (thesis Algorithms 7-8) as steps of explicit arguments, inside ``parallel.shard_lanes``
on this device's ``B`` lanes.

:func:`iteration` composes them: the lanes collect ``N`` steps (``on_policy.collect``; an LSTM's memory
per lane, new episodes from the start-state table), :func:`prepare` turns the rollout into a
:class:`Batch` (normalised observations, values, λ-return targets, π_old as it acted), the update
order chosen when the trainer is built (:attr:`Learner.order`) runs the actor and critic steps, and
:func:`adapt_beta` measures the KL divergence (Eq. 5.4) and adapts β.  The orders:

* :func:`thesis_order` — Algorithm 8: ``m`` actor steps on advantages of the critic that collected the
  data (while pre-training: the imitation update instead, :func:`actor_phase`), then ``n`` critic steps;
* :func:`critic_first_order` — the critic steps first, the advantages from the updated critic;
* :func:`segment_order` — ``advantage_segment`` S > 0: per mini-batch of whole segments, advantages and
  targets from the current critic, then one actor and one critic step (:func:`joint_step`).
"""

from __future__ import annotations

from collections.abc import Callable
from functools import partial
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import optax
from brax.envs.base import Env, State

from jaxrl_robot import parallel
from jaxrl_robot.agents import core, on_policy
from jaxrl_robot.agents.on_policy import flat, gradient_step, lane_gae, sgd_steps
from jaxrl_robot.agents.ppo.config import PPOConfig
from jaxrl_robot.agents.ppo.losses import adapt_kl_beta, value_loss
from jaxrl_robot.agents.ppo.nets import PPONets
from jaxrl_robot.agents.ppo.pretrain import action_search
from jaxrl_robot.networks import normalize, update_running_stats
from jaxrl_robot.types import Metrics, RunningStats, Transition

__all__ = [
    "Batch",
    "Learner",
    "act",
    "critic_first_order",
    "iteration",
    "segment_order",
    "thesis_order",
    "train_forward",
]


class Learner(NamedTuple):
    """The pieces of a PPO iteration fixed when the trainer is built (``ppo.train.make_learner``).

    Attributes:
      config: the validated :class:`PPOConfig`.
      env: the env wrapped for training (lanes, time limit, auto-reset).
      nets: the networks' functions (:class:`~jaxrl_robot.agents.ppo.nets.PPONets`).
      actor_tx, critic_tx: the Adam optimisers.
      actor_loss: ``ppo.make_actor_loss`` of the networks' training forward pass (:func:`train_forward`).
      starts: where a new episode's memory comes from (zeros or the start-state table).
      tables: the episode-parameter schedule (``on_policy.schedule_tables``); schedule_len: iterations of the run.
      local_lanes: B, this device's lanes; action_size: A.
      per_lane: whole sequences each lane gives a mini-batch (``B / (K · L)``).
      segment_count: segments per device in a mini-batch (``advantage_segment`` > 0; else 0).
      pretrain_iters: iterations of action-search pre-training; model_reward: the env's known
        kinematics (``env.model_reward``, None without); imitate: ``pretrain.make_imitation_update``'s
        update (None without pre-training).
      order: the update order, :func:`thesis_order`, :func:`critic_first_order` or :func:`segment_order`.
    """

    config: PPOConfig
    env: Env
    nets: PPONets
    actor_tx: optax.GradientTransformation
    critic_tx: optax.GradientTransformation
    actor_loss: Callable
    starts: on_policy.StartStates
    tables: dict
    schedule_len: float
    local_lanes: int
    action_size: int
    per_lane: int
    segment_count: int
    pretrain_iters: int
    model_reward: Callable | None
    imitate: Callable | None
    order: Callable


class Batch(NamedTuple):
    """One iteration's data on this device, ``[N, B, ...]``.

    Attributes:
      traj: the rollout's transitions as collected.
      inputs: ``(memory, reset, obs)``: the memory each step started from, where a step restarts from
        it (``on_policy.sequence_resets``), the observations normalised by the updated normaliser.
      next_obs: the successors, normalised alike.
      rewards: ``reward_scale`` times the rewards.
      values, next_values: ``V(s)``, ``V(s')`` of the critic that collected the data.
      targets: the critic's λ-return targets (Eq. 5.14).
      old: ``(mean, log_std) [N, B, A]`` of π_old exactly as it acted (moving batch-norm statistics,
        the normaliser it saw).
      searched: ``(best action [N, B, A], its reward [N, B])`` of the action search (``()`` without
        pre-training).
    """

    traj: Transition
    inputs: tuple
    next_obs: jax.Array
    rewards: jax.Array
    values: jax.Array
    next_values: jax.Array
    targets: jax.Array
    old: tuple[jax.Array, jax.Array]
    searched: Any


# ---- networks ---------------------------------------------------------------------------------
def obs_norm(config: PPOConfig, stats: RunningStats, obs: jax.Array) -> jax.Array:
    """``obs`` through the observation normaliser (unchanged unless ``normalize_obs``)."""
    return normalize(stats if config.normalize_obs else None, obs)


def act(learner: Learner, state: Any, memory: Any, obs: jax.Array) -> tuple[Any, tuple[jax.Array, jax.Array]]:
    """``(memory, (mean, log_std))`` of the acting policy of ``state`` (moving batch-norm statistics,
    normalised ``obs [B, D]``)."""
    obs = obs_norm(learner.config, state.obs_stats, obs)
    return learner.nets.act(state.actor_params, state.actor_stats, state.critic_params, memory, obs)


def train_forward(nets: PPONets, params: Any, stats: Any, inputs: tuple) -> tuple[tuple[jax.Array, jax.Array], Any]:
    """The actor in training mode on ``inputs = (memory, reset, obs) [L, B, ...]``: ``((mean, log_std)
    [L * B, A], new stats)``."""
    (mean, log_std), stats = nets.actor_forward(params, stats, *inputs, train=True)
    return (flat(mean), flat(log_std)), stats


def critic_loss(nets: PPONets, params: Any, minibatch: tuple) -> jax.Array:
    """Algorithm 8, line 14 on ``(inputs, targets) [L, B, ...]``."""
    inputs, targets = minibatch
    return value_loss(flat(nets.critic_forward(params, *inputs)[0]), flat(targets))


def values_of(nets: PPONets, critic_params: Any, inputs: tuple, next_obs: jax.Array) -> tuple[jax.Array, jax.Array]:
    """``(V(s), V(s'))`` ``[N, B]`` of a batch under ``critic_params``."""
    values, after = nets.critic_forward(critic_params, *inputs)
    return values, nets.next_values(critic_params, after, next_obs)


def draw(learner: Learner, key: jax.Array, lane_ids: jax.Array, data: Any) -> Any:
    """A mini-batch of whole sequences from every lane (``on_policy.draw_sequences``)."""
    return on_policy.draw_sequences(key, lane_ids, data, learner.nets.seq_length, learner.per_lane)


def advantages(config: PPOConfig, rewards, values, next_values, terminations, truncations) -> jax.Array:
    """GAE (Eq. 5.12) per lane, standardised over every device's lanes with ``normalize_advantages``."""
    adv = lane_gae(rewards, values, next_values, terminations, truncations, config.gamma, config.gae_lambda)
    return on_policy.standardize(adv) if config.normalize_advantages else adv


# ---- the batch ----------------------------------------------------------------------------------
def search_record(learner: Learner, pretraining: jax.Array, lane_ids: jax.Array) -> Callable | None:
    """The action search at every visited state while pre-training (Algorithm 9, lines 7-9), as
    ``on_policy.collect``'s ``record``; None without pre-training."""
    if not learner.pretrain_iters:
        return None
    config, lanes, size = learner.config, learner.local_lanes, learner.action_size

    def search(key: jax.Array, s: State) -> tuple[jax.Array, jax.Array]:
        def best() -> tuple[jax.Array, jax.Array]:
            return action_search(key, lane_ids, learner.model_reward, s, config.pretrain_candidates, size)

        def skip() -> tuple[jax.Array, jax.Array]:
            return jnp.zeros((lanes, size)), jnp.full((lanes,), -jnp.inf)

        return jax.lax.cond(pretraining, best, skip)

    return search


def prepare(learner: Learner, state: Any, rollout: on_policy.Rollout) -> tuple[Batch, RunningStats, Any]:
    """The :class:`Batch` of ``rollout``, the observation normaliser and the start-state table after it."""
    config, nets, traj = learner.config, learner.nets, rollout.traj
    reset = on_policy.sequence_resets(rollout.starts, nets.seq_length)
    start_table = on_policy.update_start_table(learner.starts, state.start_table, rollout)
    obs_stats = state.obs_stats
    if config.normalize_obs:
        obs_stats = update_running_stats(obs_stats, traj.obs, parallel.LANES)
    inputs = (rollout.memory_seq, reset, obs_norm(config, obs_stats, traj.obs))
    next_obs = obs_norm(config, obs_stats, traj.next_obs)
    rewards = traj.reward * config.reward_scale
    values, next_values = values_of(nets, state.critic_params, inputs, next_obs)
    targets = on_policy.lane_lambda_returns(
        rewards, next_values, traj.termination, traj.truncation, config.gamma, config.gae_lambda
    )
    old_inputs = (rollout.memory_seq, reset, obs_norm(config, state.obs_stats, traj.obs))
    old, _ = nets.actor_forward(state.actor_params, state.actor_stats, *old_inputs, False)
    batch = Batch(traj, inputs, next_obs, rewards, values, next_values, targets, old, rollout.record)
    return batch, obs_stats, start_table


# ---- critic and actor steps ---------------------------------------------------------------------
def critic_update(learner: Learner, key: jax.Array, lane_ids: jax.Array, params: Any, opt: Any, batch: Batch):
    """``n`` critic steps on the λ-return targets (Algorithm 8, lines 11-16): ``((params, opt), losses [n])``."""

    def step(carry: tuple, k: jax.Array) -> tuple[tuple, jax.Array]:
        params, opt = carry
        minibatch = draw(learner, k, lane_ids, (batch.inputs, batch.targets))
        loss, grads = jax.value_and_grad(partial(critic_loss, learner.nets))(params, minibatch)
        return gradient_step(learner.critic_tx, grads, opt, params), loss

    return sgd_steps(step, (params, opt), key, learner.config.critic_updates)


def actor_step(learner: Learner, lane_ids: jax.Array, batch: Batch, adv: jax.Array, kl_beta: jax.Array,
               carry: tuple, key: jax.Array) -> tuple[tuple, tuple]:  # fmt: skip
    """One actor step (Algorithm 8, lines 5-10) on a mini-batch drawn with ``key``."""
    params, stats, opt = carry
    inputs, *rest = draw(learner, key, lane_ids, (batch.inputs, batch.traj.action, adv, *batch.old))
    minibatch = (inputs, *map(flat, rest))
    grad_fn = jax.value_and_grad(learner.actor_loss, has_aux=True)
    (loss, (stats, clip_frac, entropy, _)), grads = grad_fn(params, stats, minibatch, kl_beta)
    params, opt = gradient_step(learner.actor_tx, grads, opt, params)
    return (params, stats, opt), (loss, clip_frac, entropy)


def ppo_actor_update(learner: Learner, key: jax.Array, lane_ids: jax.Array, state: Any, batch: Batch, adv: jax.Array):
    """``m`` actor steps: ``((params, stats, opt), (mean loss, mean clip fraction, mean entropy))``."""
    step = partial(actor_step, learner, lane_ids, batch, adv, state.kl_beta)
    carry = (state.actor_params, state.actor_stats, state.actor_opt)
    carry, losses = sgd_steps(step, carry, key, learner.config.actor_updates)
    return carry, tuple(map(jnp.mean, losses))


def imitation_update(learner: Learner, key: jax.Array, lane_ids: jax.Array, state: Any, batch: Batch):
    """Pre-training: the actor's mean fitted to the searched actions that beat its own (Algorithm 9);
    the same outputs as :func:`ppo_actor_update` (clip fraction 0)."""
    target, best_reward = batch.searched
    better = (best_reward > batch.traj.reward).astype(jnp.float32)
    args = (state.actor_params, state.actor_stats, batch.inputs, target, better)
    (params, stats), (loss, entropy) = learner.imitate(key, lane_ids, *args)
    return (params, stats, state.actor_opt), (loss, jnp.zeros(()), entropy)


def actor_phase(learner: Learner, key: jax.Array, lane_ids: jax.Array, state: Any, batch: Batch, adv: jax.Array,
                pretraining: jax.Array):  # fmt: skip
    """The actor's update of this iteration: PPO's steps, or the imitation update while pre-training."""
    ppo = partial(ppo_actor_update, learner, key, lane_ids, state, batch, adv)
    if not learner.pretrain_iters:
        return ppo()
    return jax.lax.cond(pretraining, partial(imitation_update, learner, key, lane_ids, state, batch), ppo)


def joint_step(learner: Learner, lane_ids: jax.Array, batch: Batch, kl_beta: jax.Array, carry: tuple,
               key: jax.Array) -> tuple[tuple, tuple]:  # fmt: skip
    """One mini-batch of whole segments: advantages and λ-returns from the current critic (Eq. 5.12,
    5.14; ``lambda_returns = gae + values``), then one actor and one critic step."""
    (a_params, a_stats, a_opt), (c_params, c_opt) = carry
    config, nets, traj = learner.config, learner.nets, batch.traj
    data = (batch.inputs, traj.action, batch.rewards, batch.next_obs, traj.termination, traj.truncation, *batch.old)
    segments = on_policy.draw_segments(key, lane_ids, data, config.advantage_segment, learner.segment_count)
    inputs, action, reward, next_obs, term, trunc, old_mean, old_log_std = segments
    v, after = nets.critic_forward(c_params, *inputs)  # [S, m]
    adv = lane_gae(reward, v, nets.next_values(c_params, after, next_obs), term, trunc, config.gamma, config.gae_lambda)
    std_adv = on_policy.standardize(adv) if config.normalize_advantages else adv
    minibatch = (inputs, *map(flat, (action, std_adv, old_mean, old_log_std)))
    grad_fn = jax.value_and_grad(learner.actor_loss, has_aux=True)
    (loss, (a_stats, clip_frac, entropy, _)), grads = grad_fn(a_params, a_stats, minibatch, kl_beta)
    a_params, a_opt = gradient_step(learner.actor_tx, grads, a_opt, a_params)
    c_loss, grads = jax.value_and_grad(partial(critic_loss, nets))(c_params, (inputs, adv + v))
    c_params, c_opt = gradient_step(learner.critic_tx, grads, c_opt, c_params)
    return ((a_params, a_stats, a_opt), (c_params, c_opt)), (loss, clip_frac, entropy, c_loss)


# ---- update orders (one chosen per trainer) -----------------------------------------------------
def thesis_order(learner: Learner, state: Any, batch: Batch, keys: tuple, lane_ids: jax.Array, pretraining):
    """Algorithm 8: the actor on advantages of the critic that collected the data, then the critic.
    ``keys = (actor key, critic key)``; returns ``(actor out, (critic params, opt), critic losses)``."""
    traj = batch.traj
    adv = advantages(learner.config, batch.rewards, batch.values, batch.next_values, traj.termination, traj.truncation)
    actor_out = actor_phase(learner, keys[0], lane_ids, state, batch, adv, pretraining)
    critic_out, c_loss = critic_update(learner, keys[1], lane_ids, state.critic_params, state.critic_opt, batch)
    return actor_out, critic_out, c_loss


def critic_first_order(learner: Learner, state: Any, batch: Batch, keys: tuple, lane_ids: jax.Array, pretraining):
    """``critic_first``: the critic learns from this batch first; the advantages then come from the
    updated critic (as :func:`thesis_order`)."""
    critic_out, c_loss = critic_update(learner, keys[1], lane_ids, state.critic_params, state.critic_opt, batch)
    values, next_values = values_of(learner.nets, critic_out[0], batch.inputs, batch.next_obs)
    traj = batch.traj
    adv = advantages(learner.config, batch.rewards, values, next_values, traj.termination, traj.truncation)
    actor_out = actor_phase(learner, keys[0], lane_ids, state, batch, adv, pretraining)
    return actor_out, critic_out, c_loss


def segment_order(learner: Learner, state: Any, batch: Batch, keys: tuple, lane_ids: jax.Array, pretraining):
    """``advantage_segment`` S > 0: ``actor_updates`` joint steps on mini-batches of whole segments
    (:func:`joint_step`), with the actor key (as :func:`thesis_order`)."""
    carry = ((state.actor_params, state.actor_stats, state.actor_opt), (state.critic_params, state.critic_opt))
    step = partial(joint_step, learner, lane_ids, batch, state.kl_beta)
    (actor_carry, critic_carry), (*losses, c_loss) = sgd_steps(step, carry, keys[0], learner.config.actor_updates)
    return (actor_carry, tuple(map(jnp.mean, losses))), critic_carry, c_loss


# ---- the iteration ------------------------------------------------------------------------------
def adapt_beta(learner: Learner, kl_beta: jax.Array, batch: Batch, actor_params: Any, actor_stats: Any,
               pretraining: jax.Array) -> tuple[jax.Array, jax.Array]:  # fmt: skip
    """``(D, β)``: D of Eq. 5.4 on all K·N transitions (π_old as it acted vs π_θ as it will act), and
    β after the halve/double rule with ``objective='kl'`` (kept while pre-training)."""
    config = learner.config
    new, _ = learner.nets.actor_forward(actor_params, actor_stats, *batch.inputs, False)
    kl = on_policy.policy_kl(batch.old, new)
    if config.objective == "kl":
        adapted = adapt_kl_beta(kl_beta, kl, config.kl_target, config.kl_beta_min, config.kl_beta_max)
        kl_beta = jnp.where(pretraining, kl_beta, adapted)
    return kl, kl_beta


def iteration_metrics(learner: Learner, batch: Batch, losses: tuple, c_loss: jax.Array, kl: jax.Array,
                      kl_beta: jax.Array, pretraining: jax.Array) -> Metrics:  # fmt: skip
    """The iteration's scalar metrics (means over every device's lanes)."""
    a_loss, clip_frac, entropy = losses
    traj, mean = batch.traj, jnp.mean
    metrics = {
        "actor_loss": parallel.pmean(mean(a_loss)),
        "critic_loss": parallel.pmean(mean(c_loss)),
        "kl": kl,
        "kl_beta": kl_beta,
        "clip_fraction": parallel.pmean(mean(clip_frac)),
        "entropy": mean(entropy),
        "policy_std": parallel.pmean(mean(jnp.exp(batch.old[1]))),
        "value": parallel.pmean(mean(batch.values)),
        "reward": parallel.pmean(mean(traj.reward)),
    }
    if learner.pretrain_iters:
        metrics["pretraining"] = pretraining.astype(jnp.float32)
        metrics["search_better"] = parallel.pmean(mean((batch.searched[1] > traj.reward).astype(jnp.float32)))
    return metrics


def iteration(learner: Learner, state: Any) -> tuple[Any, tuple[Metrics, dict[str, jax.Array]]]:
    """One iteration: ``(state, (metrics, episode sums))`` (``on_policy.episode_sums``)."""
    config = learner.config
    key, k_roll, k_actor, k_critic = jax.random.split(state.key, 4)
    lane_ids = parallel.global_lane_ids(learner.local_lanes)
    progress = state.iteration.astype(jnp.float32) / learner.schedule_len
    env_state = on_policy.apply_schedule(state.env_state, learner.tables, progress)
    pretraining = state.iteration < learner.pretrain_iters
    rollout = on_policy.collect(
        k_roll, learner.env, env_state, state.memory, state.start_table, partial(act, learner, state), lane_ids,
        config.unroll_length, learner.starts, search_record(learner, pretraining, lane_ids),
    )  # fmt: skip
    batch, obs_stats, start_table = prepare(learner, state, rollout)
    actor_out, (critic_params, critic_opt), c_loss = learner.order(
        learner, state, batch, (k_actor, k_critic), lane_ids, pretraining
    )
    (actor_params, actor_stats, actor_opt), losses = actor_out
    kl, kl_beta = adapt_beta(learner, state.kl_beta, batch, actor_params, actor_stats, pretraining)
    # Same dtypes in as out (an env may return weak-typed metrics), so the jitted chunk never retraces.
    env_state = core.cast_like(rollout.env_state, state.env_state)
    new_state = state.replace(
        actor_params=actor_params, actor_stats=actor_stats, actor_opt=actor_opt,
        critic_params=critic_params, critic_opt=critic_opt, obs_stats=obs_stats, kl_beta=kl_beta,
        env_state=env_state, memory=rollout.memory, start_table=start_table, key=key, iteration=state.iteration + 1,
    )  # fmt: skip
    metrics = iteration_metrics(learner, batch, losses, c_loss, kl, kl_beta, pretraining)
    return new_state, (metrics, on_policy.episode_sums(rollout.traj))
