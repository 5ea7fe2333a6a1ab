"""Imitation pre-training of the DDPG/TD3 actor (thesis §6.1.2, SPEC A10).

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

Then the run continues as plain DDPG or TD3 from those weights; with ``imitation_weight`` > 0 the
actor also keeps its imitation updates on the expert's labels of the states it visits, their
Adam steps scaled by that weight (a behaviour-cloning anchor between the DDPG updates).  The memory and the imitation
optimiser are part of the training state, so a resumed run continues exactly.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import optax
from brax.envs.base import Env, State

from envs_mjx.config import ConfigError
from jaxrl_robot.agents.ddpg.config import DDPGConfig
from jaxrl_robot.imitation import expert_of, imitation_loss, mix_teacher, teacher_share
from jaxrl_robot.replay import make_uniform_replay
from jaxrl_robot.types import RunningStats

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
        imitation updates; otherwise changes nothing (NaN loss).
    """

    iterations: int
    init: Callable[[Any, int, int], tuple[Any, Any]]
    active: Callable[[jax.Array], jax.Array]
    teacher: Callable[[jax.Array, jax.Array], Teacher]
    learn: Callable[..., tuple[Any, Any, Any, jax.Array]]


def make_imitation(
    config: DDPGConfig, env: Env, actor: Any, norm: Callable[[RunningStats, jax.Array], jax.Array]
) -> Imitation | None:
    """The :class:`Imitation` of ``config`` (None when ``config.pretrain == 'none'``).

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
    iterations = config.pretrain_iterations
    memory = make_uniform_replay(config.imitation_buffer, config.imitation_batch)
    tx = optax.adam(config.imitation_lr)

    def init(actor_params: Any, obs_size: int, action_size: int) -> tuple[Any, Any]:
        example = Demo(jnp.zeros((obs_size,), jnp.float32), jnp.zeros((action_size,), jnp.float32))
        return memory.init(example), tx.init(actor_params)

    def active(iteration: jax.Array) -> jax.Array:
        return iteration < iterations

    def labelling(iteration: jax.Array) -> jax.Array:
        """Whether the expert labels this iteration's states: in the stage, or always with an anchor."""
        return active(iteration) | (config.imitation_weight > 0)

    def teacher(lane_ids: jax.Array, iteration: jax.Array) -> Teacher:
        share = teacher_share(iteration, iterations, config.expert_share)

        def run(key: jax.Array, state: State, action: jax.Array) -> tuple[jax.Array, jax.Array]:
            def label(_):
                a_star = jax.vmap(expert)(state).astype(action.dtype)
                return mix_teacher(key, lane_ids, action, a_star, share), a_star

            return jax.lax.cond(labelling(iteration), label, lambda _: (action, jnp.zeros_like(action)), None)

        return run

    def update(stats: RunningStats, scale: jax.Array, carry: tuple, key: jax.Array) -> tuple[tuple, jax.Array]:
        params, opt, buf = carry
        batch = memory.sample(key, buf).experience

        def loss_fn(p):
            mean = actor.apply(p, norm(stats, batch.obs))
            ones = jnp.ones(batch.obs.shape[:1], jnp.float32)
            return imitation_loss(mean, batch.action, ones, jnp.asarray(ones.shape[0], jnp.float32))

        loss, grads = jax.value_and_grad(loss_fn)(params)
        updates, opt = tx.update(grads, opt, params)
        updates = jax.tree.map(lambda u: scale * u, updates)
        return (optax.apply_updates(params, updates), opt, buf), loss

    def learn(key, params, opt, buf, stats, obs, labels, iteration):
        scale = jnp.where(active(iteration), 1.0, config.imitation_weight).astype(jnp.float32)

        def run(args):
            params, opt, buf = args
            buf = memory.add(buf, Demo(obs, labels))
            keys = jax.random.split(key, config.imitation_updates)
            (params, opt, buf), loss = jax.lax.scan(lambda c, k: update(stats, scale, c, k), (params, opt, buf), keys)
            return params, opt, buf, jnp.mean(loss)

        skip = (params, opt, buf, jnp.full((), jnp.nan, jnp.float32))
        return jax.lax.cond(labelling(iteration), run, lambda args: skip, (params, opt, buf))

    return Imitation(iterations=iterations, init=init, active=active, teacher=teacher, learn=learn)
