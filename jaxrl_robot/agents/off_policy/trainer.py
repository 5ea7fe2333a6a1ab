"""The off-policy family's trainer: what DDPG, TD3 and SAC (single learner or distributed) are wired from.

>>> trainer = make_trainer(config, env, make_member)     # make_member: the algorithm (``ddpg``, ``sac``)
>>> state = jax.jit(trainer.init)(key)
>>> state, metrics = jax.jit(trainer.update, donate_argnums=0)(state)   # one chunk (an epoch)

An algorithm supplies a :class:`Member` — its deterministic and (optionally) stochastic policy, the
initial networks and its gradient steps (:class:`~jaxrl_robot.agents.off_policy.learner.Update`); the
family supplies everything else: :func:`setup` validates a configuration and builds the replay (uniform
or prioritised, HER), the acting (:mod:`~jaxrl_robot.agents.off_policy.acting`: schedules, exploration,
random start), the learner loop (:mod:`~jaxrl_robot.agents.off_policy.learner`) and the imitation stage
(:mod:`~jaxrl_robot.agents.off_policy.imitation`); :func:`init_state` draws the initial
:class:`OffPolicyState`; :func:`store` writes an iteration's rows into the replay; :func:`run_chunk`
runs a chunk of iterations and turns their sums into the chunk's metrics; :func:`make_trainer` builds
the single learner's :class:`~jaxrl_robot.types.Trainer` (``config.distributed``: the distributed one,
:mod:`~jaxrl_robot.agents.off_policy.distributed`).

One iteration of the ``"episodes"`` schedule (thesis §3.4.2, Algorithms 1–2): ``num_envs`` lanes each
run one whole episode with the exploring policy; every transition is stored with its real goal and, with
HER, again with each additional goal and a recomputed reward; then ``updates_per_cycle`` updates.  The
``"steps"`` schedule (§3.5, Table 3.3) steps auto-resetting lanes continuously and updates after every
``unroll_length`` steps.

Devices: the lanes (acting, env steps, exploration noise, episode bookkeeping, HER relabelling) are
split over the device mesh with ``parallel.shard_lanes``; each iteration's transitions are gathered
from every device in global lane order, so the replay memory, the observation statistics and the
learner (sampling, updates, priorities) are replicated and identical on every device.  Per-lane
randomness is keyed by *global* lane index, so a run gives the same result on any number of devices
(up to float summation order of the episode metrics).  The replay lives in the train state on the
device, so a checkpoint of the state resumes a run exactly.
"""

from __future__ import annotations

import functools
from collections.abc import Callable
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
from brax.envs.base import Env
from flax import struct

from envs_mjx.playground import adapt
from jaxrl_robot import parallel
from jaxrl_robot.agents import core
from jaxrl_robot.agents.off_policy.acting import Acting, make_acting, make_noise_for
from jaxrl_robot.agents.off_policy.config import OffPolicyConfig, with_env_target_clip
from jaxrl_robot.agents.off_policy.imitation import Imitation, make_imitation
from jaxrl_robot.agents.off_policy.learner import SINGLE, Learner, NetworkState, make_learner
from jaxrl_robot.agents.off_policy.losses import linear_noise_factor
from jaxrl_robot.agents.off_policy.member import MakeMember, Member
from jaxrl_robot.networks import init_running_stats, update_running_stats
from jaxrl_robot.noise import NoiseState
from jaxrl_robot.replay import make_her, make_prioritized_replay, make_uniform_replay
from jaxrl_robot.types import Metrics, Policy, RunningStats, Trainer, Transition
from jaxrl_robot.validation import ConfigError

__all__ = [
    "GOAL_API",
    "Member",
    "OffPolicyState",
    "Setup",
    "greedy_policy",
    "init_state",
    "make_trainer",
    "noise_factor",
    "run_chunk",
    "setup",
    "state_specs",
    "store",
    "warming_up",
]

GOAL_API = ("achieved_goal", "desired_goal", "compute_reward", "sample_goal", "in_feasible_region", "obs_from")


