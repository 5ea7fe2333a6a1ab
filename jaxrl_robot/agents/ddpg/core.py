"""What both DDPG trainers (single learner, distributed) are wired from.

:func:`setup` validates a configuration and builds the networks, optimisers, noise, replay,
acting (:mod:`~jaxrl_robot.agents.ddpg.acting`) and learner
(:mod:`~jaxrl_robot.agents.ddpg.learner`); :func:`init_state` draws the initial
:class:`DDPGState`; :func:`store` writes an iteration's rows into the replay; :func:`run_chunk`
runs a chunk of iterations and turns their sums into the chunk's metrics; :func:`make_trainer_of`
splits a chunk over the lanes and returns the :class:`~jaxrl_robot.types.Trainer`.  A trainer
supplies only its iteration.
"""

from __future__ import annotations

import functools
from collections.abc import Callable
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import optax
from brax.envs.base import Env, State
from flax import struct

from envs_mjx.base import default_episode_length
from envs_mjx.config import ConfigError
from envs_mjx.playground import adapt
from jaxrl_robot import parallel
from jaxrl_robot.agents.common import cast_like
from jaxrl_robot.agents.ddpg.acting import Acting, make_acting, make_noise_for
from jaxrl_robot.agents.ddpg.config import DDPGConfig
from jaxrl_robot.agents.ddpg.imitation import Imitation, make_imitation
from jaxrl_robot.agents.ddpg.learner import Learner, make_learner, make_networks, make_optimizer
from jaxrl_robot.agents.ddpg.losses import linear_noise_factor
from jaxrl_robot.agents.ddpg.networks import DDPGActor, DDPGCritic
from jaxrl_robot.networks import init_running_stats, update_running_stats
from jaxrl_robot.noise import NoiseState
from jaxrl_robot.replay import Transition, make_her, make_prioritized_replay, make_uniform_replay
from jaxrl_robot.types import Metrics, Policy, RunningStats, Trainer

__all__ = [
    "GOAL_API",
    "DDPGState",
    "Setup",
    "episode_means",
    "greedy_policy",
    "init_state",
    "make_trainer_of",
    "noise_factor",
    "run_chunk",
    "setup",
    "state_specs",
    "store",
    "warming_up",
]

GOAL_API = ("achieved_goal", "desired_goal", "compute_reward", "sample_goal", "in_feasible_region", "obs_from")


@struct.dataclass
class DDPGState:
    """Everything a DDPG run needs to continue exactly.

    Attributes:
      actor_params, critic_params: online network parameters θ^μ, θ^Q (with ``twin_critics``
        the two critics' parameters stacked on a leading axis of size 2).
      target_actor_params, target_critic_params: target parameters θ^μ', θ^Q'.
      actor_opt, critic_opt: Adam states.
      replay: uniform or prioritised replay state (stored transitions, sum-tree, β).
      env_state: ``State [B]`` of the lanes ('steps' schedule; the last cycle's for 'episodes'),
        split over devices.
      noise_state: ``NoiseState [B, A]`` of every lane, split over devices.
      obs_stats: running mean and variance of the observations (used only with ``normalize_obs``).
      key: PRNG key of the run.
      iteration: ``[] int32`` iterations (cycles or unroll phases) done.
      updates: ``[] int32`` gradient updates done.
      demos, imitation_opt: the expert's pairs and the actor's imitation Adam state
        (``pretrain='imitation'``, :mod:`~jaxrl_robot.agents.ddpg.imitation`; ``()`` otherwise).
    """

    actor_params: Any
    critic_params: Any
    target_actor_params: Any
    target_critic_params: Any
    actor_opt: Any
    critic_opt: Any
    replay: Any
    env_state: State
    noise_state: NoiseState
    obs_stats: RunningStats
    key: jax.Array
    iteration: jax.Array
    updates: jax.Array
    demos: Any
    imitation_opt: Any


