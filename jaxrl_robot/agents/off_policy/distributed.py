"""Distributed off-policy training (thesis §4.2, Algorithms 4–6: distributed DDPG, and so TD3 and SAC):
synchronous and collecting workers, one shared replay.

>>> config = DDPGConfig(schedule="steps", per=True, distributed=True, sync_workers=4, collect_workers=4)
>>> trainer = make_trainer(config, env)        # jaxrl_robot.agents.ddpg.make_trainer dispatches here

The acting, the replay, the update and the losses are the single learner's
(:mod:`~jaxrl_robot.agents.off_policy.trainer`); this module adds the workers.

Where things live:

* **Synchronous workers** (Algorithm 5) are the ``m = sync_workers`` shards of the ``num_envs``
  lanes: worker ``w`` owns lanes ``[w·n, (w+1)·n)``, ``n = num_envs / m``, and the workers are
  split over the device mesh (``m / D`` per device, a vmapped local worker axis).  They act with
  the latest global parameters.  In every update each worker samples its own mini-batch of
  ``batch_size`` and computes its gradients; their mean is applied once (Algorithm 4) and every
  worker's sampled indices and new priorities are written back
  (:func:`~jaxrl_robot.agents.off_policy.learner.worker_shards`).  A worker's target networks follow
  the same global parameters as every other worker's, so one replicated set stands for all.
* **Collecting workers** (Algorithm 6): ``collect_workers`` further groups of ``collect_lanes``
  lanes, split over the devices, that only act, each with its own noise processes (and, with
  ``collect_noise_factors``, its own noise scale) and its own copy of the actor, the critic and
  the observation statistics (:class:`Collectors`).
* **Acting**: a device's synchronous and collecting lanes step as one batch
  (``collect(..., split=n)``, each lane under its own worker's policy, the two kinds' episode sums
  apart), so an iteration runs one env step per time step, as the single learner does.
* **The global networks** (Algorithm 4) and **the shared replay** are replicated: every
  iteration's rows (synchronous lanes first, then collecting lanes, each in global lane order)
  are all-gathered and added on every device, so every device holds the same memory.

Initial priorities: every worker stores its transitions with the priority ``|δ|`` (clipped,
``+ ε``) from its own networks — the synchronous workers' are the global ones, a collecting
worker's its stale copy — with ``δ = r + γ (1 − d) Q(s', μ(s')) − Q(s, a)`` (Algorithms 5–6,
line 9), instead of the single learner's largest priority.

Global sampling rule: worker ``w`` draws its mini-batch by stratified sampling over the *whole*
memory: ``[0, Σ_k p_k^α)`` is cut into ``batch_size`` equal segments, one point is drawn
uniformly in each with the key ``fold_in(k, w)``, and the slot whose interval of the prefix sums
holds the point is taken (Fig. 3.2).  A slot ``i`` is therefore expected ``batch_size · P(i)``
times in each worker's batch and ``m · batch_size · P(i)`` times per update, with
``P(i) = p_i^α / Σ_k p_k^α`` (Eq. 3.9); the workers' draws are independent given the memory.
Importance weights are normalised within each worker's batch (Eq. 3.10), as each worker
computes its gradient as DDPG does.

Staleness rule: collecting worker ``c`` (global index, ``C = collect_workers``) fetches the
global parameters at the start of every iteration ``t`` with ``(t − φ_c) mod F = 0``,
``φ_c = ⌊c·F / C⌋`` and ``F = fetch_every`` — the fetches are spread over the period as the
thesis's asynchronous processes would spread them, so the collectors act with different
policies.  A copy fetched at ``t`` acts in iterations ``t … t + F − 1`` (staleness 0 … F − 1,
reported as ``staleness_mean`` / ``staleness_max``) and is exactly ``F`` iterations old when it
is replaced; before its first fetch a worker holds the initial parameters (fetched at 0).

Metrics: the usual episode metrics are the synchronous workers' (thesis Fig. 4.17: only they
act with the global parameters); ``collect_*`` are the collecting workers'.
"""

from __future__ import annotations

import functools
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
from brax.envs.base import Env, State
from flax import struct

from jaxrl_robot import parallel
from jaxrl_robot.acting import lane_select
from jaxrl_robot.agents import core
from jaxrl_robot.agents.off_policy import trainer
from jaxrl_robot.agents.off_policy.acting import Collected, LanePolicy
from jaxrl_robot.agents.off_policy.config import OffPolicyConfig
from jaxrl_robot.agents.off_policy.learner import worker_shards
from jaxrl_robot.agents.off_policy.member import MakeMember
from jaxrl_robot.agents.off_policy.trainer import OffPolicyState
from jaxrl_robot.noise import NoiseState
from jaxrl_robot.types import Metrics, RunningStats, Trainer

