"""Imitation pre-training of an off-policy actor (DDPG, TD3, SAC; thesis §6.1.2).

For the first ``config.pretrain_iterations`` iterations of a run:

* the lanes act with the actor's own action, no exploration noise (or, with probability
  ``expert_share`` falling to 0 over the stage, the expert's: DAgger's β), and every visited
  state is labelled with the env's expert action ``a* = env.expert(state)``;
* the pairs ``(s, a*)`` go into a ring memory of the latest ``imitation_buffer`` pairs
  (:class:`Demo`), and the actor takes ``imitation_updates`` Adam steps on
  ``mean ‖μ(s) − a*‖²`` (:func:`jaxrl_robot.imitation.imitation_loss`) over mini-batches of
  ``imitation_batch`` pairs drawn uniformly from it;
* the transitions go into the replay and the critic(s) learn from them as in DDPG, the target
  networks following the imitating actor (``Learner.learn(..., actor_on=False)``).

Then the run continues as plain DDPG, TD3 or SAC from those weights; with ``imitation_weight`` > 0 the
expert goes on labelling the visited states and the actor stays anchored to its labels: with
``imitation_anchor='steps'`` it keeps its imitation updates, their Adam steps scaled by that weight
(a behaviour-cloning anchor between the DDPG updates); with ``'loss'`` the updates stop and the
actor loss takes a behaviour-cloning term on the memory instead (:attr:`Imitation.anchor`,
TD3+BC's objective).  The memory and the imitation optimiser are part of the training state, so a
resumed run continues exactly.
"""

from __future__ import annotations

import functools
from collections.abc import Callable
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import optax
from brax.envs.base import Env, State

from jaxrl_robot.agents.off_policy.config import OffPolicyConfig
from jaxrl_robot.imitation import expert_of, imitation_loss, mix_teacher, teacher_share
from jaxrl_robot.replay import make_uniform_replay
from jaxrl_robot.types import RunningStats
from jaxrl_robot.validation import ConfigError

__all__ = ["Demo", "Imitation", "make_imitation"]


class Demo(NamedTuple):
    """A pair of the expert's: raw observation ``obs [..., O]`` and its action ``action [..., A]``."""

    obs: jax.Array
    action: jax.Array


Teacher = Callable[[jax.Array, State, jax.Array], tuple[jax.Array, jax.Array]]
"""``(key, State [b], action [b, A]) -> (executed action [b, A], expert label [b, A])``."""


class Imitation(NamedTuple):
    """The imitation stage of one configuration.

    Attributes:
      iterations: iterations of the stage.
      init: ``(actor params, obs_size, action_size) -> (memory, optimiser state)``.
      active: ``iteration [] -> bool []``, whether ``iteration`` is in the stage.
      teacher: ``(lane_ids [b], iteration []) -> Teacher`` for one device's lanes: labels the
        states with the expert's action and executes it with probability β(iteration) while in
        the stage; outside it returns the action unchanged and zero labels (the expert is not run).
      learn: ``(key, actor params, optimiser state, memory, obs stats, obs [R], labels [R], iteration [])
        -> (actor params, optimiser state, memory, loss [])``: in the stage (or after it, with
        ``imitation_weight`` > 0, the steps scaled by it) stores the pairs and takes the actor's
        imitation updates; after the stage with ``imitation_anchor='loss'`` only stores the pairs;
        otherwise changes nothing (NaN loss when no update was taken).
      anchor: with ``imitation_anchor='loss'`` and ``imitation_weight`` > 0, ``(key, actor params, obs
        stats, memory) -> []``: the imitation loss of the actor on a mini-batch of ``imitation_batch``
        pairs drawn from the memory with ``key``, the term the actor loss adds (else None).
    """

    iterations: int
    init: Callable[[Any, int, int], tuple[Any, Any]]
    active: Callable[[jax.Array], jax.Array]
    teacher: Callable[[jax.Array, jax.Array], Teacher]
    learn: Callable[..., tuple[Any, Any, Any, jax.Array]]
    anchor: Callable[..., jax.Array] | None = None


class _Stage(NamedTuple):
    """What the functions of the imitation stage share (static): the config, the env's expert
    (``State -> a*``), the pairs' memory, the imitation optimiser, the actor's ``act`` and ``norm``."""

    config: OffPolicyConfig
    expert: Callable[[State], jax.Array]
    memory: Any
    tx: optax.GradientTransformation
    act: Callable[[Any, jax.Array], jax.Array]
    norm: Callable[[RunningStats, jax.Array], jax.Array]