class Setup(NamedTuple):
    """A validated configuration and what is built from it.

    Attributes:
      config, mesh: as given (``mesh`` defaulted to all devices).
      chunk: iterations per ``update`` call; num_updates: calls in the run.
      episode_length: T.  local_lanes: ``num_envs`` lanes per device.
      obs_size, action_size: the env's.
      actor, critic, actor_tx, critic_tx: networks and Adam optimisers.
      replay: uniform or prioritised replay (``batch_size`` per mini-batch).
      acting, learner: see :mod:`~jaxrl_robot.agents.ddpg.acting` and ``learner``.
      updates_per_iteration: ``updates_per_cycle`` ('episodes') or ``updates_per_iteration``.
      steps_per_iteration: env steps of every lane in one iteration.
      imitation: the imitation stage (``pretrain='imitation'``) or None.
    """

    config: DDPGConfig
    mesh: jax.sharding.Mesh
    chunk: int
    num_updates: int
    episode_length: int
    local_lanes: int
    obs_size: int
    action_size: int
    actor: DDPGActor
    critic: DDPGCritic
    actor_tx: optax.GradientTransformation
    critic_tx: optax.GradientTransformation
    replay: Any
    acting: Acting
    learner: Learner
    updates_per_iteration: int
    steps_per_iteration: int
    imitation: Imitation | None


def with_env_target_clip(config: DDPGConfig, env: Env) -> DDPGConfig:
    """``config`` with ``target_clip`` set from ``env.return_bounds(gamma)`` when ``clip_targets_to_env``.

    The critic's target is ``r·reward_scale + reward_shift + γ·Q'``, so the env's bounds ``[lo, hi]`` on
    the return become ``[lo·scale + min(shift, 0)/(1−γ), hi·scale + max(shift, 0)/(1−γ)]``.

    Raises:
      ConfigError: the env gives no bounds for its settings.
    """
    if not config.clip_targets_to_env:
        return config
    bounds_of = getattr(env, "return_bounds", None)
    bounds = bounds_of(config.gamma) if bounds_of is not None else None
    if bounds is None:
        raise ConfigError(
            "clip_targets_to_env=True needs an env whose return_bounds(gamma) bounds its return; this env "
            "gives none: set target_clip=(lo, hi) instead, or clip_targets_to_env=False"
        )
    shift = config.reward_shift / (1.0 - config.gamma)
    lo = bounds[0] * config.reward_scale + min(shift, 0.0)
    hi = bounds[1] * config.reward_scale + max(shift, 0.0)
    return config.replace(target_clip=(float(lo), float(hi)), clip_targets_to_env=False)


