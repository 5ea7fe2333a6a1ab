"""The off-policy family's hyper-parameters (DDPG, TD3, SAC): schedule, lanes, replay, PER, HER,
exploration noise, targets, imitation and distributed workers (defaults: thesis Table 3.2, the arm with
HER; the noise one value for any action size).  A member's config subclasses :class:`OffPolicyConfig`
and adds only its own fields (``ddpg.DDPGConfig``: the actor's output, twin critics, target smoothing;
``sac.SACConfig``: the temperature)."""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Any, Self

from brax.envs.base import Env

from jaxrl_robot.replay.her import STRATEGIES
from jaxrl_robot.replay.prioritized import TREES as PER_TREES
from jaxrl_robot.validation import ConfigError, check_choice, check_counts, check_each, check_integer, check_range

__all__ = ["ANCHORS", "NOISES", "PRETRAINS", "SCHEDULES", "OffPolicyConfig", "with_env_target_clip"]

SCHEDULES = ("episodes", "steps")
NOISES = ("gaussian", "ou")
PRETRAINS = ("none", "imitation")
ANCHORS = ("steps", "loss")


@dataclass(frozen=True)
class OffPolicyConfig:
    """An off-policy actor-critic (DDPG's Algorithm 1 and its family) with optional prioritised replay
    (§3.2) and hindsight relabelling (§3.3).

    Two schedules:

    * ``"episodes"`` (thesis §3.4.2, Tables 3.1–3.2): ``epochs`` × ``cycles_per_epoch``
      cycles; each cycle runs ``num_envs`` whole episodes as parallel lanes (16 in the
      thesis), stores their transitions (relabelled by HER) and then makes
      ``updates_per_cycle`` (40) updates on mini-batches of ``batch_size`` (128).
    * ``"steps"`` (thesis §3.5, Table 3.3): lanes step continuously with auto-reset; after
      every ``unroll_length`` steps of all lanes, ``updates_per_iteration`` updates, once
      ``learning_starts`` transitions are stored (5000 in the thesis).

    With ``distributed`` (thesis §4.2), either schedule runs with synchronous and collecting
    workers (``jaxrl_robot.agents.off_policy.distributed``).
    """

    schedule: str = "episodes"
    """'episodes' (cycles of whole episodes, then updates) or 'steps' (updates every few steps)."""
    epochs: int = 200
    """'episodes' schedule: number of epochs (200 for the sparse-reward rows, 100 for the shaped)."""
    cycles_per_epoch: int = 50
    """'episodes' schedule: cycles per epoch."""
    updates_per_cycle: int = 40
    """'episodes' schedule: gradient updates after each cycle."""
    total_steps: int = 200_000
    """'steps' schedule: environment steps of the run (all lanes together, collecting workers' included)."""
    unroll_length: int = 1
    """'steps' schedule: steps of every lane between update phases."""
    updates_per_iteration: int = 1
    """'steps' schedule: gradient updates after each unroll."""
    learning_starts: int = 0
    """No updates until this many transitions are stored (at least one batch is always required)."""
    random_start: bool = False
    """Until ``learning_starts`` transitions are stored, every lane acts uniformly at random in
    [−1, 1] instead of ``μ(s) + ω`` (the start steps of TD3 and Stable-Baselines3's off-policy
    methods): the first memory then spans the action space rather than the untrained actor's
    near-constant output.  False: the actor with its noise from the first step (Algorithm 1)."""
    num_envs: int = 16
    """Parallel lanes: episodes per cycle ('episodes') or continuously running envs ('steps')."""
    episode_length: int = 0
    """Time limit in steps (0: the environment's own ``episode_length``, else brax's default of 1000)."""
    batch_size: int = 128
    """Mini-batch size b_n (of each synchronous worker when distributed)."""
    buffer_size: int = 1_000_000
    """Replay memory capacity C."""
    actor_lr: float = 1e-3
    """Adam learning rate of the actor α_μ."""
    critic_lr: float = 1e-3
    """Adam learning rate of the critic α_Q."""
    tau: float = 0.05
    """Soft replacement coefficient ε of the target networks."""
    gamma: float = 0.9
    """Discount factor γ."""
    per: bool = False
    """Prioritised experience replay (sum-tree, Eq. 3.9-3.10) instead of uniform sampling."""
    alpha: float = 0.6
    """PER priority exponent α."""
    beta0: float = 0.4
    """PER initial importance-sampling exponent β0."""
    beta_increment: float = 0.001
    """PER increment of β per update (up to 1)."""
    per_tree: str = "auto"
    """PER: the sum-tree, 'sum' (16-ary, :mod:`jaxrl_robot.replay.sum_tree`), 'block' (two levels,
    :mod:`jaxrl_robot.replay.block_tree`, Pallas kernels on a GPU) or 'auto' (= 'sum'; see
    :func:`jaxrl_robot.replay.make_prioritized_replay`)."""
    priority_eps: float = 1e-6
    """PER: ε of the priority ``p = min(|δ|, priority_clip) + ε``; the smallest priority, so it bounds
    the largest importance weight relative to the others (Eq. 3.10 normalises by the largest)."""
    priority_clip: float = 0.0
    """PER: clip ``|δ|`` to this before it becomes a priority (0: no clipping).  Bounds the
    priority ratio to ``((priority_clip + ε) / ε)^α``, so that a few unpredictable transitions
    (terminations the observation cannot foresee) neither dominate the mini-batches nor shrink
    every other importance weight."""
    her: str = "none"
    """Hindsight relabelling strategy: 'none', 'final', 'future' or 'random' (episodes schedule only)."""
    her_k: int = 2
    """Additional goals per transition for 'future' and 'random'."""
    noise: str = "gaussian"
    """Exploration noise: 'gaussian' or 'ou' (Ornstein-Uhlenbeck, Eq. 3.8)."""
    noise_scale: tuple[float, ...] = (0.2,)
    """σ of the Gaussian noise, or σ2 of the OU process, in action units: one value (broadcast to the env's
    action size) or one per action.  The default 0.2 is the arm presets' Gaussian σ and suits any env
    with actions in [−1, 1] (TD3's own is 0.1); per-action values such as the racing car's Table 6.1 are
    set by the presets."""
    noise_mean: tuple[float, ...] = (0.0,)
    """Mean of the noise (η of the OU process): one value (broadcast) or one per action."""
    noise_reversion: tuple[float, ...] = (0.15,)
    """σ1 of the OU process (reversion rate): one value (broadcast) or one per action."""
    actor_hidden: tuple[int, ...] = (100, 100, 100)
    """Hidden widths of the actor (arm: 3 x 100; tracking: 300-100)."""
    critic_hidden: tuple[int, ...] = (100, 100, 100)
    """Hidden widths of the critic."""
    failure_value: float = 0.0
    """Value of the state after a failure (a termination without success, e.g. leaving the
    feasible region): a failing step's target is r + γ·failure_value.  0 is plain termination
    (Algorithm 1).  With the sparse reward and γ = 0.9, plain termination makes leaving the region
    (value −1) better than any goal more than one step away, so the sparse presets use
    −1/(1−γ) = −10: failing counts as never reaching the goal."""
    reward_scale: float = 1.0
    """Multiply rewards by this in the critic target."""
    target_clip: tuple[float, ...] = ()
    """(lo, hi): clip critic targets to the reachable return range, e.g. (-10, 0) for the sparse
    reward with γ = 0.9 (as in the HER reference implementation); empty: no clipping."""
    clip_targets_to_env: bool = False
    """Clip critic targets to the env's bounds on the return, ``env.return_bounds(gamma)`` (scaled by
    ``reward_scale``, widened by ``reward_shift``), instead of a fixed ``target_clip``; the env must
    define ``return_bounds`` (``arm7`` does for its sparse and shaped rewards)."""
    max_grad_norm: float = 0.0
    """Clip gradients to this global norm (0: no clipping)."""
    normalize_obs: bool = False
    """Feed actor and critic ``(obs − mean) / std`` (clipped to ±10) with a running mean and variance
    of every observation the lanes visited (the replay keeps raw observations, normalised when
    sampled with the current statistics); the statistics are part of the training state."""
    policy_delay: int = 1
    """Update the actor and the target networks once every ``policy_delay`` critic updates
    (TD3 uses 2; 1 is Algorithm 1).  Counted over the whole run: after n updates the actor has had
    ``n // policy_delay`` steps."""
    noise_end_factor: float = 1.0
    """Linear exploration-noise schedule: the noise sample ω is multiplied by
    ``f = 1 + (noise_end_factor − 1) · min(1, iteration / (noise_decay_fraction · iterations))``,
    falling from 1 to ``noise_end_factor`` (in [0, 1]) and then held.  1: constant noise."""
    noise_decay_fraction: float = 1.0
    """Fraction of the run's iterations over which the noise factor falls (in (0, 1])."""
    reward_shift: float = 0.0
    """Added to every (scaled) reward in the critic target, ``y = reward_scale·r + reward_shift +
    γ (1 − d) Q'``.  −1 turns a reward in [0, 1] (Eq. 3.22–3.23) into a cost ``−(1 − r)``, so Q is the
    small negative cost-to-go instead of a value near ``1/(1 − γ)``, and the critic's absolute error
    is small next to the action-dependent part.  Only sensible with ``termination_metric`` and a
    ``failure_value`` of at most ``reward_shift/(1 − γ)``; otherwise an ending is a shortcut."""
    termination_metric: str = ""
    """Name of a per-step 0/1 metric of the env marking the real terminations (tracking envs:
    ``"early_termination"``); any other episode end (the reference running out) is then treated as
    a time limit and bootstrapped (d = 0).  Empty: every end that is not a truncation terminates."""
    lr_end_factor: float = 1.0
    """Linear learning-rate decay of actor and critic (in (0, 1]): the Adam step size of the k-th step
    of an optimiser is ``lr · (1 + (lr_end_factor − 1) · min(1, k / K))``, with K its planned steps
    over the run — ``iterations × updates`` per iteration for the critic, that divided by
    ``policy_delay`` for the actor (updates skipped before ``learning_starts`` leave the end factor
    slightly higher).  Smaller late steps keep the policy from drifting away late in training.
    1: constant learning rates (Algorithm 1)."""
    pretrain: str = "none"
    """'none', or 'imitation' (thesis §6.1.2): for the first ``pretrain_steps`` env steps the actor
    fits the env's expert (``env.expert(state)``) on the states the lanes visit — mean squared
    error on mini-batches of ``imitation_batch`` pairs from a memory of the latest
    ``imitation_buffer`` pairs, ``imitation_updates`` Adam steps per iteration, no exploration
    noise — while the critic learns from the transitions as in DDPG and the targets follow; then
    the agent (DDPG, TD3, SAC) fine-tunes from those weights.  Needs the 'steps' schedule and an env with
    ``expert``."""
    pretrain_steps: int = 4000
    """'imitation': env steps (all lanes) of the imitation stage, counted in ``total_steps``; equal to
    ``total_steps``, the whole run imitates (an imitation-only policy)."""
    imitation_updates: int = 4
    """'imitation': actor updates on the expert's actions per iteration."""
    imitation_batch: int = 50
    """'imitation': (state, expert action) pairs per actor update (50 in the thesis)."""
    imitation_lr: float = 1e-3
    """'imitation': Adam step size of the actor's imitation updates."""
    imitation_buffer: int = 100_000
    """'imitation': pairs kept (the latest), sampled uniformly for the actor's updates."""
    imitation_weight: float = 0.0
    """'imitation': after the stage, the actor stays anchored to the expert's labels of the visited
    states with this weight (a behaviour-cloning anchor in the manner of DDPG from demonstrations,
    Nair et al. 2018), as separate imitation steps or as a term of its loss (``imitation_anchor``);
    0: plain fine-tuning, as in the thesis."""
    imitation_anchor: str = "steps"
    """'imitation' with ``imitation_weight`` > 0: 'steps' — after the stage the imitation updates go on
    between the DDPG updates, their step size scaled by the weight; 'loss' — the imitation updates stop
    with the stage and the actor's loss takes the anchor instead (DDPG's:
    ``−mean Q1(s, μ(s)) / mean |Q1| + imitation_weight · mean ‖μ(s_d) − a*_d‖²``) on a mini-batch of
    ``imitation_batch`` pairs from the memory per actor step (TD3+BC's objective, Fujimoto & Gu 2021;
    :func:`~jaxrl_robot.agents.off_policy.losses.anchored_actor_loss`), one Adam step at ``actor_lr``."""
    expert_share: float = 0.0
    """'imitation': probability that a lane's step executes the expert's action instead of the
    actor's at the start of the stage, falling linearly to 0 at its end (DAgger's β); 0: the actor
    drives every visited state, as in the thesis."""
    distributed: bool = False
    """Distributed DDPG (thesis §4.2, Algorithms 4-6): sync_workers synchronous workers share the
    num_envs lanes, act with the latest parameters, each sample its own prioritised mini-batch of
    batch_size from the shared replay and average their gradients (m · batch_size transitions per
    update); collect_workers collecting workers only act, in collect_lanes lanes each, with a
    parameter copy fetched every fetch_every iterations, and store their transitions with
    priorities from their own critic copy."""
    sync_workers: int = 4
    """Distributed: synchronous workers m (a divisor of num_envs, a multiple of the device count)."""
    collect_workers: int = 4
    """Distributed: collecting workers (0: none; a multiple of the device count)."""
    collect_lanes: int = 1
    """Distributed: lanes of each collecting worker."""
    fetch_every: int = 5
    """Distributed: a collecting worker fetches the global parameters every this many iterations
    (steps with unroll_length 1), the workers' fetches spread evenly over that period."""
    collect_noise_factors: tuple[float, ...] = ()
    """Distributed: the exploration noise of each collecting worker times this factor (one value
    for all or one per worker; empty: 1)."""

    @property
    def lanes(self) -> int:
        """Lanes that act: ``num_envs``, plus the collecting workers' lanes when distributed."""
        return self.num_envs + (self.collect_workers * self.collect_lanes if self.distributed else 0)

    @property
    def iterations(self) -> int:
        """Training iterations: cycles ('episodes') or unroll + update phases ('steps'; ``total_steps``
        counts the steps of every lane)."""
        if self.schedule == "episodes":
            return self.epochs * self.cycles_per_epoch
        return max(1, -(-self.total_steps // (self.lanes * self.unroll_length)))

    @property
    def total_iterations(self) -> int:
        """:attr:`iterations` (the name ``core.setup`` reads)."""
        return self.iterations

    def validate(self) -> Self:
        """Raise ``ConfigError`` naming the first invalid field; return self."""
        check_choice("schedule", self.schedule, SCHEDULES)
        check_choice("pretrain", self.pretrain, PRETRAINS)
        check_choice("imitation_anchor", self.imitation_anchor, ANCHORS)
        check_counts(self, "epochs", "cycles_per_epoch", "updates_per_cycle", "total_steps", "unroll_length",
                     "updates_per_iteration", "num_envs", "batch_size", "buffer_size")
        check_range("learning_starts", self.learning_starts, 0)
        if self.random_start and self.learning_starts < 1:
            raise ConfigError("random_start=True acts at random until learning_starts transitions are stored; "
                              "set learning_starts >= 1")
        check_range("episode_length", self.episode_length, 0)
        check_range("actor_lr", self.actor_lr, 0.0, lo_open=True)
        check_range("critic_lr", self.critic_lr, 0.0, lo_open=True)
        check_range("tau", self.tau, 0.0, 1.0, lo_open=True)
        check_range("gamma", self.gamma, 0.0, 1.0)
        check_range("alpha", self.alpha, 0.0, 1.0)
        check_range("beta0", self.beta0, 0.0, 1.0)
        check_range("beta_increment", self.beta_increment, 0.0)
        check_range("priority_eps", self.priority_eps, 0.0, lo_open=True)
        check_range("priority_clip", self.priority_clip, 0.0)
        check_choice("her", self.her, STRATEGIES)
        if self.her in ("future", "random"):
            check_range("her_k", self.her_k, 1)
        if self.her != "none" and self.schedule != "episodes":
            raise ConfigError(f"her={self.her!r} needs whole episodes: use schedule='episodes'")
        check_choice("noise", self.noise, NOISES)
        check_choice("per_tree", self.per_tree, PER_TREES)
        for name in ("noise_scale", "noise_mean", "noise_reversion"):
            if not getattr(self, name):
                raise ConfigError(f"{name}=() must have at least one value")
        check_each("noise_scale", self.noise_scale, 0.0)
        check_each("noise_reversion", self.noise_reversion, 0.0, 2.0, lo_open=True, hi_open=True)
        check_each("actor_hidden", self.actor_hidden, 1)
        check_each("critic_hidden", self.critic_hidden, 1)
        check_range("reward_scale", self.reward_scale, 0.0, lo_open=True)
        if self.target_clip and (len(self.target_clip) != 2 or self.target_clip[0] > self.target_clip[1]):
            raise ConfigError(f"target_clip={self.target_clip!r} must be () or (lo, hi) with lo <= hi")
        if self.target_clip and self.clip_targets_to_env:
            raise ConfigError("target_clip and clip_targets_to_env=True exclude each other; set one of them")
        check_range("max_grad_norm", self.max_grad_norm, 0.0)
        check_counts(self, "policy_delay")
        check_range("noise_end_factor", self.noise_end_factor, 0.0, 1.0)
        check_range("noise_decay_fraction", self.noise_decay_fraction, 0.0, 1.0, lo_open=True)
        check_range("lr_end_factor", self.lr_end_factor, 0.0, 1.0, lo_open=True)
        if self.reward_shift != self.reward_shift or abs(self.reward_shift) == float("inf"):
            raise ConfigError(f"reward_shift={self.reward_shift!r} must be a finite number")
        if self.termination_metric and not self.termination_metric.isidentifier():
            raise ConfigError(f"termination_metric={self.termination_metric!r} must be empty or a metric name")
        if self.distributed:
            self._validate_workers()
        if self.pretrain != "none":
            self._validate_pretrain()
        return self

    def check_action_size(self, action_size: int) -> Self:
        """Raise ``ConfigError`` naming the first per-action noise field (``noise_scale``, ``noise_mean``;
        ``noise_reversion`` with OU noise) that has neither 1 nor ``action_size`` values; return self."""
        names = ("noise_scale", "noise_mean") + (("noise_reversion",) if self.noise == "ou" else ())
        for name in names:
            if len(getattr(self, name)) not in (1, action_size):
                raise ConfigError(f"{name}={getattr(self, name)!r} must have 1 or action_size={action_size} values")
        return self

    @property
    def pretrain_iterations(self) -> int:
        """Iterations of the imitation stage (0 without ``pretrain``)."""
        if self.pretrain == "none":
            return 0
        return min(self.iterations, -(-self.pretrain_steps // (self.lanes * self.unroll_length)))

    def _validate_pretrain(self) -> None:
        """The imitation fields (thesis §6.1.2)."""
        check_choice("pretrain", self.pretrain, PRETRAINS)
        if self.schedule != "steps":
            raise ConfigError(f"pretrain={self.pretrain!r} needs schedule='steps' (got {self.schedule!r})")
        if self.distributed:
            raise ConfigError(f"pretrain={self.pretrain!r} is not available with distributed=True")
        check_counts(self, "pretrain_steps", "imitation_updates", "imitation_batch", "imitation_buffer")
        if self.pretrain_steps > self.total_steps:
            raise ConfigError(f"pretrain_steps={self.pretrain_steps} must be at most total_steps ({self.total_steps})")
        check_range("imitation_lr", self.imitation_lr, 0.0, lo_open=True)
        check_range("expert_share", self.expert_share, 0.0, 1.0)
        check_range("imitation_weight", self.imitation_weight, 0.0)

    def _validate_workers(self) -> None:
        """The distributed fields (thesis §4.2)."""
        for name, lo in (("sync_workers", 1), ("collect_workers", 0), ("collect_lanes", 1), ("fetch_every", 1)):
            check_integer(name, getattr(self, name), lo)
        if self.num_envs % self.sync_workers:
            raise ConfigError(f"num_envs={self.num_envs} must be a multiple of sync_workers ({self.sync_workers})")
        if len(self.collect_noise_factors) not in (0, 1, self.collect_workers):
            raise ConfigError(
                f"collect_noise_factors={self.collect_noise_factors!r} must have 0, 1 or collect_workers "
                f"({self.collect_workers}) values"
            )
        check_each("collect_noise_factors", self.collect_noise_factors, 0.0)

    def replace(self, **changes: Any) -> Self:
        """A copy with ``changes`` applied (the original is not modified)."""
        return dataclasses.replace(self, **changes)


def with_env_target_clip(config: OffPolicyConfig, env: Env) -> OffPolicyConfig:
    """``config`` with ``target_clip`` set from ``env.return_bounds(gamma)`` when ``clip_targets_to_env``.

    The critic's target is ``r·reward_scale + reward_shift + γ·Q'``, so the env's bounds ``[lo, hi]`` on
    the return become ``[lo·scale + min(shift, 0)/(1−γ), hi·scale + max(shift, 0)/(1−γ)]``.

    Raises:
      ConfigError: the env gives no bounds for its settings.
    """
    if not config.clip_targets_to_env:
        return config
    bounds_of = getattr(env, "return_bounds", None)
    bounds = bounds_of(config.gamma) if bounds_of is not None else None
    if bounds is None:
        raise ConfigError(
            "clip_targets_to_env=True needs an env whose return_bounds(gamma) bounds its return; this env "
            "gives none: set target_clip=(lo, hi) instead, or clip_targets_to_env=False"
        )
    shift = config.reward_shift / (1.0 - config.gamma)
    lo = bounds[0] * config.reward_scale + min(shift, 0.0)
    hi = bounds[1] * config.reward_scale + max(shift, 0.0)
    return config.replace(target_clip=(float(lo), float(hi)), clip_targets_to_env=False)
