"""DDPG (thesis §3.1, Algorithm 1) — and TD3 (§6.2) — as a member of the off-policy family.

>>> trainer = make_trainer(DDPGConfig(her="future", her_k=2), env)   # any unbatched brax Env
>>> state = jax.jit(trainer.init)(key)
>>> state, metrics = jax.jit(trainer.update, donate_argnums=0)(state)   # one chunk (an epoch)
>>> train = make_train(config, env)                                  # or the whole run
>>> state, metrics = jax.jit(train)(key)

DDPG supplies its networks (:func:`make_networks`) and its gradient steps (:func:`make_update`): critic
step on ``mean w (Q(s, a) − y)²`` with ``y = r + γ (1 − d) Q'(s', μ'(s'))`` (Eq. 3.4–3.5); actor step
on ``−mean Q(s, μ(s))`` (Eq. 3.6); soft target updates with ε.  Options: twin critics with the clipped
double-Q target (Eq. 6.2), target smoothing (Eq. 6.3), the actor and targets moving every
``policy_delay`` critic updates, reward scale and shift, target clipping.  Everything else — the
schedules, acting, replay with PER and HER, the learner loop, the imitation stage and distributed DDPG
(thesis §4.2, ``config.distributed``) — is the family's (:mod:`jaxrl_robot.agents.off_policy`).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import jax
import jax.numpy as jnp
import optax
from brax.envs.base import Env

from jaxrl_robot.agents import core
from jaxrl_robot.agents.ddpg.config import DDPGConfig
from jaxrl_robot.agents.ddpg.losses import smooth_target_action
from jaxrl_robot.agents.ddpg.networks import DDPGActor, DDPGCritic
from jaxrl_robot.agents.off_policy import distributed, trainer
from jaxrl_robot.agents.off_policy import learner as family
from jaxrl_robot.agents.off_policy.learner import LearnerState, Update, Workers, critic_target
from jaxrl_robot.agents.off_policy.losses import (
    actor_loss,
    anchored_actor_loss,
    clipped_double_q,
    critic_loss,
    soft_update,
    twin_critic_loss,
)
from jaxrl_robot.agents.off_policy.member import Member, member_optimizers
from jaxrl_robot.agents.off_policy.networks import critic_values, first_critic, init_critics
from jaxrl_robot.types import RunningStats, Trainer, Transition

__all__ = ["make_distributed_trainer", "make_learner", "make_member", "make_networks", "make_train", "make_trainer",
           "make_update"]  # fmt: skip


def make_networks(config: DDPGConfig, action_size: int) -> tuple[DDPGActor, DDPGCritic]:
    """Actor and critic of the configured widths (thesis §3.4.1, §3.5.2)."""
    return (
        DDPGActor(action_size=action_size, hidden=tuple(config.actor_hidden), output=config.actor_output),
        DDPGCritic(hidden=tuple(config.critic_hidden)),
    )


def make_update(
    config: DDPGConfig, actor: DDPGActor, critic: DDPGCritic, actor_tx: optax.GradientTransformation,
    critic_tx: optax.GradientTransformation,
) -> Update:
    """DDPG's (TD3's) gradient steps for the family's learner loop."""
    twin, smoothing = config.twin_critics, config.target_noise > 0
    q_values, q_first = critic_values(critic, twin), first_critic(critic, twin)

    def target(actor_p: Any, critic_p: Any, tr: Transition, key: jax.Array | None) -> jax.Array:
        """``y [N]`` of normalised rows under the networks ``(actor_p, critic_p)`` (Eq. 3.5, 6.2, 6.3)."""
        next_a = actor.apply(actor_p, tr.next_obs)
        if key is not None:
            next_a = smooth_target_action(key, next_a, config.target_noise, config.target_noise_clip)
        if twin:
            next_q = clipped_double_q(q_values(critic_p, tr.next_obs, next_a))
        else:
            next_q = critic.apply(critic_p, tr.next_obs, next_a)
        return critic_target(config, tr, next_q)

    def sample_key(key: jax.Array) -> jax.Array:
        return jax.random.split(key)[0] if smoothing else key

    def critic_step(ls: LearnerState, tr: Transition, weights: jax.Array | None, key: jax.Array, workers: Workers):
        y = target(ls.target_actor_params, ls.target_critic_params, tr, jax.random.split(key)[1] if smoothing else None)

        def c_loss(p: Any) -> tuple[jax.Array, jax.Array]:
            if twin:
                return twin_critic_loss(q_values(p, tr.obs, tr.action), y, weights)
            return critic_loss(critic.apply(p, tr.obs, tr.action), y, weights)

        (closs, td), grads = jax.value_and_grad(c_loss, has_aux=True)(ls.critic_params)
        closs, grads = workers.mean((closs, grads))
        critic_p, c_opt = core.apply_gradients(critic_tx, grads, ls.critic_opt, ls.critic_params)
        return ls.replace(critic_params=critic_p, critic_opt=c_opt), closs, td

    def a_loss(p: Any, ls: LearnerState, obs: jax.Array, key: jax.Array, anchor: Callable | None):
        q = q_first(ls.critic_params, obs, actor.apply(p, obs))
        if anchor is None:
            return actor_loss(q), q
        return anchored_actor_loss(q, anchor(jax.random.fold_in(key, 1), p), config.imitation_weight), q

    def actor_step(ls: LearnerState, tr: Transition, key: jax.Array, workers: Workers, anchor: Callable | None):
        """Actor step on ``−mean Q1(s, μ(s))`` (with the anchor, where given)."""
        (aloss, q), grads = jax.value_and_grad(a_loss, has_aux=True)(ls.actor_params, ls, tr.obs, key, anchor)
        aloss, grads = workers.mean((aloss, grads))
        actor_p, a_opt = core.apply_gradients(actor_tx, grads, ls.actor_opt, ls.actor_params)
        return ls.replace(actor_params=actor_p, actor_opt=a_opt), aloss, q

    def actor_loss_only(ls: LearnerState, tr: Transition, key: jax.Array, workers: Workers, anchor: Callable | None):
        aloss, q = a_loss(ls.actor_params, ls, tr.obs, key, anchor)
        return workers.mean(aloss), q

    def targets(ls: LearnerState) -> LearnerState:
        return ls.replace(target_actor_params=soft_update(ls.target_actor_params, ls.actor_params, config.tau),
                          target_critic_params=soft_update(ls.target_critic_params, ls.critic_params, config.tau))

    def td_error(actor_p: Any, critic_p: Any, tr: Transition) -> jax.Array:
        """``δ = y − Q(s, a)`` from one network copy alone (a collecting worker has no targets): ``[N]``, ``[2, N]``."""
        td = target(actor_p, critic_p, tr, None)[None] - q_values(critic_p, tr.obs, tr.action)
        return td if twin else td[0]

    def priority(td: jax.Array) -> jax.Array:
        """``δ`` (its absolute value is the priority), or the mean of the twin critics' ``|δ_k|``."""
        return jnp.mean(jnp.abs(td), axis=0) if twin else td

    return Update(sample_key=sample_key, critic=critic_step, actor=actor_step, actor_loss=actor_loss_only,
                  targets=targets, td_error=td_error, priority=priority)