__all__ = ["Collectors", "DistributedState", "fetch_phases", "make_distributed_trainer"]


@struct.dataclass
class Collectors:
    """The collecting workers, ``C`` workers of ``L`` lanes, split over devices.

    Attributes:
      env_state: ``State [C·L]`` (worker ``c`` owns lanes ``[c·L, (c+1)·L)``).
      noise_state: ``NoiseState [C·L, A]``.
      actor_params, critic_params: ``[C, ...]`` each worker's copy of θ^μ, θ^Q.
      obs_stats: ``RunningStats [C, ...]`` each worker's copy of the observation statistics.
      fetched: ``[C] int32`` the iteration at which each copy was fetched.
    """

    env_state: State
    noise_state: NoiseState
    actor_params: Any
    critic_params: Any
    obs_stats: RunningStats
    fetched: jax.Array


@struct.dataclass
class DistributedState(OffPolicyState):
    """:class:`~jaxrl_robot.agents.off_policy.trainer.OffPolicyState` (the global networks, the shared replay
    and the synchronous workers' lanes) plus ``collectors`` (:class:`Collectors`, None without collecting
    workers)."""

    collectors: Collectors | None = None


def fetch_phases(worker_ids: jax.Array, collect_workers: int, fetch_every: int) -> jax.Array:
    """``φ_c = ⌊c·F / C⌋``: collecting worker ``c`` fetches at iterations ``t ≡ φ_c (mod F)``: ``[n] -> [n]``."""
    return (worker_ids * fetch_every) // max(collect_workers, 1)


def _groups(x: jax.Array, n: int) -> jax.Array:
    """``[n·l, ...] -> [n, l, ...]``."""
    return x.reshape((n, -1) + x.shape[1:])


def _ungroup(x: jax.Array) -> jax.Array:
    """``[n, l, ...] -> [n·l, ...]``."""
    return x.reshape((-1,) + x.shape[2:])


def _split(tree: Any, n: int) -> tuple[Any, Any]:
    """``[b, ...]`` leaves ``-> ([n, ...], [b − n, ...])``."""
    return jax.tree.map(lambda x: x[:n], tree), jax.tree.map(lambda x: x[n:], tree)


def _concat(a: Any, b: Any) -> Any:
    """``[n, ...]`` and ``[m, ...]`` leaves ``-> [n + m, ...]``."""
    return jax.tree.map(lambda x, y: jnp.concatenate([x, y]), a, b)


def _split_collected(got: Collected, n: int) -> tuple[Collected, Collected]:
    """A ``collect(..., split=n)`` of ``b`` lanes as the collections of lanes ``[:n]`` and ``[n:]``."""
    lanes = (got.env_state, got.noise_state, got.rows, got.mask)
    head, tail = _split(lanes, n)
    return (Collected(*head, sums=jax.tree.map(lambda x: x[0], got.sums)),
            Collected(*tail, sums=jax.tree.map(lambda x: x[1], got.sums)))  # fmt: skip


class _Workers(NamedTuple):
    """What the functions of a distributed trainer share (static).

    Attributes:
      s: the single learner's :class:`~jaxrl_robot.agents.off_policy.trainer.Setup`.
      local_workers, local_collectors: synchronous and collecting workers per device.
      noise_factors: ``[C]`` each collecting worker's noise factor.
    """

    s: trainer.Setup
    local_workers: int
    local_collectors: int
    noise_factors: jax.Array

    @property
    def config(self) -> OffPolicyConfig:
        return self.s.config


