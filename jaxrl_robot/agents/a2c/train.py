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

from functools import partial
from typing import Any

import jax
import jax.numpy as jnp
from brax.envs.base import Env
from flax import struct
from jax.sharding import Mesh

from envs_mjx.playground import adapt
from jaxrl_robot import parallel
from jaxrl_robot.agents import core, on_policy
from jaxrl_robot.agents.a2c.asynchrony import PushState, init_push_state
from jaxrl_robot.agents.a2c.config import A2CConfig, A3CConfig
from jaxrl_robot.agents.a2c.losses import make_worker_loss
from jaxrl_robot.agents.a2c.rounds import Workers, actor_dist, chunk, round_a2c, round_a3c, worker_returns
from jaxrl_robot.networks import Critic, GaussianActor
from jaxrl_robot.types import Metrics, Policy, Trainer
from jaxrl_robot.validation import ConfigError

__all__ = [
    "A2CState",
    "A3CState",
    "NetParams",
    "make_networks",
    "make_train",
    "make_trainer",
    "make_worker_loss",
    "make_workers",
]


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
    return on_policy.make_actor_critic(
        config, action_size, bn_axis_name=parallel.LANES if synchronous_update_batch else None
    )


def make_workers(config: A2CConfig, run: core.Setup) -> Workers:
    """The :class:`~jaxrl_robot.agents.a2c.rounds.Workers` of ``config`` and the run's
    :class:`~jaxrl_robot.agents.core.Setup` (raises ``ConfigError``)."""
    asynchronous = isinstance(config, A3CConfig)
    lanes_per_worker = config.lanes_per_worker if asynchronous else run.local_lanes
    if run.local_lanes % lanes_per_worker:
        raise ConfigError(
            f"lanes_per_worker={lanes_per_worker} must divide the lanes per device ({run.local_lanes} = "
            f"num_envs / {run.mesh.shape[parallel.LANES]})"
        )
    num_workers = config.num_envs // lanes_per_worker if asynchronous else 1
    actor, critic = make_networks(config, run.action_size)
    applied = run.num_updates * run.iterations_per_update * num_workers  # global updates of the whole run
    end = on_policy.lr_end_factor(config)  # "linear": annealed to 0 over the applied updates
    return Workers(
        config=config,
        env=run.env,
        actor=actor,
        critic=critic,
        worker_loss=make_worker_loss(config, actor, critic, axis_name=None if asynchronous else parallel.LANES),
        actor_tx=core.make_optimizer(config.actor_lr, config.max_grad_norm, end, applied),
        critic_tx=core.make_optimizer(config.critic_lr, config.max_grad_norm, end, applied),
        local_lanes=run.local_lanes,
        lanes_per_worker=lanes_per_worker,
        num_workers=num_workers,
    )


def init_state(w: Workers, run: core.Setup, key: jax.Array) -> A2CState | A3CState:
    """The state a run starts from: networks of ``key``, env states over the mesh; for A3C every
    worker's snapshot synced to the global parameters."""
    k_actor, k_critic, k_env, k_run = jax.random.split(key, 4)
    params = NetParams(*on_policy.init_actor_critic(k_actor, k_critic, w.actor, w.critic, run.obs_size))
    env_state = run.reset(k_env)
    actor_opt, critic_opt = w.actor_tx.init(params.actor), w.critic_tx.init(params.critic)
    zero = jnp.zeros((), jnp.int32)
    if isinstance(w.config, A3CConfig):
        push = init_push_state((params, actor_opt, critic_opt), params, w.num_workers)
        # snapshots split with their workers, as the chunk returns them: its second call reuses its first program
        split = parallel.lane_sharding(run.mesh)
        push = push.replace(snapshots=jax.lax.with_sharding_constraint(push.snapshots, split))
        return A3CState(push=push, env_state=env_state, key=k_run, iteration=zero)
    return A2CState(params, actor_opt, critic_opt, env_state=env_state, key=k_run, iteration=zero)


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
    run = core.setup(config, adapt(env), mesh, iterations_per_update)
    w = make_workers(config, run)
    lanes = parallel.P(parallel.LANES)
    if asynchronous:
        specs = core.state_specs(A3CState, push=core.state_specs(PushState, snapshots=lanes), env_state=lanes)
    else:
        specs = core.state_specs(A2CState, env_state=lanes)
    one_round = partial(round_a3c if asynchronous else round_a2c, w)
    sharded_chunk = run.map_lanes(
        partial(chunk, w, one_round, iterations_per_update), in_specs=(specs,),
        out_specs=(specs, parallel.P(), lanes, lanes),
    )  # fmt: skip

    def update(state: A2CState | A3CState) -> tuple[A2CState | A3CState, Metrics]:
        state, metrics, lane_returns, lane_episodes = sharded_chunk(state)
        return state, {
            **metrics,
            **worker_returns(lane_returns, lane_episodes, w.lanes_per_worker if asynchronous else 1),
        }

    return run.trainer(partial(init_state, w, run), update, partial(policy, w))


def policy(w: Workers, state: A2CState | A3CState) -> Policy:
    """The deterministic policy (the Gaussian's mean) of the global parameters of ``state``."""
    params = state.push.global_[0] if isinstance(w.config, A3CConfig) else state.params
    return lambda obs: actor_dist(w.actor, params, obs)[0]


make_train = core.make_train_for(make_trainer)
"""``make_train(config, env, *, mesh=None, iterations_per_update=1) -> train``: ``train(key) -> (final
A2CState | A3CState, metrics [num_updates])``, the whole run, pure and jittable (vmappable over keys)."""
