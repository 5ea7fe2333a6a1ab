"""A2C / A3C hyper-parameters (defaults: thesis Table 4.2, the arm; K = 4 workers, N = 8 transitions; σ is one
value for any action size, the arm's (0.8, 0.8, 0.1) is set by its presets)."""

from __future__ import annotations

from dataclasses import dataclass

from jaxrl_robot.agents.on_policy import LR_SCHEDULES, ActorCriticConfig
from jaxrl_robot.validation import ConfigError, check_choice, check_range

__all__ = ["BN_BATCHES", "LR_SCHEDULES", "PUSH_ORDERS", "A2CConfig", "A3CConfig"]

PUSH_ORDERS = ("random", "fixed")
BN_BATCHES = ("update", "lane")


@dataclass(frozen=True)
class A2CConfig(ActorCriticConfig):
    """Synchronous advantage actor-critic (thesis §4.1.2, Algorithm 3 with a barrier).

    Each round, every lane (worker) fills its local buffer with up to ``unroll_length`` (N)
    transitions using the current global parameters; a buffer closes early at the end of its
    episode (Algorithm 3, line 8), and the lane waits for the round's end. Each lane's
    gradient averages over its own transitions (lines 15-16, batch-norm statistics over its
    own buffer); the global network applies the mean of the lanes' gradients once per round.
    The fields shared with the other actor-critic agents are those of
    :class:`~jaxrl_robot.agents.on_policy.ActorCriticConfig`; ``gamma`` discounts the n-step
    returns (Eq. 4.3).
    """

    critic_lr: float = 2e-4
    """Adam learning rate of the critic (α_v, Table 4.2)."""
    entropy_coef: float = 0.01
    """β, the entropy regularisation of Eq. 4.4 (no effect on the gradient while σ is fixed)."""
    normalize_advantages: bool = False
    """Standardise the advantages over all transitions behind one applied gradient (A2C: the
    round's K·N; A3C: the worker's buffers) — not in the thesis."""
    bn_batch: str = "update"
    """Batch-norm statistics in training: 'lane' (each lane's own buffer of at most N
    consecutive steps, as each thesis worker normalises its local buffer) or 'update' (all
    transitions behind one applied gradient: A2C all K·N, A3C the worker's lanes)."""

    def validate(self) -> A2CConfig:
        """Raise ``ConfigError`` naming the first invalid field; return self."""
        super().validate()
        check_choice("bn_batch", self.bn_batch, BN_BATCHES)
        return self


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
