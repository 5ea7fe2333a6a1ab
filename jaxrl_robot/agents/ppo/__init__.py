"""Distributed PPO with GAE (thesis ch. 5): clipped (Eq. 5.5) or adaptive-KL (Eq. 5.3-5.4) objective."""

from jaxrl_robot.agents.ppo.config import OBJECTIVES, PPOConfig
from jaxrl_robot.agents.ppo.losses import (
    adapt_kl_beta,
    clipped_surrogate_loss,
    kl_penalty_loss,
    make_actor_loss,
    value_loss,
)
from jaxrl_robot.agents.ppo.train import PPOState, make_networks, make_train, make_trainer, optimizer_steps

__all__ = [
    "OBJECTIVES",
    "PPOConfig",
    "PPOState",
    "adapt_kl_beta",
    "clipped_surrogate_loss",
    "kl_penalty_loss",
    "make_actor_loss",
    "make_networks",
    "make_train",
    "make_trainer",
    "optimizer_steps",
    "value_loss",
]
