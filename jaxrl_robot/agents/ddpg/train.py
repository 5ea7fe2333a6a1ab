"""DDPG with prioritised and hindsight replay as a pure, jit-compiled training function.

>>> trainer = make_trainer(DDPGConfig(her="future", her_k=2), env)   # any unbatched brax Env
>>> state = jax.jit(trainer.init)(key)
>>> state, metrics = jax.jit(trainer.update, donate_argnums=0)(state)   # one chunk (an epoch)
>>> train = make_train(config, env)                                  # or the whole run
>>> state, metrics = jax.jit(train)(key)

One iteration of the ``"episodes"`` schedule (thesis §3.4.2, Algorithms 1–2): ``num_envs``
lanes each run one whole episode with ``a = μ(s) + noise`` (Eq. 3.7); every transition is
stored with its real goal and, with HER, again with each additional goal and a recomputed
reward; then ``updates_per_cycle`` updates.  The ``"steps"`` schedule (§3.5, Table 3.3)
steps auto-resetting lanes continuously and updates after every ``unroll_length`` steps.
Acting is :mod:`~jaxrl_robot.agents.ddpg.acting`, the update (Algorithm 1, lines 9–17)
:mod:`~jaxrl_robot.agents.ddpg.learner`.

With ``config.distributed`` :func:`make_trainer` builds distributed DDPG (thesis §4.2,
:mod:`~jaxrl_robot.agents.ddpg.distributed`) from the same pieces.

The replay buffer lives in the training state on the device, so a checkpoint of the state
resumes a run exactly.

Devices: the lanes (acting, env steps, exploration noise, episode bookkeeping, HER relabelling)
are split over the device mesh with ``parallel.shard_lanes``; each iteration's transitions are
gathered from every device in global lane order, so the replay memory, the observation
statistics and the learner (sampling, updates, priorities) are replicated and identical on
every device.  Per-lane randomness is keyed by *global* lane index, so a run gives the same
result on any number of devices (up to float summation order of the episode metrics).
"""

from __future__ import annotations

import functools

import jax
import jax.numpy as jnp
from brax.envs.base import Env

from jaxrl_robot import parallel
from jaxrl_robot.agents import common
from jaxrl_robot.agents.ddpg import core
from jaxrl_robot.agents.ddpg.config import DDPGConfig
from jaxrl_robot.agents.ddpg.core import DDPGState
from jaxrl_robot.agents.ddpg.distributed import make_distributed_trainer
from jaxrl_robot.agents.ddpg.learner import SINGLE
from jaxrl_robot.types import Metrics, Trainer

__all__ = ["make_train", "make_trainer"]


def make_trainer(
    config: DDPGConfig,
    env: Env,
    *,
    mesh: jax.sharding.Mesh | None = None,
    iterations_per_update: int | None = None,
) -> Trainer:
    """Build the DDPG :class:`~jaxrl_robot.types.Trainer` for ``env``.

    Args:
      config: hyper-parameters (validated here); ``config.distributed`` selects distributed DDPG.
      env: an *unbatched* env: a brax ``Env`` (brax's or ours) or a MuJoCo Playground env
        (``envs_mjx.playground.adapt``); with HER it must provide the goal-conditioned API
        (``core.GOAL_API``) and ``state.info["ee_pos"]``.
      mesh: device mesh from ``parallel.lane_mesh`` (default: all devices); the ``num_envs``
        lanes are split over it, the replay memory and the learner are replicated.
      iterations_per_update: iterations per ``update`` call (default: one epoch of
        ``cycles_per_epoch`` cycles for 'episodes', 1 for 'steps').
    Raises:
      ConfigError: invalid settings, or HER on an env without the goal API.
      ValueError: ``num_envs`` (or, distributed, the workers) do not divide over the mesh's devices.
    """
    if config.distributed:
        return make_distributed_trainer(config, env, mesh=mesh, iterations_per_update=iterations_per_update)
    s = core.setup(config, env, mesh, iterations_per_update)

    imitation = s.imitation

    def iteration(state: DDPGState, lane_ids: jax.Array) -> tuple[DDPGState, tuple]:
        """Act in this device's lanes ``lane_ids [b]``, store every device's rows, then learn (in the
        imitation stage the actor fits the expert's labels instead of maximising Q)."""
        key, k_act, k_learn, k_imitate = jax.random.split(state.key, 4)
        factor = core.noise_factor(config, state.iteration)
        imitating, teacher = None, None
        if imitation is not None:
            imitating = imitation.active(state.iteration)
            factor = jnp.where(imitating, 0.0, 1.0 if factor is None else factor)  # no noise while imitating
            teacher = imitation.teacher(lane_ids, state.iteration)
        policy = s.acting.policy(lane_ids, state.actor_params, state.obs_stats, factor, core.warming_up(config, state))
        got = s.acting.collect(k_act, lane_ids, policy, state.env_state, state.noise_state, teacher)
        rows, mask = s.acting.gather(got.rows, got.mask)
        state = core.store(s, state.replace(env_state=got.env_state, noise_state=got.noise_state), rows, mask)
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

    def chunk_fn(state: DDPGState) -> tuple[DDPGState, Metrics]:
        lane_ids = parallel.global_lane_ids(s.local_lanes)
        state, metrics, extra = core.run_chunk(s, state, lambda st: iteration(st, lane_ids))
        if imitation is not None:
            # mean over the chunk's imitation updates (NaN once the stage is over, without an anchor)
            metrics["imitation_loss"] = jnp.nanmean(extra) if extra.size else jnp.nan
        return state, metrics

    return core.make_trainer_of(s, functools.partial(core.init_state, s), chunk_fn, core.state_specs())


make_train = common.make_train_for(make_trainer)
"""``make_train(config, env, *, mesh=None, iterations_per_update=None) -> train``: ``train(key) -> (final
DDPGState, metrics [num_updates])``, the whole run, pure and jittable (``config.distributed`` as in
:func:`make_trainer`)."""
