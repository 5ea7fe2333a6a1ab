"""SAC hyper-parameters: the off-policy family's (:class:`~jaxrl_robot.agents.off_policy.OffPolicyConfig`)
and SAC's own — the temperature α of the entropy bonus and the policy's smallest σ."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Self

from jaxrl_robot.agents.off_policy.config import OffPolicyConfig
from jaxrl_robot.validation import check_range

__all__ = ["SACConfig"]


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
