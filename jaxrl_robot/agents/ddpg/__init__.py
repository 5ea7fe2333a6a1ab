"""DDPG (thesis §3.1, Algorithm 1) with prioritised (§3.2) and hindsight (§3.3) replay."""

from jaxrl_robot.agents.ddpg.config import NOISES, SCHEDULES, DDPGConfig
from jaxrl_robot.agents.ddpg.losses import actor_loss, critic_loss, smooth_target_action, soft_update, td_target
from jaxrl_robot.agents.ddpg.networks import OUTPUTS, DDPGActor, DDPGCritic
from jaxrl_robot.agents.ddpg.train import GOAL_API, DDPGState, make_networks, make_noise_for, make_train, make_trainer

__all__ = [
    "GOAL_API",
    "NOISES",
    "OUTPUTS",
    "SCHEDULES",
    "DDPGActor",
    "DDPGConfig",
    "DDPGCritic",
    "DDPGState",
    "actor_loss",
    "critic_loss",
    "make_networks",
    "make_noise_for",
    "make_train",
    "make_trainer",
    "smooth_target_action",
    "soft_update",
    "td_target",
]
