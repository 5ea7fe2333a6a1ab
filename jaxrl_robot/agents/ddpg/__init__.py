"""DDPG (thesis §3.1, Algorithm 1) with prioritised (§3.2) and hindsight (§3.3) replay; distributed DDPG (§4.2).

A member of the off-policy family (:mod:`jaxrl_robot.agents.off_policy`): its config, networks, target
smoothing and gradient steps here, everything else shared.  TD3 is DDPG with three options set
(:mod:`jaxrl_robot.agents.td3`).
"""

from jaxrl_robot.agents.core import make_optimizer
from jaxrl_robot.agents.ddpg.config import NOISES, SCHEDULES, DDPGConfig
from jaxrl_robot.agents.ddpg.losses import smooth_target_action
from jaxrl_robot.agents.ddpg.networks import OUTPUTS, DDPGActor, DDPGCritic
from jaxrl_robot.agents.ddpg.train import (
    make_distributed_trainer,
    make_learner,
    make_member,
    make_networks,
    make_train,
    make_trainer,
)
from jaxrl_robot.agents.off_policy.acting import make_noise_for
from jaxrl_robot.agents.off_policy.distributed import Collectors
from jaxrl_robot.agents.off_policy.distributed import DistributedState as DistributedDDPGState
from jaxrl_robot.agents.off_policy.learner import SINGLE, Workers, worker_shards
from jaxrl_robot.agents.off_policy.losses import (
    actor_loss,
    anchored_actor_loss,
    clipped_double_q,
    critic_loss,
    linear_noise_factor,
    soft_update,
    td_target,
    twin_critic_loss,
)
from jaxrl_robot.agents.off_policy.trainer import GOAL_API
from jaxrl_robot.agents.off_policy.trainer import OffPolicyState as DDPGState

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
    "make_learner",
    "make_member",
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