@struct.dataclass
class OffPolicyState(NetworkState, core.RunState):
    """Everything an off-policy run needs to continue exactly: the lanes' ``env_state`` (``'steps'``
    schedule; the last cycle's for ``'episodes'``), ``key`` and ``iteration`` (cycles or unroll phases
    done) of :class:`~jaxrl_robot.agents.core.RunState`, the networks, targets and Adam states of
    :class:`~jaxrl_robot.agents.off_policy.learner.NetworkState` (θ^μ, θ^Q, θ^μ', θ^Q'), and

    Attributes:
      replay: uniform or prioritised replay state (stored transitions, sum-tree, β).
      noise_state: ``NoiseState [B, A]`` of every lane, split over devices.
      obs_stats: running mean and variance of the observations (used only with ``normalize_obs``).
      updates: ``[] int32`` gradient updates done.
      demos, imitation_opt: the expert's pairs and the actor's imitation Adam state
        (``pretrain='imitation'``, :mod:`~jaxrl_robot.agents.off_policy.imitation`; ``()`` otherwise).
      extras: the algorithm's own learned quantities (SAC: its temperature; ``()`` for DDPG and TD3).
    """

    replay: Any
    noise_state: NoiseState
    obs_stats: RunningStats
    updates: jax.Array
    demos: Any
    imitation_opt: Any
    extras: Any = ()


class Setup(NamedTuple):
    """A validated configuration and what is built from it.

    Attributes:
      run: the run's shell (:class:`~jaxrl_robot.agents.core.Setup`: mesh, lanes per device, time limit
        ``episode_length``, obs and action sizes, ``iterations_per_update`` (the chunk), ``num_updates``,
        env steps per iteration of every lane, collecting workers' included).
      config: the validated config (``target_clip`` from the env where ``clip_targets_to_env``).
      member: the algorithm.
      replay: uniform or prioritised replay (``batch_size`` per mini-batch).
      acting, learner: see :mod:`~jaxrl_robot.agents.off_policy.acting` and ``learner``.
      updates_per_iteration: ``updates_per_cycle`` ('episodes') or ``updates_per_iteration``.
      imitation: the imitation stage (``pretrain='imitation'``) or None.
    """

    run: core.Setup
    config: OffPolicyConfig
    member: Member
    replay: Any
    acting: Acting
    learner: Learner
    updates_per_iteration: int
    imitation: Imitation | None


def _check_env(config: OffPolicyConfig, env: Env) -> None:
    """HER needs the goal API; ``termination_metric`` must be a metric of the env (``ConfigError``)."""
    if config.her != "none":
        missing = [name for name in GOAL_API if not hasattr(env, name)]
        if missing:
            raise ConfigError(f"her={config.her!r} needs the goal-conditioned env API; env lacks {', '.join(missing)}")
    if config.termination_metric:
        metrics = jax.eval_shape(env.reset, jax.random.PRNGKey(0)).metrics
        if config.termination_metric not in metrics:
            raise ConfigError(
                f"termination_metric={config.termination_metric!r} is not a metric of this env; "
                f"choose from {sorted(metrics)}"
            )


def _make_replay(config: OffPolicyConfig) -> Any:
    if config.per:
        return make_prioritized_replay(
            config.buffer_size, config.batch_size, config.alpha, config.beta0, config.beta_increment,
            priority_eps=config.priority_eps, tree=config.per_tree,
        )
    return make_uniform_replay(config.buffer_size, config.batch_size)


def setup(
    config: OffPolicyConfig, env: Env, make_member: MakeMember, mesh: jax.sharding.Mesh | None = None,
    iterations_per_update: int | None = None,
) -> Setup:
    """Validate ``config`` for ``env`` and build the :class:`Setup` (see :func:`make_trainer` for the arguments).

    Raises:
      ConfigError: invalid settings, HER on an env without the goal API, or a replay too small
        for one iteration's rows (of every lane, collecting workers included).
      ValueError: ``num_envs`` does not divide over the mesh's devices.
    """
    config.validate()
    env = adapt(env)
    config = with_env_target_clip(config, env)
    episodes = config.schedule == "episodes"
    chunk = iterations_per_update or (config.cycles_per_epoch if episodes else 1)
    _check_env(config, env)
    run = core.setup(config, env, mesh, chunk,
                     steps_per_iteration=lambda T: config.lanes * (T if episodes else config.unroll_length))
    per_iteration = config.updates_per_cycle if episodes else config.updates_per_iteration
    member = make_member(config, run.action_size, config.iterations * per_iteration)
    her = make_her(env, config.her, config.her_k) if config.her != "none" else None
    rows = run.steps_per_iteration * (her.copies if her is not None else 1)
    if rows > config.buffer_size:
        raise ConfigError(
            f"buffer_size={config.buffer_size} is out of range; one iteration stores up to {rows} "
            "transitions, so allowed [that, inf)"
        )
    replay = _make_replay(config)
    acting = make_acting(config, env, member.act, make_noise_for(config, run.action_size), her, run.episode_length,
                         sample=member.sample, batched_env=run.env)  # fmt: skip
    learner = make_learner(config, member.update, replay, acting.norm, max(config.batch_size, config.learning_starts),
                           member.metric_names)  # fmt: skip
    return Setup(run=run, config=config, member=member, replay=replay, acting=acting, learner=learner,
                 updates_per_iteration=per_iteration, imitation=make_imitation(config, env, member.act, acting.norm))