def make_imitation(
    config: OffPolicyConfig, env: Env, act: Callable[[Any, jax.Array], jax.Array],
    norm: Callable[[RunningStats, jax.Array], jax.Array],
) -> Imitation | None:
    """The :class:`Imitation` of ``config`` (None when ``config.pretrain == 'none'``); ``act(params, x)``:
    the actor's deterministic action, which imitates.

    Raises:
      ConfigError: ``pretrain='imitation'`` on an env without ``expert``.
    """
    if config.pretrain == "none":
        return None
    expert = expert_of(env)
    if expert is None:
        raise ConfigError(
            f"pretrain={config.pretrain!r} needs an env with an expert (env.expert(state) -> action); "
            f"{type(env).__name__} has none: use pretrain='none'"
        )
    memory = make_uniform_replay(config.imitation_buffer, config.imitation_batch)
    stage = _Stage(config, expert, memory, optax.adam(config.imitation_lr), act, norm)
    return Imitation(
        iterations=config.pretrain_iterations,
        init=functools.partial(_init, stage),
        active=functools.partial(_active, config),
        teacher=functools.partial(_teacher, stage),
        learn=functools.partial(_learn, stage),
        anchor=functools.partial(_demo_loss, stage) if _anchor_in_loss(config) else None,
    )


def _init(stage: _Stage, actor_params: Any, obs_size: int, action_size: int) -> tuple[Any, Any]:
    """An empty memory of pairs and the imitation optimiser's state."""
    example = Demo(jnp.zeros((obs_size,), jnp.float32), jnp.zeros((action_size,), jnp.float32))
    return stage.memory.init(example), stage.tx.init(actor_params)


def _active(config: OffPolicyConfig, iteration: jax.Array) -> jax.Array:
    """``[]`` bool: ``iteration`` is in the stage."""
    return iteration < config.pretrain_iterations


def _anchor_in_loss(config: OffPolicyConfig) -> bool:
    """After the stage the actor's loss takes the behaviour-cloning term (``imitation_anchor='loss'``, a weight)."""
    return config.imitation_anchor == "loss" and config.imitation_weight > 0


def _labelling(config: OffPolicyConfig, iteration: jax.Array) -> jax.Array:
    """Whether the expert labels this iteration's states: in the stage, or always with an anchor."""
    return _active(config, iteration) | (config.imitation_weight > 0)


def _teacher(stage: _Stage, lane_ids: jax.Array, iteration: jax.Array) -> Teacher:
    """:attr:`Imitation.teacher`."""
    config = stage.config
    share = teacher_share(iteration, config.pretrain_iterations, config.expert_share)

    def run(key: jax.Array, state: State, action: jax.Array) -> tuple[jax.Array, jax.Array]:
        def label(_):
            a_star = jax.vmap(stage.expert)(state).astype(action.dtype)
            return mix_teacher(key, lane_ids, action, a_star, share), a_star

        return jax.lax.cond(_labelling(config, iteration), label, lambda _: (action, jnp.zeros_like(action)), None)

    return run


def _demo_loss(stage: _Stage, key: jax.Array, params: Any, stats: RunningStats, buf: Any) -> jax.Array:
    """The actor's imitation loss on ``imitation_batch`` pairs drawn from ``buf`` with ``key``."""
    batch = stage.memory.sample(key, buf).experience
    mean = stage.act(params, stage.norm(stats, batch.obs))
    ones = jnp.ones(batch.obs.shape[:1], jnp.float32)
    return imitation_loss(mean, batch.action, ones, jnp.asarray(ones.shape[0], jnp.float32))


def _update(
    stage: _Stage, stats: RunningStats, scale: jax.Array, carry: tuple, key: jax.Array
) -> tuple[tuple, jax.Array]:
    """One imitation step of the actor, ``carry = (params, optimiser state, memory)``, its Adam step times ``scale``."""
    params, opt, buf = carry
    loss, grads = jax.value_and_grad(lambda p: _demo_loss(stage, key, p, stats, buf))(params)
    updates, opt = stage.tx.update(grads, opt, params)
    updates = jax.tree.map(lambda u: scale * u, updates)
    return (optax.apply_updates(params, updates), opt, buf), loss


def _learn(stage: _Stage, key, params, opt, buf, stats, obs, labels, iteration):
    """:attr:`Imitation.learn`."""
    config = stage.config
    scale = jnp.where(_active(config, iteration), 1.0, config.imitation_weight).astype(jnp.float32)
    nan = jnp.full((), jnp.nan, jnp.float32)

    def run(args):
        params, opt, buf = args
        buf = stage.memory.add(buf, Demo(obs, labels))
        keys = jax.random.split(key, config.imitation_updates)
        step = functools.partial(_update, stage, stats, scale)
        (params, opt, buf), loss = jax.lax.scan(step, (params, opt, buf), keys)
        return params, opt, buf, jnp.mean(loss)

    def store(args):
        """After the stage with the anchor in the DDPG loss: the pairs only."""
        params, opt, buf = args
        return params, opt, stage.memory.add(buf, Demo(obs, labels)), nan

    def labelled(args):
        return jax.lax.cond(_active(config, iteration), run, store, args) if _anchor_in_loss(config) else run(args)

    return jax.lax.cond(_labelling(config, iteration), labelled, lambda args: (*args, nan), (params, opt, buf))