def make_distributed_trainer(config: OffPolicyConfig, env: Env, make_member: MakeMember, **options: Any) -> Trainer:
    """The distributed :class:`~jaxrl_robot.types.Trainer` of the algorithm ``make_member``; ``options`` are
    ``trainer.make_trainer``'s keywords (``mesh``, ``iterations_per_update``), which hands distributed
    configs to this function.

    Raises:
      ConfigError: as ``make_trainer``; ``distributed`` must be set.
      ValueError: ``num_envs``, ``sync_workers`` or ``collect_workers`` do not divide over the devices.
    """
    if not config.distributed:
        raise ValueError("make_distributed_trainer needs distributed=True")
    s = trainer.setup(config, env, make_member, **options)
    devices = s.run.mesh.shape[parallel.LANES]
    for name in ("sync_workers", "collect_workers"):
        if getattr(config, name) % devices:
            raise ValueError(f"{name}={getattr(config, name)} must be a multiple of the number of devices ({devices})")
    C = config.collect_workers
    noise_factors = jnp.broadcast_to(jnp.asarray(config.collect_noise_factors or (1.0,), jnp.float32), (C,))
    w = _Workers(s, config.sync_workers // devices, C // devices, noise_factors)
    specs = trainer.state_specs(DistributedState, collectors=parallel.P(parallel.LANES) if C else None)
    return s.run.trainer(functools.partial(_init, w), s.run.shard(functools.partial(_chunk, w), specs),
                         functools.partial(trainer.greedy_policy, s))  # fmt: skip


def _copies_of(state: OffPolicyState, n: int) -> tuple:
    """The global ``(actor, critic, obs stats)`` repeated ``n`` times: ``[n, ...]`` leaves."""
    fresh = (state.actor_params, state.critic_params, state.obs_stats)
    return jax.tree.map(lambda x: jnp.broadcast_to(x, (n,) + x.shape), fresh)


def _init(w: _Workers, key: jax.Array) -> DistributedState:
    """The single learner's initial state plus the collecting workers' lanes and copies (``fold_in(key, 1)``)."""
    s, config = w.s, w.config
    base = trainer.init_state(s, key)
    fields = {name: getattr(base, name) for name in OffPolicyState.__dataclass_fields__}
    if not config.collect_workers:
        return DistributedState(**fields, collectors=None)

    def start(keys: jax.Array, state: OffPolicyState) -> Collectors:
        env_state, noise_state = s.acting.reset(keys)
        actor, critic, stats = _copies_of(state, w.local_collectors)
        return Collectors(env_state, noise_state, actor, critic, stats, jnp.zeros((w.local_collectors,), jnp.int32))

    keys = jax.random.split(jax.random.fold_in(key, 1), config.collect_workers * config.collect_lanes)
    lanes, same = parallel.P(parallel.LANES), parallel.P()
    collectors = s.run.map_lanes(start, (lanes, same), lanes)(keys, base)
    return DistributedState(**fields, collectors=collectors)


def _fetch(config: OffPolicyConfig, state: DistributedState, ids: jax.Array) -> tuple[Collectors, jax.Array]:
    """This device's collectors ``ids [c]`` after the fetches due at ``state.iteration``, and their staleness."""
    col, t, F = state.collectors, state.iteration, config.fetch_every
    due = (t - fetch_phases(ids, config.collect_workers, F)) % F == 0
    actor, critic, stats = lane_select(due, _copies_of(state, ids.shape[0]),
                                       (col.actor_params, col.critic_params, col.obs_stats))
    col = col.replace(actor_params=actor, critic_params=critic, obs_stats=stats,
                      fetched=jnp.where(due, t, col.fetched))
    return col, t - col.fetched


def _group_policy(
    w: _Workers, lane_ids: jax.Array, col: Collectors, factors: jax.Array | None, uniform: jax.Array | None
) -> LanePolicy:
    """Each collector acts in its lanes with its own copy: ``explore`` vmapped over this device's collectors."""
    n = w.local_collectors

    def policy(key: jax.Array, obs: jax.Array, nstate: NoiseState) -> tuple[jax.Array, NoiseState]:
        def one(ids, params, stats, o, ns, f):
            return w.s.acting.explore(key, ids, params, stats, o, ns, f, uniform)

        grouped = jax.tree.map(lambda x: _groups(x, n), (lane_ids, obs, nstate))
        a, nstate = jax.vmap(one)(grouped[0], col.actor_params, col.obs_stats, grouped[1], grouped[2], factors)
        return jax.tree.map(_ungroup, (a, nstate))

    return policy


def _priorities(s: trainer.Setup, copies: tuple, rows: Any, n: int) -> jax.Array:
    """Initial priorities ``[n·l, N]`` of rows ``[n·l, N]``: lane group ``g`` under the copies ``[g]``
    of ``copies = (actor, critic, stats)`` with ``[n, ...]`` leaves."""
    groups = jax.tree.map(lambda x: x.reshape((n, -1) + x.shape[2:]), rows)  # [n, l·N, ...]
    return jax.vmap(s.learner.priorities)(*copies, groups).reshape(rows.reward.shape)


def _both_policy(sync: LanePolicy, col: LanePolicy, n: int) -> LanePolicy:
    """The synchronous lanes ``[:n]`` under ``sync``, the collecting lanes ``[n:]`` under ``col``."""

    def policy(key: jax.Array, obs: jax.Array, nstate: NoiseState) -> tuple[jax.Array, NoiseState]:
        head, tail = _split((obs, nstate), n)
        return _concat(sync(key, *head), col(key, *tail))

    return policy


def _act_both(
    w: _Workers, state: DistributedState, ids: dict[str, jax.Array], k_act: jax.Array, policy: LanePolicy,
    factor: jax.Array | None, uniform: jax.Array | None,
) -> tuple[Collected, Collected, Collectors, jax.Array]:
    """Both kinds of worker step as one batch of lanes (one env step per time step, not two); lane ids, and so
    every lane's randomness, are as if each kind acted alone.  Returns the synchronous lanes' and the collecting
    lanes' :class:`Collected`, the collectors after their fetches and their staleness ``[c]``."""
    s = w.s
    col, staleness = _fetch(w.config, state, ids["collectors"])
    factors = w.noise_factors[ids["collectors"]]
    factors = factors if factor is None else factors * factor
    n = s.run.local_lanes
    both = _both_policy(policy, _group_policy(w, ids["collect_lanes"], col, factors, uniform), n)
    env_state, noise_state = _concat((state.env_state, state.noise_state), (col.env_state, col.noise_state))
    both_got = s.acting.collect(k_act, jnp.concatenate([ids["lanes"], ids["collect_lanes"]]), both,
                                env_state, noise_state, split=n)  # fmt: skip
    got, col_got = _split_collected(both_got, n)
    return got, col_got, col, staleness


def _iteration(w: _Workers, state: DistributedState, ids: dict[str, jax.Array]) -> tuple[DistributedState, tuple]:
    """Act (both kinds of worker), store every worker's rows with their priorities, then one learning phase of
    the synchronous workers; ``ids``: this device's global lane, worker and collector indices."""
    s, config = w.s, w.config
    key, k_act, k_learn = jax.random.split(state.key, 3)
    factor = trainer.noise_factor(config, state.iteration)
    uniform = trainer.warming_up(config, state)
    policy = s.acting.policy(ids["lanes"], state.actor_params, state.obs_stats, factor, uniform)
    if config.collect_workers:
        got, col_got, col, staleness = _act_both(w, state, ids, k_act, policy, factor, uniform)
    else:
        got = s.acting.collect(k_act, ids["lanes"], policy, state.env_state, state.noise_state)
    prio = _priorities(s, _copies_of(state, 1), got.rows, 1) if config.per else None
    (rows, prio), mask = s.acting.gather((got.rows, prio), got.mask)
    state = state.replace(env_state=got.env_state, noise_state=got.noise_state)
    extra = {}
    if config.collect_workers:
        copies = (col.actor_params, col.critic_params, col.obs_stats)
        col_prio = _priorities(s, copies, col_got.rows, w.local_collectors) if config.per else None
        (col_rows, col_prio), col_mask = s.acting.gather((col_got.rows, col_prio), col_got.mask)
        rows, prio, mask = _concat((rows, prio, mask), (col_rows, col_prio, col_mask))
        state = state.replace(collectors=col.replace(env_state=col_got.env_state, noise_state=col_got.noise_state))
        extra = {"episodes": col_got.sums, "staleness": parallel.all_gather(staleness)}
    state = trainer.store(s, state, rows, mask, prio)
    state, sums, count = s.learner.learn(state, k_learn, s.updates_per_iteration, worker_shards(ids["workers"]))
    state = state.replace(key=key, iteration=state.iteration + 1)
    return state, (sums, count, got.sums, extra)


def _chunk(w: _Workers, state: DistributedState) -> tuple[DistributedState, Metrics]:
    """A chunk of iterations on this device (inside ``shard_lanes``), with the collecting workers' metrics."""
    s, config = w.s, w.config
    ids = {
        "lanes": parallel.global_lane_ids(s.run.local_lanes),
        "workers": parallel.global_lane_ids(w.local_workers),
        "collectors": parallel.global_lane_ids(w.local_collectors),
        "collect_lanes": config.num_envs + parallel.global_lane_ids(w.local_collectors * config.collect_lanes),
    }
    state, metrics, extra = trainer.run_chunk(s, state, lambda st: _iteration(w, st, ids))
    if config.collect_workers:
        metrics.update(core.episode_means(jax.tree.map(jnp.sum, extra["episodes"]), "collect_"))
        staleness = extra["staleness"].astype(jnp.float32)  # [chunk, C]
        metrics["staleness_mean"] = jnp.mean(staleness)
        metrics["staleness_max"] = jnp.max(staleness)
    return state, metrics
