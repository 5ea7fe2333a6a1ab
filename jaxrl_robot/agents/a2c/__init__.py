"""A2C and A3C (thesis §4.1, Algorithm 3): n-step advantage actor-critic, synchronous or asynchronous."""

from jaxrl_robot.agents.a2c.asynchrony import (
    PushState,
    init_push_state,
    push_in_order,
    push_order,
    staleness_histogram,
)
from jaxrl_robot.agents.a2c.config import PUSH_ORDERS, A2CConfig, A3CConfig
from jaxrl_robot.agents.a2c.losses import actor_loss, critic_loss, make_worker_loss, worker_targets
from jaxrl_robot.agents.a2c.train import A2CState, A3CState, NetParams, make_networks, make_train, make_trainer

__all__ = [
    "PUSH_ORDERS",
    "A2CConfig",
    "A2CState",
    "A3CConfig",
    "A3CState",
    "NetParams",
    "PushState",
    "actor_loss",
    "critic_loss",
    "init_push_state",
    "make_worker_loss",
    "make_networks",
    "make_train",
    "make_trainer",
    "push_in_order",
    "push_order",
    "staleness_histogram",
    "worker_targets",
]
