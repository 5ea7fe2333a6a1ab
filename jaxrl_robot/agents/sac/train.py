"""SAC as a member of the off-policy family: its hyper-parameters (:class:`SACConfig`), its networks, its
temperature and its gradient steps.

>>> trainer = make_trainer(SACConfig(schedule="steps", total_steps=100_000), env)   # any unbatched brax Env
>>> state = jax.jit(trainer.init)(key)
>>> state, metrics = jax.jit(trainer.update, donate_argnums=0)(state)
>>> train = make_train(config, env)                                                  # or the whole run

One update (after brax's ``sac/train.py``, with the critic step first as the family's loop takes it):
the twin critics regress on ``y = r + γ (1 − d) (min_k Q'_k(s', a') − α log π(a'|s'))`` with ``a'``
drawn from the policy (:func:`~jaxrl_robot.agents.sac.losses.soft_value`); then — every ``policy_delay``
updates — the policy on ``mean (α log π(a|s) − min_k Q_k(s, a))`` with reparametrised draws ``a``, the
temperature on ``mean α (−log π(a|s) − H̄)`` with the same draws (``learn_alpha``), and the target critics
softly with ε.  The policy explores by sampling itself; evaluation and imitation use its mode
``tanh(loc)``.  Schedules, replay (PER, HER), random start, imitation and the distributed workers are the
family's (:mod:`jaxrl_robot.agents.off_policy`); α and its Adam state live in the state's ``extras``
(:class:`SACExtras`), so a checkpoint resumes it.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any, Self

import jax
import jax.numpy as jnp
import optax
from brax.envs.base import Env
from flax import struct

from jaxrl_robot.agents import core
from jaxrl_robot.agents.off_policy import trainer
from jaxrl_robot.agents.off_policy.config import OffPolicyConfig
from jaxrl_robot.agents.off_policy.learner import LearnerState, Update, Workers, critic_target
from jaxrl_robot.agents.off_policy.losses import anchored_actor_loss, soft_update, twin_critic_loss
from jaxrl_robot.agents.off_policy.member import Member, member_optimizers
from jaxrl_robot.agents.off_policy.networks import QCritic, critic_values, init_critics
from jaxrl_robot.agents.sac.losses import (
    SACActor,
    actor_loss,
    alpha_loss,
    gaussian_scale,
    mode,
    soft_value,
    tanh_gaussian_sample,
)
from jaxrl_robot.types import Trainer, Transition
from jaxrl_robot.validation import check_range

__all__ = ["SACConfig", "SACExtras", "make_member", "make_networks", "make_train", "make_trainer", "make_update"]


@dataclass(frozen=True)
class SACConfig(OffPolicyConfig):
    """Soft actor-critic (Haarnoja et al. 2018, "Soft Actor-Critic Algorithms and Applications"): a
    tanh-Gaussian policy maximising ``Q − α log π``, twin critics regressed on
    ``y = r + γ (1 − d) (min_k Q'_k(s', a') − α log π(a'|s'))`` with ``a' ~ π(·|s')``, and α learned so
    that the policy's entropy stays near ``target_entropy``.  The policy explores by sampling itself: the
    family's exploration-noise fields are not used.  Schedules, replay, PER, HER, imitation and the
    distributed workers are the family's."""

    init_alpha: float = 1.0
    """The temperature α at the start (brax's SAC: 1)."""
    learn_alpha: bool = True
    """Learn α (Eq. 18 of the paper) so that the policy's entropy approaches ``target_entropy``; False
    keeps ``init_alpha``."""
    alpha_lr: float = 3e-4
    """Adam learning rate of log α (brax's SAC: 3e-4)."""
    target_entropy: float | None = None
    """The entropy the temperature aims at; None: −action_size (the paper's; brax's SAC uses −action_size / 2)."""
    min_std: float = 0.001
    """The policy's σ = softplus(·) + min_std before the tanh (brax's parametrisation)."""

    def validate(self) -> Self:
        """Raise ``ConfigError`` naming the first invalid field; return self."""
        super().validate()
        check_range("init_alpha", self.init_alpha, 0.0, lo_open=True)
        check_range("alpha_lr", self.alpha_lr, 0.0, lo_open=True)
        check_range("min_std", self.min_std, 0.0, lo_open=True)
        if self.target_entropy is not None:
            check_range("target_entropy", self.target_entropy, float("-inf"), float("inf"), lo_open=True, hi_open=True)
        return self

    def entropy_target(self, action_size: int) -> float:
        """``target_entropy``, or −``action_size`` where it is None."""
        return -float(action_size) if self.target_entropy is None else float(self.target_entropy)


@struct.dataclass
class SACExtras:
    """SAC's own learned quantities in the train state (``OffPolicyState.extras``).

    Attributes:
      log_alpha: ``[]`` log of the temperature α.
      alpha_opt: its Adam state.
    """

    log_alpha: jax.Array
    alpha_opt: Any


def make_networks(config: SACConfig, action_size: int) -> tuple[SACActor, QCritic]:
    """The tanh-Gaussian actor and the (twin) critic of the configured widths."""
    actor = SACActor(action_size=action_size, hidden=tuple(config.actor_hidden))
    return actor, QCritic(hidden=tuple(config.critic_hidden))


def make_update(
    config: SACConfig, actor: SACActor, critic: QCritic, txs: tuple[optax.GradientTransformation, ...],
    target_entropy: float,
) -> Update:
    """SAC's gradient steps for the family's learner loop; ``txs = (actor, critic, temperature)`` optimisers."""
    actor_tx, critic_tx, alpha_tx = txs
    q_values = critic_values(critic, twin=True)

    def draw(params: Any, obs: jax.Array, key: jax.Array) -> tuple[jax.Array, jax.Array]:
        """Reparametrised draws ``a [N, A]`` of the policy at ``obs [N, O]`` and their ``log π(a|s) [N]``."""
        loc, raw = actor.apply(params, obs)
        return tanh_gaussian_sample(key, loc, gaussian_scale(raw, config.min_std))

    def alpha(ls: LearnerState) -> jax.Array:
        return jnp.exp(ls.extras.log_alpha)

    def critic_step(ls: LearnerState, tr: Transition, weights: jax.Array | None, key: jax.Array, workers: Workers):
        next_a, next_log_prob = draw(ls.actor_params, tr.next_obs, jax.random.split(key, 3)[1])
        next_v = soft_value(q_values(ls.target_critic_params, tr.next_obs, next_a), next_log_prob, alpha(ls))
        y = critic_target(config, tr, next_v)
        loss = lambda p: twin_critic_loss(q_values(p, tr.obs, tr.action), y, weights)  # noqa: E731
        (closs, td), grads = jax.value_and_grad(loss, has_aux=True)(ls.critic_params)
        closs, grads = workers.mean((closs, grads))
        critic_p, c_opt = core.apply_gradients(critic_tx, grads, ls.critic_opt, ls.critic_params)
        return ls.replace(critic_params=critic_p, critic_opt=c_opt), closs, td

    def a_loss(p: Any, ls: LearnerState, obs: jax.Array, key: jax.Array, anchor: Callable | None):
        a, log_prob = draw(p, obs, jax.random.split(key, 3)[2])
        q = jnp.min(q_values(ls.critic_params, obs, a), axis=0)
        if anchor is None:
            return actor_loss(q, log_prob, alpha(ls)), (q, log_prob)
        soft_q = q - jax.lax.stop_gradient(alpha(ls)) * log_prob  # TD3+BC's normalised objective on the soft Q
        bc = anchor(jax.random.fold_in(key, 1), p)
        return anchored_actor_loss(soft_q, bc, config.imitation_weight), (q, log_prob)

    def actor_step(ls: LearnerState, tr: Transition, key: jax.Array, workers: Workers, anchor: Callable | None):
        """The policy's step and, with ``learn_alpha``, the temperature's on the same draws."""
        (aloss, (q, log_prob)), grads = jax.value_and_grad(a_loss, has_aux=True)(ls.actor_params, ls, tr.obs, key,
                                                                                  anchor)  # fmt: skip
        aloss, grads = workers.mean((aloss, grads))
        actor_p, a_opt = core.apply_gradients(actor_tx, grads, ls.actor_opt, ls.actor_params)
        extras = ls.extras
        if config.learn_alpha:
            grad = workers.mean(jax.grad(alpha_loss)(extras.log_alpha, log_prob, target_entropy))
            log_alpha, alpha_opt = core.apply_gradients(alpha_tx, grad, extras.alpha_opt, extras.log_alpha)
            extras = SACExtras(log_alpha=log_alpha, alpha_opt=alpha_opt)
        return ls.replace(actor_params=actor_p, actor_opt=a_opt, extras=extras), aloss, q

    def actor_loss_only(ls: LearnerState, tr: Transition, key: jax.Array, workers: Workers, anchor: Callable | None):
        aloss, (q, _) = a_loss(ls.actor_params, ls, tr.obs, key, anchor)
        return workers.mean(aloss), q

    def targets(ls: LearnerState) -> LearnerState:
        return ls.replace(target_critic_params=soft_update(ls.target_critic_params, ls.critic_params, config.tau))

    def td_error(actor_p: Any, critic_p: Any, tr: Transition) -> jax.Array:
        """``δ [2, N]`` under one network copy (no targets, no α): ``y`` with the policy's mode at ``s'``."""
        next_q = q_values(critic_p, tr.next_obs, mode(actor.apply(actor_p, tr.next_obs)[0]))
        y = critic_target(config, tr, jnp.min(next_q, axis=0))
        return y[None] - q_values(critic_p, tr.obs, tr.action)

    return Update(
        sample_key=lambda key: jax.random.split(key, 3)[0], critic=critic_step, actor=actor_step,
        actor_loss=actor_loss_only, targets=targets, td_error=td_error,
        priority=lambda td: jnp.mean(jnp.abs(td), axis=0), extra_metrics=lambda ls: {"alpha": alpha(ls)},
    )  # fmt: skip


def make_member(config: SACConfig, action_size: int, critic_updates: int) -> Member:
    """SAC as a :class:`~jaxrl_robot.agents.off_policy.member.Member` (``critic_updates``: the run's critic
    updates, over which ``lr_end_factor`` anneals the step sizes; the actor's are that over ``policy_delay``)."""
    actor, critic = make_networks(config, action_size)
    actor_tx, critic_tx = member_optimizers(config, critic_updates)
    alpha_tx = core.make_optimizer(config.alpha_lr, 0.0)

    def init(k_actor: jax.Array, k_critic: jax.Array, obs_size: int, action_size: int) -> dict[str, Any]:
        actor_params = actor.init(k_actor, jnp.zeros((1, obs_size), jnp.float32))
        critic_params = init_critics(critic, k_critic, obs_size, action_size, twin=True)
        log_alpha = jnp.asarray(jnp.log(config.init_alpha), jnp.float32)
        return dict(actor_params=actor_params, critic_params=critic_params, target_actor_params=(),
                    target_critic_params=critic_params, actor_opt=actor_tx.init(actor_params),
                    critic_opt=critic_tx.init(critic_params),
                    extras=SACExtras(log_alpha=log_alpha, alpha_opt=alpha_tx.init(log_alpha)))  # fmt: skip

    def act(params: Any, x: jax.Array) -> jax.Array:
        return mode(actor.apply(params, x)[0])

    def sample(keys: jax.Array, params: Any, x: jax.Array) -> jax.Array:
        loc, raw = actor.apply(params, x)
        scale = gaussian_scale(raw, config.min_std)
        return jax.vmap(lambda k, m, s: tanh_gaussian_sample(k, m, s)[0])(keys, loc, scale)

    update = make_update(config, actor, critic, (actor_tx, critic_tx, alpha_tx), config.entropy_target(action_size))
    return Member(act=act, init=init, update=update, sample=sample, metric_names=("alpha",))


def make_trainer(
    config: SACConfig, env: Env, *, mesh: jax.sharding.Mesh | None = None, iterations_per_update: int | None = None
) -> Trainer:
    """Build the SAC :class:`~jaxrl_robot.types.Trainer` for ``env`` (``config.distributed``: with the
    synchronous and collecting workers of thesis §4.2); the arguments and errors are
    :func:`jaxrl_robot.agents.off_policy.make_trainer`'s."""
    return trainer.make_trainer(config, env, make_member, mesh=mesh, iterations_per_update=iterations_per_update)


make_train = core.make_train_for(make_trainer)
"""``make_train(config, env, *, mesh=None, iterations_per_update=None) -> train``: ``train(key) -> (final
state, metrics [num_updates])``, the whole run, pure and jittable."""