def init_state(s: Setup, key: jax.Array) -> OffPolicyState:
    """Initial :class:`OffPolicyState`: ``key`` splits into actor, critic, lanes and the run's key."""
    k_actor, k_critic, k_env, k_run = jax.random.split(key, 4)
    obs_size, action_size = s.run.obs_size, s.run.action_size
    nets = s.member.init(k_actor, k_critic, obs_size, action_size)
    example = Transition(
        obs=jnp.zeros((obs_size,), jnp.float32),
        action=jnp.zeros((action_size,), jnp.float32),
        reward=jnp.zeros((), jnp.float32),
        next_obs=jnp.zeros((obs_size,), jnp.float32),
        termination=jnp.zeros((), jnp.float32),
    )
    imitation = s.imitation.init(nets["actor_params"], obs_size, action_size) if s.imitation else ((), ())
    lanes = parallel.P(parallel.LANES)
    env_state, noise_state = s.run.map_lanes(s.acting.reset, (lanes,), (lanes, lanes))(
        jax.random.split(k_env, s.config.num_envs)
    )
    return OffPolicyState(
        **nets,
        replay=s.replay.init(example),
        env_state=env_state,
        noise_state=noise_state,
        obs_stats=init_running_stats(obs_size),
        key=k_run,
        iteration=jnp.zeros((), jnp.int32),
        updates=jnp.zeros((), jnp.int32),
        demos=imitation[0],
        imitation_opt=imitation[1],
    )


def state_specs(cls: type = OffPolicyState, **extra: Any) -> Any:
    """``shard_lanes`` specs of an :class:`OffPolicyState` (or subclass ``cls`` with the ``extra`` fields' specs):
    the lanes' env and noise states split over devices, everything else replicated."""
    lanes = parallel.P(parallel.LANES)
    return core.state_specs(cls, env_state=lanes, noise_state=lanes, **extra)


def warming_up(config: OffPolicyConfig, state: OffPolicyState) -> jax.Array | None:
    """``[]`` bool: the lanes act uniformly at random now (``random_start``, fewer than ``learning_starts``
    transitions stored); None without ``random_start``."""
    if not config.random_start:
        return None
    return state.replay.size < config.learning_starts


def noise_factor(config: OffPolicyConfig, iteration: jax.Array) -> jax.Array | None:
    """The exploration-noise multiplier at ``iteration`` (:func:`linear_noise_factor`); None when constant."""
    if config.noise_end_factor >= 1.0:
        return None
    return linear_noise_factor(iteration, config.iterations, config.noise_end_factor, config.noise_decay_fraction)


def store(
    s: Setup, state: OffPolicyState, rows: Transition, mask: jax.Array | None, priorities: jax.Array | None = None
) -> OffPolicyState:
    """Write rows ``[R]`` (where ``mask [R]``) into the replay, with raw ``priorities [R]`` (PER; default:
    the largest priority so far), and merge their observations into the statistics (``normalize_obs``)."""
    if priorities is not None and s.config.per:
        buf = s.replay.add(state.replay, rows, priorities=priorities, mask=mask)
    else:
        buf = s.replay.add(state.replay, rows, mask=mask)
    stats = state.obs_stats
    if s.config.normalize_obs:
        stats = update_running_stats(stats, rows.obs, mask=mask)
    return state.replace(replay=buf, obs_stats=stats)


def run_chunk(
    s: Setup, state: OffPolicyState, iteration: Callable[[OffPolicyState], tuple]
) -> tuple[OffPolicyState, Metrics, Any]:
    """``s.run.iterations_per_update`` iterations under ``lax.scan`` (inside ``shard_lanes``).

    ``iteration(state) -> (state, (loss sums, update count, episode sums, extra))`` with
    ``extra`` any pytree.  Returns the state, the metrics (means over the chunk's updates, 0
    before learning starts; episode means; replay size, updates and β) and the extras stacked
    over the chunk's iterations.
    """
    start = state
    state, (sums, count, ep, extra) = jax.lax.scan(lambda st, _: iteration(st), state, None,
                                                   length=s.run.iterations_per_update)  # fmt: skip
    state = core.cast_like(state, start)  # update returns its input's dtypes: no recompilation
    n = jnp.sum(count)
    out: dict[str, jax.Array] = {k: jnp.sum(v) / jnp.maximum(n, 1.0) for k, v in sums.items()}
    out.update(core.episode_means(jax.tree.map(jnp.sum, ep)))
    out["replay_size"] = state.replay.size.astype(jnp.float32)
    out["updates"] = state.updates.astype(jnp.float32)
    if s.config.per:
        out["beta"] = state.replay.beta
    return state, out, extra


