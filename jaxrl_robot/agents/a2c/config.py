"""A2C / A3C hyper-parameters (defaults: thesis Table 4.2, the arm; K = 4 workers, N = 8 transitions)."""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass

from envs_mjx.config import ConfigError, check_choice, check_range
from jaxrl_robot.networks import BN_MODES

__all__ = ["BN_BATCHES", "LR_SCHEDULES", "PUSH_ORDERS", "A2CConfig", "A3CConfig"]

PUSH_ORDERS = ("random", "fixed")
BN_BATCHES = ("update", "lane")
LR_SCHEDULES = ("constant", "linear")


@dataclass(frozen=True)
class A2CConfig:
    """Synchronous advantage actor-critic (thesis §4.1.2, Algorithm 3 with a barrier).

    Each round, every lane (worker) fills its local buffer with up to ``unroll_length`` (N)
    transitions using the current global parameters; a buffer closes early at the end of its
    episode (Algorithm 3, line 8), and the lane waits for the round's end. Each lane's
    gradient averages over its own transitions (lines 15-16, batch-norm statistics over its
    own buffer); the global network applies the mean of the lanes' gradients once per round.
    """

    total_steps: int = 400_000
    """Environment step slots of the whole run, K * N per round (rounded up to whole chunks).
    Lanes idle after an early episode end, so the steps taken (metric ``steps_taken``) can be fewer."""
    num_envs: int = 4
    """K: parallel lanes (workers); a multiple of the device count."""
    unroll_length: int = 8
    """N: capacity of each lane's local buffer (Algorithm 3)."""
    actor_lr: float = 1e-4
    """Adam learning rate of the actor (α_π, Table 4.2)."""
    critic_lr: float = 2e-4
    """Adam learning rate of the critic (α_v, Table 4.2)."""
    lr_schedule: str = "constant"
    """Learning rates 'constant' (the thesis) or 'linear' (annealed to 0 over the run's applied gradients)."""
    entropy_coef: float = 0.01
    """β, the entropy regularisation of Eq. 4.4 (no effect on the gradient while σ is fixed)."""
    gamma: float = 0.9
    """Discount factor γ of the n-step returns (Eq. 4.3)."""
    sigma: tuple[float, ...] = (0.8, 0.8, 0.1)
    """Policy standard deviation per action dimension (one value is broadcast)."""
    learn_std: bool = False
    """Learn a state-independent log-std starting at log(sigma) instead of the fixed σ."""
    actor_hidden: tuple[int, ...] = (200, 200)
    """Hidden layer widths of the actor."""
    critic_hidden: tuple[int, ...] = (200, 200)
    """Hidden layer widths of the critic."""
    batch_norm: bool = True
    """Batch-normalise the actor (batch statistics in training, see bn_batch; moving averages when acting)."""
    bn_momentum: float = 0.999
    """Decay of the batch-norm moving averages, once per applied gradient. Slow: with K = 4 lanes a
    round's batch holds 4 goals (arm7 thesis preset with batch renormalisation: 2 % test success at
    0.99; 65 / 27 % at 0.999, seeds 0 / 1; 0 % at 0.9997)."""
    bn_mode: str = "renorm"
    """Actor batch-norm in training: 'renorm' — batch renormalisation (Ioffe, 2017): outputs equal
    the acting ones (moving averages) while gradients flow through the batch statistics;
    'batch' — plain batch-norm, whose trained policy (each few-lane mini-batch normalised by its
    own statistics) is not the acting one."""
    bn_batch: str = "update"
    """Batch-norm statistics in training: 'lane' (each lane's own buffer of at most N
    consecutive steps, as each thesis worker normalises its local buffer) or 'update' (all
    transitions behind one applied gradient: A2C all K·N, A3C the worker's lanes)."""
    normalize_advantages: bool = False
    """Standardise the advantages over all transitions behind one applied gradient (A2C: the
    round's K·N; A3C: the worker's buffers) — not in the thesis."""
    max_grad_norm: float = 0.0
    """Clip every applied gradient to this global norm (0: no clipping)."""
    reward_scale: float = 1.0
    """Multiply rewards by this before computing returns."""
    episode_length: int = 0
    """Time limit in steps (0: the environment's own ``episode_length``)."""

    def validate(self) -> A2CConfig:
        """Raise ``ConfigError`` naming the first invalid field; return self."""
        for name in ("total_steps", "num_envs", "unroll_length"):
            value = getattr(self, name)
            check_range(name, value, 1)
            if int(value) != value:
                raise ConfigError(f"{name}={value!r} must be an integer")
        check_range("actor_lr", self.actor_lr, 0.0, lo_open=True)
        check_range("critic_lr", self.critic_lr, 0.0, lo_open=True)
        check_choice("lr_schedule", self.lr_schedule, LR_SCHEDULES)
        check_range("entropy_coef", self.entropy_coef, 0.0)
        check_range("gamma", self.gamma, 0.0, 1.0)
        check_range("bn_momentum", self.bn_momentum, 0.0, 1.0, hi_open=True)
        check_choice("bn_mode", self.bn_mode, BN_MODES)
        check_choice("bn_batch", self.bn_batch, BN_BATCHES)
        check_range("max_grad_norm", self.max_grad_norm, 0.0)
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

    def replace(self, **changes) -> A2CConfig:
        """A copy with ``changes`` applied (the original is not modified)."""
        return dataclasses.replace(self, **changes)


@dataclass(frozen=True)
class A3CConfig(A2CConfig):
    """Asynchronous advantage actor-critic (thesis §4.1.1, Algorithm 3), reproduced deterministically.

    Workers are groups of ``lanes_per_worker`` lanes; each worker holds its own parameter
    snapshot, acts and computes its gradient with it. After every round the workers' gradients
    are applied to the global parameters one after another in the push order, and a worker
    re-syncs its snapshot right after its own push — so the later pushes of a round were
    computed on parameters that the earlier pushes have since changed (gradient delay).
    """

    lanes_per_worker: int = 1
    """Lanes that share one worker's parameter snapshot and push one averaged gradient
    (1: every lane is a worker, as in the thesis). Must divide the lanes of each device."""
    push_order: str = "random"
    """Order of the workers' pushes in each round: 'random' (a fresh permutation per round)
    or 'fixed' (worker 0 first, then 1, ...)."""
    staleness_bins: int = 8
    """Bins of the staleness histogram in the metrics (the last bin collects the tail)."""

    def validate(self) -> A3CConfig:
        super().validate()
        check_range("lanes_per_worker", self.lanes_per_worker, 1)
        if self.num_envs % self.lanes_per_worker:
            raise ConfigError(f"lanes_per_worker={self.lanes_per_worker} must divide num_envs={self.num_envs}")
        check_choice("push_order", self.push_order, PUSH_ORDERS)
        check_range("staleness_bins", self.staleness_bins, 1)
        return self

    @property
    def num_workers(self) -> int:
        """W: asynchronous workers (parameter snapshots)."""
        return self.num_envs // self.lanes_per_worker
