"""DDPG (thesis §3.1, Algorithm 1) with prioritised (§3.2) and hindsight (§3.3) replay; distributed DDPG (§4.2)."""

from jaxrl_robot.agents.ddpg.acting import make_noise_for
from jaxrl_robot.agents.ddpg.config import NOISES, SCHEDULES, DDPGConfig
from jaxrl_robot.agents.ddpg.core import GOAL_API, DDPGState
from jaxrl_robot.agents.ddpg.distributed import Collectors, DistributedDDPGState, make_distributed_trainer
from jaxrl_robot.agents.ddpg.learner import SINGLE, Workers, make_networks, make_optimizer, worker_shards
from jaxrl_robot.agents.ddpg.losses import (
    actor_loss,
    anchored_actor_loss,
    clipped_double_q,
    critic_loss,
    linear_noise_factor,
    smooth_target_action,
    soft_update,
    td_target,
    twin_critic_loss,
)
from jaxrl_robot.agents.ddpg.networks import OUTPUTS, DDPGActor, DDPGCritic
from jaxrl_robot.agents.ddpg.train import make_train, make_trainer

__all__ = [
    "GOAL_API",
    "NOISES",
    "OUTPUTS",
    "SCHEDULES",
    "SINGLE",
    "Collectors",
    "DDPGActor",
    "DDPGConfig",
    "DDPGCritic",
    "DDPGState",
    "DistributedDDPGState",
    "Workers",
    "actor_loss",
    "anchored_actor_loss",
    "clipped_double_q",
    "critic_loss",
    "linear_noise_factor",
    "make_distributed_trainer",
    "make_networks",
    "make_noise_for",
    "make_optimizer",
    "make_train",
    "make_trainer",
    "smooth_target_action",
    "soft_update",
    "td_target",
    "twin_critic_loss",
    "worker_shards",
]
