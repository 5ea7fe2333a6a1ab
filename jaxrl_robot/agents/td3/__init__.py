"""TD3 (thesis §6.2, Eq. 6.2–6.3): DDPG (:mod:`jaxrl_robot.agents.ddpg`) with three of its options set.

Two critics regressed on the clipped double-Q target ``y = r + γ (1 − d) min(Q1'(s', a'), Q2'(s', a'))``
(Eq. 6.2), the target action smoothed as ``a' = clip(μ'(s') + clip(ξ, −0.5, 0.5), −1, 1)`` with
``ξ ~ N(0, 0.2²)`` (Eq. 6.3), and the actor (which maximises Q1) and the target networks updated once
every 2 critic updates.  The trainer is DDPG's:

>>> config = td3_config(schedule="steps", total_steps=100_000)    # a DDPGConfig with TD3_SETTINGS
>>> trainer = make_trainer(config, env)
"""

from __future__ import annotations

from typing import Any

from jaxrl_robot.agents.ddpg import DDPGConfig, make_train, make_trainer

__all__ = ["TD3_SETTINGS", "make_train", "make_trainer", "td3_config"]

TD3_SETTINGS: dict[str, Any] = dict(twin_critics=True, target_noise=0.2, target_noise_clip=0.5, policy_delay=2)
"""The :class:`~jaxrl_robot.agents.ddpg.DDPGConfig` fields that make TD3 (Eq. 6.2, Eq. 6.3, delayed actor
and targets)."""


def td3_config(base: DDPGConfig | None = None, **changes: Any) -> DDPGConfig:
    """``base`` (default ``DDPGConfig()``) with :data:`TD3_SETTINGS`, then ``changes``."""
    return (base or DDPGConfig()).replace(**TD3_SETTINGS).replace(**changes)