def greedy_policy(s: Setup, state: OffPolicyState) -> Policy:
    """The deterministic policy of ``state`` (observations normalised as in training)."""

    def greedy(obs: jax.Array) -> jax.Array:
        return s.acting.act(state.actor_params, s.acting.norm(state.obs_stats, obs))

    return greedy


def make_trainer(
    config: OffPolicyConfig,
    env: Env,
    make_member: MakeMember,
    *,
    mesh: jax.sharding.Mesh | None = None,
    iterations_per_update: int | None = None,
) -> Trainer:
    """Build the :class:`~jaxrl_robot.types.Trainer` of the algorithm ``make_member`` for ``env``.

    Args:
      config: hyper-parameters (validated here); ``config.distributed`` selects the distributed trainer.
      env: an *unbatched* env: a brax ``Env`` (brax's or ours) or a MuJoCo Playground env
        (``envs_mjx.playground.adapt``); with HER it must provide the goal-conditioned API
        (:data:`GOAL_API`) and ``state.info["ee_pos"]``.
      make_member: ``(config, action_size, critic updates of the run) -> Member``, the algorithm.
      mesh: device mesh from ``parallel.lane_mesh`` (default: all devices); the ``num_envs``
        lanes are split over it, the replay memory and the learner are replicated.
      iterations_per_update: iterations per ``update`` call (default: one epoch of
        ``cycles_per_epoch`` cycles for 'episodes', 1 for 'steps').
    Raises:
      ConfigError: invalid settings, or HER on an env without the goal API.
      ValueError: ``num_envs`` (or, distributed, the workers) do not divide over the mesh's devices.
    """
    if config.distributed:
        from jaxrl_robot.agents.off_policy.distributed import make_distributed_trainer

        return make_distributed_trainer(config, env, make_member, mesh=mesh,
                                        iterations_per_update=iterations_per_update)
    s = setup(config, env, make_member, mesh, iterations_per_update)
    imitation = s.imitation

    def iteration(state: OffPolicyState, lane_ids: jax.Array) -> tuple[OffPolicyState, tuple]:
        """Act in this device's lanes ``lane_ids [b]``, store every device's rows, then learn (in the
        imitation stage the actor fits the expert's labels instead of learning from the critic)."""
        key, k_act, k_learn, k_imitate = jax.random.split(state.key, 4)
        factor = noise_factor(config, state.iteration)
        imitating, teacher = None, None
        if imitation is not None:
            imitating = imitation.active(state.iteration)
            factor = jnp.where(imitating, 0.0, 1.0 if factor is None else factor)  # no noise while imitating
            teacher = imitation.teacher(lane_ids, state.iteration)
        policy = s.acting.policy(lane_ids, state.actor_params, state.obs_stats, factor, warming_up(config, state))
        got = s.acting.collect(k_act, lane_ids, policy, state.env_state, state.noise_state, teacher)
        rows, mask = s.acting.gather(got.rows, got.mask)
        state = store(s, state.replace(env_state=got.env_state, noise_state=got.noise_state), rows, mask)
        extra = ()
        if imitation is not None:
            labels, _ = s.acting.gather(got.labels, None)
            actor_p, opt, demos, loss = imitation.learn(k_imitate, state.actor_params, state.imitation_opt,
                                                        state.demos, state.obs_stats, rows.obs, labels,
                                                        state.iteration)
            state = state.replace(actor_params=actor_p, imitation_opt=opt, demos=demos)
            extra = loss
        actor_on = None if imitating is None else ~imitating
        anchor = None
        if imitation is not None and imitation.anchor is not None:  # the BC term in the actor loss (TD3+BC)
            anchor = functools.partial(imitation.anchor, stats=state.obs_stats, buf=state.demos)
        state, sums, count = s.learner.learn(state, k_learn, s.updates_per_iteration, SINGLE, actor_on, anchor)
        state = state.replace(key=key, iteration=state.iteration + 1)
        return state, (sums, count, got.sums, extra)

    def chunk_fn(state: OffPolicyState) -> tuple[OffPolicyState, Metrics]:
        lane_ids = parallel.global_lane_ids(s.run.local_lanes)
        state, metrics, extra = run_chunk(s, state, lambda st: iteration(st, lane_ids))
        if imitation is not None:
            # mean over the chunk's imitation updates (NaN once the stage is over, without an anchor)
            metrics["imitation_loss"] = jnp.nanmean(extra) if extra.size else jnp.nan
        return state, metrics

    return s.run.trainer(functools.partial(init_state, s), s.run.shard(chunk_fn, state_specs()),
                         functools.partial(greedy_policy, s))  # fmt: skip

