"""The hyper-parameters every on-policy actor-critic agent has (:class:`ActorCriticConfig`) and the
learning-rate schedules (:data:`LR_SCHEDULES`, :func:`lr_end_factor`)."""

from __future__ import annotations

import dataclasses
import math
from dataclasses import dataclass
from typing import Any, Self

from jaxrl_robot.networks import ACTIVATIONS, BN_MODES
from jaxrl_robot.validation import ConfigError, check_choice, check_counts, check_range

__all__ = ["LR_SCHEDULES", "ActorCriticConfig", "lr_end_factor"]

LR_SCHEDULES = ("constant", "linear")
"""The learning-rate schedules of :attr:`ActorCriticConfig.lr_schedule`."""


@dataclass(frozen=True)
class ActorCriticConfig:
    """Hyper-parameters shared by the actor-critic agents (defaults: the thesis's arm settings, except
    that a per-action field such as ``sigma`` defaults to one value, broadcast to any env's action size;
    the arm's per-action values are set by its presets, ``train/presets/``).

    ``num_envs`` lanes (the K workers) each collect ``unroll_length`` (N) steps per iteration;
    the actor is Gaussian (fixed or learned σ, optional batch-norm), the critic a plain MLP,
    both trained with Adam.  Subclasses add the algorithm's fields, re-declare a field to change
    its default, and extend :meth:`validate`.
    """

    total_steps: int = 400_000
    """Environment step slots of the whole run, num_envs * unroll_length per iteration (rounded up
    to whole chunks of iterations). Where lanes idle after an early episode end (A2C), the steps
    taken (metric ``steps_taken``) can be fewer."""
    num_envs: int = 4
    """K: parallel lanes (workers); a multiple of the device count."""
    unroll_length: int = 8
    """N: steps (buffer slots) each lane collects per iteration."""
    actor_lr: float = 1e-4
    """Adam learning rate of the actor (α_π)."""
    critic_lr: float = 5e-4
    """Adam learning rate of the critic (α_v)."""
    gamma: float = 0.9
    """Discount factor γ."""
    sigma: tuple[float, ...] = (0.5,)
    """Policy standard deviation in action units: one value (broadcast to the env's action size) or one
    per action dimension. The default 0.5 suits any env with actions in [−1, 1]: it is fixed for the whole
    run unless ``learn_std``, so it sits below the initial σ of policies that learn theirs (brax's PPO
    ≈ 0.69 = softplus(0) + 0.001, Stable-Baselines3's 1) and within the thesis's fixed values (arm
    (0.8, 0.8, 0.1), Table 5.2; unicycle (0.1, 0.01), Table 5.3), which the presets set per env."""
    learn_std: bool = False
    """Learn a state-independent log-std starting at log(sigma) instead of a fixed σ."""
    state_std: bool = False
    """With learn_std: a state-dependent σ(s) = softplus(·) + 0.001 from a second output layer of
    the actor, starting at sigma (brax's PPO parametrisation)."""
    activation: str = "relu"
    """Hidden-layer activation of actor and critic: relu, swish (brax's PPO networks), tanh or elu."""
    actor_hidden: tuple[int, ...] = (200, 200)
    """Hidden layer widths of the actor."""
    critic_hidden: tuple[int, ...] = (200, 200)
    """Hidden layer widths of the critic."""
    batch_norm: bool = True
    """Batch-normalise the actor (batch statistics in training, moving averages when acting)."""
    bn_momentum: float = 0.999
    """Decay of the batch-norm moving averages, applied at every actor gradient step. Slow: with
    K = 4 lanes a batch holds 4 goals, and its statistics would drag the acting policy around
    (arm7 thesis preset: 2 % test success at 0.99; at 0.999 PPO 79 %, A2C 65 / 27 %, seeds 0 / 1)."""
    bn_mode: str = "renorm"
    """Actor batch-norm in training: 'renorm' — batch renormalisation (Ioffe, 2017): outputs equal
    the acting ones (moving averages) while gradients flow through the batch statistics;
    'batch' — plain batch-norm, whose trained policy (each few-lane mini-batch normalised by its
    own statistics) is not the acting one."""
    normalize_advantages: bool = True
    """Standardise advantages over each iteration's K·N transitions."""
    entropy_coef: float = 0.0
    """Entropy bonus coefficient in the actor objective."""
    max_grad_norm: float = 0.0
    """Clip gradients to this global norm (0: no clipping)."""
    lr_schedule: str = "constant"
    """Learning rates 'constant' (the thesis) or 'linear': annealed to 0 over the run's optimiser steps
    (purejaxrl's and CleanRL's ``anneal_lr``, Stable-Baselines3's linear schedule)."""
    reward_scale: float = 1.0
    """Multiply rewards by this before computing returns."""
    episode_length: int = 0
    """Time limit in steps (0: the environment's own ``episode_length``, else brax's default of 1000)."""

    @property
    def total_iterations(self) -> int:
        """Iterations of the whole run: ``ceil(total_steps / (K · N))``, at least 1."""
        return max(1, math.ceil(self.total_steps / (self.num_envs * self.unroll_length)))

    def validate(self) -> Self:
        """Raise ``ConfigError`` naming the first invalid field; return self."""
        check_counts(self, "total_steps", "num_envs", "unroll_length")
        check_range("actor_lr", self.actor_lr, 0.0, lo_open=True)
        check_range("critic_lr", self.critic_lr, 0.0, lo_open=True)
        check_range("gamma", self.gamma, 0.0, 1.0)
        check_range("bn_momentum", self.bn_momentum, 0.0, 1.0, hi_open=True)
        check_choice("bn_mode", self.bn_mode, BN_MODES)
        check_choice("activation", self.activation, tuple(ACTIVATIONS))
        if self.state_std and not self.learn_std:
            raise ConfigError("state_std=True needs learn_std=True (a state-dependent σ is learned)")
        check_range("entropy_coef", self.entropy_coef, 0.0)
        check_range("max_grad_norm", self.max_grad_norm, 0.0)
        check_choice("lr_schedule", self.lr_schedule, LR_SCHEDULES)
        check_range("reward_scale", self.reward_scale, 0.0, lo_open=True)
        check_range("episode_length", self.episode_length, 0)
        if not self.sigma:
            raise ConfigError("sigma=() must have at least one value")
        for i, s in enumerate(self.sigma):
            check_range(f"sigma[{i}]", s, 0.0, lo_open=True)
        for name in ("actor_hidden", "critic_hidden"):
            for i, w in enumerate(getattr(self, name)):
                check_range(f"{name}[{i}]", w, 1)
        return self

    def replace(self, **changes: Any) -> Self:
        """A copy with ``changes`` applied (the original is not modified)."""
        return dataclasses.replace(self, **changes)


def lr_end_factor(config: ActorCriticConfig) -> float:
    """The learning rates' factor at the end of the run: 0 for ``lr_schedule='linear'``, else 1."""
    return 0.0 if config.lr_schedule == "linear" else 1.0