def setup(
    config: DDPGConfig, env: Env, mesh: jax.sharding.Mesh | None = None, iterations_per_update: int | None = None
) -> Setup:
    """Validate ``config`` for ``env`` and build the :class:`Setup` (see ``make_trainer`` for the arguments).

    Raises:
      ConfigError: invalid settings, HER on an env without the goal API, or a replay too small
        for one iteration's rows (of every lane, collecting workers included).
      ValueError: ``num_envs`` does not divide over the mesh's devices.
    """
    config.validate()
    env = adapt(env)
    config = with_env_target_clip(config, env)
    chunk = iterations_per_update or (config.cycles_per_epoch if config.schedule == "episodes" else 1)
    if chunk < 1:
        raise ConfigError(f"iterations_per_update={iterations_per_update} must be >= 1")
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
    T = int(config.episode_length or default_episode_length(env))
    mesh = parallel.lane_mesh() if mesh is None else mesh
    local_lanes = parallel.local_lane_count(config.num_envs, mesh)
    obs_size, action_size = int(env.observation_size), int(env.action_size)
    actor, critic = make_networks(config, action_size)
    episodes = config.schedule == "episodes"
    per_iteration = config.updates_per_cycle if episodes else config.updates_per_iteration
    critic_steps = config.iterations * per_iteration
    actor_tx = make_optimizer(config.actor_lr, config.max_grad_norm, config.lr_end_factor,
                              critic_steps // config.policy_delay)
    critic_tx = make_optimizer(config.critic_lr, config.max_grad_norm, config.lr_end_factor, critic_steps)
    her = make_her(env, config.her, config.her_k) if config.her != "none" else None
    steps = T if episodes else config.unroll_length
    rows = config.lanes * steps * (her.copies if her is not None else 1)
    if rows > config.buffer_size:
        raise ConfigError(
            f"buffer_size={config.buffer_size} is out of range; one iteration stores up to {rows} "
            "transitions, so allowed [that, inf)"
        )
    if config.per:
        replay = make_prioritized_replay(
            config.buffer_size, config.batch_size, config.alpha, config.beta0, config.beta_increment,
            priority_eps=config.priority_eps, tree=config.per_tree,
        )
    else:
        replay = make_uniform_replay(config.buffer_size, config.batch_size)
    acting = make_acting(config, env, actor, make_noise_for(config, action_size), her, T)
    learner = make_learner(config, actor, critic, replay, actor_tx, critic_tx, acting.norm,
                           max(config.batch_size, config.learning_starts))
    return Setup(
        config=config, mesh=mesh, chunk=chunk, num_updates=-(-config.iterations // chunk), episode_length=T,
        local_lanes=local_lanes, obs_size=obs_size, action_size=action_size, actor=actor, critic=critic,
        actor_tx=actor_tx, critic_tx=critic_tx, replay=replay, acting=acting, learner=learner,
        updates_per_iteration=per_iteration, steps_per_iteration=config.lanes * steps,
        imitation=make_imitation(config, env, actor, acting.norm),
    )


def init_state(s: Setup, key: jax.Array) -> DDPGState:
    """Initial :class:`DDPGState`: ``key`` splits into actor, critic, lanes and the run's key."""
    k_actor, k_critic, k_env, k_run = jax.random.split(key, 4)
    dummy_obs = jnp.zeros((1, s.obs_size), jnp.float32)
    dummy_act = jnp.zeros((1, s.action_size), jnp.float32)
    actor_params = s.actor.init(k_actor, dummy_obs)
    if s.config.twin_critics:
        critic_params = jax.vmap(lambda k: s.critic.init(k, dummy_obs, dummy_act))(jax.random.split(k_critic, 2))
    else:
        critic_params = s.critic.init(k_critic, dummy_obs, dummy_act)
    example = Transition(
        obs=jnp.zeros((s.obs_size,), jnp.float32),
        action=jnp.zeros((s.action_size,), jnp.float32),
        reward=jnp.zeros((), jnp.float32),
        next_obs=jnp.zeros((s.obs_size,), jnp.float32),
        terminated=jnp.zeros((), jnp.float32),
    )
    demos, imitation_opt = s.imitation.init(actor_params, s.obs_size, s.action_size) if s.imitation else ((), ())
    lanes = parallel.P(parallel.LANES)
    env_state, noise_state = parallel.shard_lanes(s.acting.reset, s.mesh, (lanes,), (lanes, lanes))(
        jax.random.split(k_env, s.config.num_envs)
    )
    return DDPGState(
        actor_params=actor_params,
        critic_params=critic_params,
        target_actor_params=actor_params,
        target_critic_params=critic_params,
        actor_opt=s.actor_tx.init(actor_params),
        critic_opt=s.critic_tx.init(critic_params),
        replay=s.replay.init(example),
        env_state=env_state,
        noise_state=noise_state,
        obs_stats=init_running_stats(s.obs_size),
        key=k_run,
        iteration=jnp.zeros((), jnp.int32),
        updates=jnp.zeros((), jnp.int32),
        demos=demos,
        imitation_opt=imitation_opt,
    )


def state_specs(cls: type = DDPGState, **extra: Any) -> Any:
    """``shard_lanes`` specs of a :class:`DDPGState` (or subclass ``cls`` with the ``extra`` fields' specs):
    the lanes' env and noise states split over devices, everything else replicated."""
    lanes, same = parallel.P(parallel.LANES), parallel.P()
    split = {"env_state", "noise_state"}
    specs = {name: lanes if name in split else same for name in DDPGState.__dataclass_fields__}
    return cls(**specs, **extra)


def warming_up(config: DDPGConfig, state: DDPGState) -> jax.Array | None:
    """``[]`` bool: the lanes act uniformly at random now (``random_start``, fewer than ``learning_starts``
    transitions stored); None without ``random_start``."""
    if not config.random_start:
        return None
    return state.replay.size < config.learning_starts


def noise_factor(config: DDPGConfig, iteration: jax.Array) -> jax.Array | None:
    """The exploration-noise multiplier at ``iteration`` (:func:`linear_noise_factor`); None when constant."""
    if config.noise_end_factor >= 1.0:
        return None
    return linear_noise_factor(iteration, config.iterations, config.noise_end_factor, config.noise_decay_fraction)


def store(
    s: Setup, state: DDPGState, rows: Transition, mask: jax.Array | None, priorities: jax.Array | None = None
) -> DDPGState:
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


def episode_means(sums: dict[str, jax.Array], prefix: str = "") -> Metrics:
    """Every device's episode ``sums`` (psum) -> ``episodes`` and per-episode means (NaN without episodes)."""
    sums = dict(parallel.psum(sums))
    episodes = sums.pop("episodes")
    out = {prefix + "episodes": episodes}
    for k, v in sums.items():
        out[prefix + k] = jnp.where(episodes > 0, v / jnp.maximum(episodes, 1.0), jnp.nan)
    return out


def run_chunk(s: Setup, state: DDPGState, iteration: Callable[[DDPGState], tuple]) -> tuple[DDPGState, Metrics, Any]:
    """``s.chunk`` iterations under ``lax.scan`` (inside ``shard_lanes``).

    ``iteration(state) -> (state, (loss sums, update count, episode sums, extra))`` with
    ``extra`` any pytree.  Returns the state, the metrics (means over the chunk's updates, 0
    before learning starts; episode means; replay size, updates and β) and the extras stacked
    over the chunk's iterations.
    """
    start = state
    state, (sums, count, ep, extra) = jax.lax.scan(lambda st, _: iteration(st), state, None, length=s.chunk)
    state = cast_like(state, start)  # update returns its input's dtypes: no recompilation
    n = jnp.sum(count)
    out: dict[str, jax.Array] = {k: jnp.sum(v) / jnp.maximum(n, 1.0) for k, v in sums.items()}
    out.update(episode_means(jax.tree.map(jnp.sum, ep)))
    out["replay_size"] = state.replay.size.astype(jnp.float32)
    out["updates"] = state.updates.astype(jnp.float32)
    if s.config.per:
        out["beta"] = state.replay.beta
    return state, out, extra


def greedy_policy(s: Setup, state: DDPGState) -> Policy:
    """The deterministic policy ``μ`` of ``state`` (observations normalised as in training)."""

    def greedy(obs: jax.Array) -> jax.Array:
        return s.acting.act(state.actor_params, s.acting.norm(state.obs_stats, obs))

    return greedy


def make_trainer_of(s: Setup, init: Callable[[jax.Array], DDPGState], chunk_fn: Callable, specs: Any) -> Trainer:
    """The :class:`~jaxrl_robot.types.Trainer` of a DDPG variant: ``init``, ``chunk_fn`` (state -> (state,
    metrics), one chunk) split over the lanes with the state's partition ``specs``, the greedy policy."""
    update = parallel.shard_lanes(chunk_fn, s.mesh, in_specs=(specs,), out_specs=(specs, parallel.P()))
    return Trainer(
        init=init,
        update=update,
        policy=functools.partial(greedy_policy, s),
        num_updates=s.num_updates,
        env_steps_per_update=s.steps_per_iteration * s.chunk,
    )
