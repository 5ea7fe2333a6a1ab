"""Soft actor-critic (Haarnoja et al. 2018): twin critics, a learned temperature with a target entropy, a
tanh-Gaussian policy — a member of the off-policy family (:mod:`jaxrl_robot.agents.off_policy`), so PER,
HER, random start, imitation and the distributed workers come with it.

>>> from jaxrl_robot.agents import sac
>>> trainer = sac.make_trainer(sac.SACConfig(schedule="steps", total_steps=100_000), env)
"""

from jaxrl_robot.agents.sac.losses import (
    SACActor,
    actor_loss,
    alpha_loss,
    gaussian_scale,
    soft_value,
    tanh_gaussian_log_prob,
    tanh_gaussian_sample,
)
from jaxrl_robot.agents.sac.train import SACConfig, SACExtras, make_member, make_networks, make_train, make_trainer

__all__ = [
    "SACActor",
    "SACConfig",
    "SACExtras",
    "actor_loss",
    "alpha_loss",
    "gaussian_scale",
    "make_member",
    "make_networks",
    "make_train",
    "make_trainer",
    "soft_value",
    "tanh_gaussian_log_prob",
    "tanh_gaussian_sample",
]