def make_member(config: DDPGConfig, action_size: int, critic_updates: int) -> Member:
    """DDPG as a :class:`~jaxrl_robot.agents.off_policy.member.Member` (``critic_updates``: the run's critic
    updates, over which ``lr_end_factor`` anneals the step sizes; the actor's are that over ``policy_delay``)."""
    actor, critic = make_networks(config, action_size)
    actor_tx, critic_tx = member_optimizers(config, critic_updates)

    def init(k_actor: jax.Array, k_critic: jax.Array, obs_size: int, action_size: int) -> dict[str, Any]:
        actor_params = actor.init(k_actor, jnp.zeros((1, obs_size), jnp.float32))
        critic_params = init_critics(critic, k_critic, obs_size, action_size, config.twin_critics)
        return dict(actor_params=actor_params, critic_params=critic_params, target_actor_params=actor_params,
                    target_critic_params=critic_params, actor_opt=actor_tx.init(actor_params),
                    critic_opt=critic_tx.init(critic_params), extras=())  # fmt: skip

    return Member(act=actor.apply, init=init, update=make_update(config, actor, critic, actor_tx, critic_tx))


def make_learner(
    config: DDPGConfig, actor: DDPGActor, critic: DDPGCritic, replay: Any, actor_tx: optax.GradientTransformation,
    critic_tx: optax.GradientTransformation, norm: Callable[[RunningStats, jax.Array], jax.Array], min_stored: int,
) -> family.Learner:
    """The family's :class:`~jaxrl_robot.agents.off_policy.learner.Learner` of DDPG's update on these networks."""
    update = make_update(config, actor, critic, actor_tx, critic_tx)
    return family.make_learner(config, update, replay, norm, min_stored)


def make_trainer(
    config: DDPGConfig, env: Env, *, mesh: jax.sharding.Mesh | None = None, iterations_per_update: int | None = None
) -> Trainer:
    """Build the DDPG :class:`~jaxrl_robot.types.Trainer` for ``env`` (``config.distributed``: distributed DDPG);
    the arguments and errors are :func:`jaxrl_robot.agents.off_policy.make_trainer`'s."""
    return trainer.make_trainer(config, env, make_member, mesh=mesh, iterations_per_update=iterations_per_update)


def make_distributed_trainer(config: DDPGConfig, env: Env, **options: Any) -> Trainer:
    """Distributed DDPG (thesis §4.2): :func:`jaxrl_robot.agents.off_policy.distributed.make_distributed_trainer`
    of DDPG (``options``: ``mesh``, ``iterations_per_update``)."""
    return distributed.make_distributed_trainer(config, env, make_member, **options)


make_train = core.make_train_for(make_trainer)
"""``make_train(config, env, *, mesh=None, iterations_per_update=None) -> train``: ``train(key) -> (final
state, metrics [num_updates])``, the whole run, pure and jittable (``config.distributed`` as in
:func:`make_trainer`)."""
