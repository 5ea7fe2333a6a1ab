"""DDPG hyper-parameters: the off-policy family's (:class:`~jaxrl_robot.agents.off_policy.OffPolicyConfig`;
defaults: thesis Table 3.2, the arm with HER) and DDPG's own — the actor's output, twin critics and target
smoothing (TD3 sets them: :mod:`jaxrl_robot.agents.td3`)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Self

from jaxrl_robot.agents.ddpg.networks import OUTPUTS
from jaxrl_robot.agents.off_policy.config import ANCHORS, NOISES, PRETRAINS, SCHEDULES, OffPolicyConfig
from jaxrl_robot.validation import check_choice, check_range

__all__ = ["ANCHORS", "NOISES", "PRETRAINS", "SCHEDULES", "DDPGConfig"]


@dataclass(frozen=True)
class DDPGConfig(OffPolicyConfig):
    """DDPG (Algorithm 1) with optional prioritised replay (§3.2) and hindsight relabelling (§3.3); with
    ``twin_critics``, ``target_noise`` and ``policy_delay`` it is TD3 (thesis §6.2).  The schedules,
    replay, exploration, imitation and distributed fields are the family's (:class:`OffPolicyConfig`)."""

    actor_output: str = "tanh"
    """Actor output activation: 'tanh' (actions in [-1, 1]) or 'sigmoid' ([0, 1])."""
    target_noise: float = 0.0
    """σ of Gaussian noise added to the target actor's action in the critic target,
    ``a' = clip(μ'(s') + clip(ξ, −target_noise_clip, target_noise_clip), −1, 1)`` (target policy
    smoothing, Fujimoto et al. 2018): the target averages Q' over nearby actions, so the critic
    cannot keep narrow peaks in a that the actor would chase.  0: plain DDPG (Algorithm 1)."""
    target_noise_clip: float = 0.5
    """Bound on the target-smoothing noise (used when ``target_noise`` > 0)."""
    twin_critics: bool = False
    """Clipped double Q (TD3, thesis Eq. 6.2): two critics Q1, Q2 with their own parameters and
    targets (stacked on a leading axis of size 2 in the state), both regressed on
    ``y = r + γ (1 − d) min(Q1'(s', a'), Q2'(s', a'))``; the actor maximises Q1; PER priorities
    use the mean of ``|δ1|`` and ``|δ2|``.  The minimum counters the critic's over-estimation."""

    def validate(self) -> Self:
        """Raise ``ConfigError`` naming the first invalid field; return self."""
        super().validate()
        check_choice("actor_output", self.actor_output, OUTPUTS)
        check_range("target_noise", self.target_noise, 0.0)
        check_range("target_noise_clip", self.target_noise_clip, 0.0)
        return self
