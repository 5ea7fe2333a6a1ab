"""What a member of the off-policy family supplies: a :class:`Member` (its policy, its initial networks, its
gradient steps) made by a :data:`MakeMember` (``ddpg.train.make_member``, ``sac.train.make_member``), and the
Adam pair every member's steps take (:func:`member_optimizers`).  The family wires the rest
(:mod:`~jaxrl_robot.agents.off_policy.trainer`)."""

from __future__ import annotations

from collections.abc import Callable
from typing import Any, NamedTuple

import jax

from jaxrl_robot.agents import core
from jaxrl_robot.agents.off_policy.config import OffPolicyConfig
from jaxrl_robot.agents.off_policy.learner import Update

__all__ = ["MakeMember", "Member", "member_optimizers"]


class Member(NamedTuple):
    """What an algorithm of the family supplies (``ddpg.train.make_member``, ``sac.train.make_member``).

    Attributes:
      act: ``(actor params, x [..., O]) -> action [..., A]`` in [-1, 1], deterministic (evaluation,
        imitation; with ``sample`` None, exploring as ``act + noise``).
      init: ``(key_actor, key_critic, obs_size, action_size) -> {field: value}``: the initial
        :class:`~jaxrl_robot.agents.off_policy.learner.LearnerState` fields but ``replay``.
      update: its gradient steps.
      sample: ``(keys [b], actor params, x [b, O]) -> action [b, A]``, a stochastic policy that explores
        by itself (SAC's), lane ``i`` drawing with ``keys[i]``; None: ``act`` plus the exploration noise.
      metric_names: the names of ``update.extra_metrics``.
    """

    act: Callable[[Any, jax.Array], jax.Array]
    init: Callable[[jax.Array, jax.Array, int, int], dict[str, Any]]
    update: Update
    sample: Callable[[jax.Array, Any, jax.Array], jax.Array] | None = None
    metric_names: tuple[str, ...] = ()


MakeMember = Callable[[Any, int, int], Member]
"""``(config, action_size, critic updates of the run) -> Member``."""


def member_optimizers(config: OffPolicyConfig, critic_updates: int) -> tuple[Any, Any]:
    """``(actor_tx, critic_tx)``: a member's Adam optimisers (:func:`~jaxrl_robot.agents.core.make_optimizer`),
    their step sizes annealed by ``lr_end_factor`` over the run's ``critic_updates`` (the actor's over
    ``critic_updates // policy_delay``, the updates it takes)."""
    actor_tx = core.make_optimizer(config.actor_lr, config.max_grad_norm, config.lr_end_factor,
                                   critic_updates // config.policy_delay)  # fmt: skip
    critic_tx = core.make_optimizer(config.critic_lr, config.max_grad_norm, config.lr_end_factor, critic_updates)
    return actor_tx, critic_tx
