"""PPO hyper-parameters (defaults: thesis Table 5.2, the arm; K = 4 workers, N = 8, 5 updates on 32; σ is one
value for any action size, the arm's (0.8, 0.8, 0.1) is set by its presets)."""

from __future__ import annotations

from dataclasses import dataclass

from jaxrl_robot.agents.on_policy import ActorCriticConfig
from jaxrl_robot.validation import ConfigError, check_choice, check_counts, check_range

__all__ = ["LSTM_STARTS", "OBJECTIVES", "POLICIES", "PRETRAINS", "PPOConfig"]

OBJECTIVES = ("clip", "kl")
POLICIES = ("mlp", "lstm")
LSTM_STARTS = ("auto", "table", "zero")
PRETRAINS = ("none", "action-search")


@dataclass(frozen=True)
class PPOConfig(ActorCriticConfig):
    """Distributed PPO with GAE (thesis §5.1–5.3, Algorithms 7–8).

    Each iteration, ``num_envs`` lanes (the K workers) collect ``unroll_length`` (N) steps with
    the current policy; then ``actor_updates`` (m) actor steps and ``critic_updates`` (n) critic
    steps run on mini-batches of ``minibatch_size`` (B) transitions drawn from the K·N.
    Each mini-batch takes ``B / K`` transitions from every lane (without replacement within
    the lane), which keeps the result independent of how lanes are spread over devices.
    The fields shared with the other actor-critic agents are those of
    :class:`~jaxrl_robot.agents.on_policy.ActorCriticConfig`.
    """

    minibatch_size: int = 32
    """B: transitions per update; a multiple of num_envs, at most num_envs * unroll_length."""
    actor_updates: int = 5
    """m: actor gradient steps per iteration (Algorithm 8, lines 5-10)."""
    critic_updates: int = 5
    """n: critic gradient steps per iteration (Algorithm 8, lines 11-16)."""
    objective: str = "clip"
    """'clip': clipped surrogate (Eq. 5.5); 'kl': adaptive KL penalty (Eq. 5.3-5.4)."""
    clip_eps: float = 0.2
    """ε of the clipped objective."""
    kl_target: float = 0.01
    """D_thre of the adaptive KL penalty: β halves below D_thre/1.5 and doubles above 1.5 D_thre."""
    kl_beta: float = 1.0
    """Initial KL penalty coefficient β."""
    kl_beta_min: float = 1e-3
    """Floor on the adaptive β (the halve/double rule never takes it below this)."""
    kl_beta_max: float = 1e3
    """Ceiling on the adaptive β."""
    critic_first: bool = False
    """Train the critic on the batch before the actor and take the advantages from the updated critic
    (False: the thesis's order, Algorithm 8 — actor steps on advantages of the critic that collected
    the data, then critic steps). With few iterations (brax's tasks: 2 048 lanes, ~20 iterations in
    5 M steps) the advantages then lag the critic by one iteration less."""
    gae_lambda: float = 0.95
    """λ of GAE (Eq. 5.12) and of the critic's λ-returns (Eq. 5.14)."""
    advantage_segment: int = 0
    """0: advantages and λ-return targets once per batch, over each lane's whole unroll. S > 0 (brax's
    PPO, S its ``unroll_length``): each mini-batch is ``minibatch_size / S`` whole segments of S steps
    drawn from all lanes (per device; the draws then depend on the device count), and recomputes both
    with the current critic, bootstrapped at each segment's end, advantages normalised over the
    mini-batch; actor and critic then step together, once per mini-batch (``actor_updates ==
    critic_updates``). MLP policy, no pre-training; S divides ``unroll_length`` and ``minibatch_size``."""
    clip_actions: bool = False
    """Clip the actions the env receives, and the deterministic policy's, to [−1, 1] (the Gaussian's
    sample is kept for its log-probability); for envs that take the action as given (brax's)."""
    tanh_actions: bool = False
    """Squash the actions the env receives with ``tanh`` (the Gaussian's mean is then linear and the
    deterministic action is tanh(mean)): brax's and SAC's squashed Gaussian. Log-probabilities are
    taken of the unsquashed sample, whose probability ratio the squash leaves unchanged; the entropy
    bonus is the squashed action's (as brax's), which falls as the mean saturates."""
    normalize_obs: bool = False
    """Normalise observations by running mean and variance (actor and critic inputs)."""
    reset_refresh: float = 0.125
    """Auto-reset cost: the fraction of lanes whose next episode is drawn per step (``(0, 1]``).
    Below 1, finished lanes start from a pool of pre-drawn episodes (``envs_mjx.PoolResetWrapper``);
    1: a fresh reset for every finished lane, computed for every lane at the steps where some lane
    finished (with MuJoCo Warp physics at every step)."""
    reset_group: int = 256
    """Lanes per reset-pool group (the effective group is gcd(lanes per device, reset_group));
    runs on different device counts agree when it divides the lanes per device."""
    lane_group: int = 0
    """Step the env's lanes in groups of this many, one group after another (0: all lanes of a
    device in one batch); must divide the lanes per device. Large lane counts of MJX physics run
    faster in groups that fit the GPU's cache (``envs_mjx.base.map_lanes``)."""
    policy: str = "mlp"
    """'mlp': feed-forward actor and critic; 'lstm': FC → LSTM → FC actor and critic (thesis §5.7;
    ``actor_hidden`` / ``critic_hidden`` are the FC layers before the LSTM), trained on sequences of
    ``seq_length`` steps from the LSTM states stored when they were collected."""
    lstm_size: int = 256
    """Units of the LSTM cell (policy='lstm')."""
    seq_length: int = 10
    """policy='lstm': steps per training sequence (truncated back-propagation through time); a
    divisor of unroll_length. Mini-batches take whole sequences, B / (K · seq_length) per lane."""
    lstm_start: str = "auto"
    """policy='lstm': the LSTM state an episode starts from. 'table': the state stored for the
    reference step RSI starts it at (``jaxrl_robot.recurrent``; tracking envs, which report the
    step in ``info["k"]``); 'zero': zeros; 'auto': 'table' where the env reports the step."""
    start_table_rate: float = 1.0
    """ρ of the start-state table's update, ``(0, 1]`` (1: a visited step's entry becomes the mean
    of this iteration's LSTM states at that step)."""
    pretrain: str = "none"
    """'action-search': two-stage training (thesis §5.6, Algorithm 9) — for the first
    ``pretrain_episodes`` the actor is fitted by SGD to the best of ``pretrain_candidates`` random
    actions ranked by the env's known kinematics (``env.model_reward``) wherever that beats the
    policy's own action, while the critic fits λ-returns; PPO then fine-tunes. 'none': PPO only."""
    pretrain_episodes: int = 200
    """Pre-training length in episodes of the time limit: ``pretrain_episodes * episode_length`` env
    steps over all lanes (rounded up to whole iterations), counted within ``total_steps``."""
    pretrain_candidates: int = 200
    """M: random actions tried at each visited state."""
    pretrain_lr: float = 0.1
    """Learning rate of the actor's plain SGD in pre-training."""
    pretrain_epochs: int = 5
    """Passes over each iteration's K·N examples: ``pretrain_epochs · K·N / B`` SGD steps on
    mini-batches of B drawn like PPO's."""
    schedule: tuple[tuple[float, str, float], ...] = ()
    """Episode-parameter schedule: entries (start fraction of training, name in
    state.info["params"], value); from each start on, the parameter takes the value, broadcast
    to its shape (e.g. the RSI window and the early-termination limit of the tracking envs,
    thesis §3.5.2). On the command line: --schedule 0 et_limit 20 0.5 et_limit 15 ..."""

    def _check_segments(self) -> None:
        """``advantage_segment`` > 0: the settings that go with it (``ConfigError`` naming the first not)."""
        s = self.advantage_segment
        for name, plain in (("policy", "mlp"), ("pretrain", "none"), ("critic_first", False)):
            if getattr(self, name) != plain:
                raise ConfigError(f"{name}={getattr(self, name)!r} is not available with advantage_segment={s} "
                                  f"(valid: {plain!r})")  # fmt: skip
        if self.actor_updates != self.critic_updates:
            raise ConfigError(f"advantage_segment={s}: actor_updates={self.actor_updates} must equal "
                              f"critic_updates={self.critic_updates} (both step on each mini-batch)")  # fmt: skip
        if self.unroll_length % s:
            raise ConfigError(f"advantage_segment={s} must divide unroll_length={self.unroll_length}")
        if self.minibatch_size % s:
            raise ConfigError(f"advantage_segment={s} must divide minibatch_size={self.minibatch_size} "
                              "(whole segments)")  # fmt: skip

    def validate(self) -> PPOConfig:
        """Raise ``ConfigError`` naming the first invalid field; return self."""
        super().validate()
        check_counts(self, "minibatch_size", "actor_updates", "critic_updates")
        check_choice("objective", self.objective, OBJECTIVES)
        check_range("clip_eps", self.clip_eps, 0.0, 1.0, lo_open=True, hi_open=True)
        check_range("kl_target", self.kl_target, 0.0, lo_open=True)
        check_range("kl_beta", self.kl_beta, 0.0, lo_open=True)
        check_range("kl_beta_min", self.kl_beta_min, 0.0)
        check_range("kl_beta_max", self.kl_beta_max, self.kl_beta_min, lo_open=True)
        check_range("gae_lambda", self.gae_lambda, 0.0, 1.0)
        check_range("reset_refresh", self.reset_refresh, 0.0, 1.0, lo_open=True)
        check_range("reset_group", self.reset_group, 1)
        check_range("lane_group", self.lane_group, 0)
        check_choice("policy", self.policy, POLICIES)
        check_choice("lstm_start", self.lstm_start, LSTM_STARTS)
        check_counts(self, "lstm_size", "seq_length")
        check_range("start_table_rate", self.start_table_rate, 0.0, 1.0, lo_open=True)
        check_choice("pretrain", self.pretrain, PRETRAINS)
        check_counts(self, "pretrain_episodes", "pretrain_candidates", "pretrain_epochs")
        check_range("pretrain_lr", self.pretrain_lr, 0.0, lo_open=True)
        if self.clip_actions and self.tanh_actions:
            raise ConfigError("clip_actions=True and tanh_actions=True exclude each other; choose one")
        if self.policy == "lstm":
            for name, plain in (("tanh_actions", False), ("state_std", False), ("activation", "relu")):
                value = getattr(self, name)
                if value != plain:
                    raise ConfigError(f"{name}={value!r} needs policy='mlp' (valid with 'lstm': {plain!r})")
        if self.pretrain != "none" and self.policy != "mlp":
            raise ConfigError(f"pretrain={self.pretrain!r} needs policy='mlp' (got policy={self.policy!r})")
        check_range("advantage_segment", self.advantage_segment, 0)
        if self.advantage_segment:
            self._check_segments()
        if self.policy == "lstm":
            if self.batch_norm:
                raise ConfigError("batch_norm=True is not available with policy='lstm'; set batch_norm=False")
            if self.unroll_length % self.seq_length:
                raise ConfigError(
                    f"seq_length={self.seq_length} must divide unroll_length={self.unroll_length} (policy='lstm')"
                )
            if self.minibatch_size % (self.num_envs * self.seq_length):
                raise ConfigError(
                    f"minibatch_size={self.minibatch_size} must be a multiple of num_envs * seq_length = "
                    f"{self.num_envs * self.seq_length} (policy='lstm': whole sequences from every lane)"
                )
        if self.minibatch_size % self.num_envs and not self.advantage_segment:
            raise ConfigError(
                f"minibatch_size={self.minibatch_size} must be a multiple of num_envs={self.num_envs} "
                "(each mini-batch takes the same number of transitions from every lane)"
            )
        if self.minibatch_size > self.num_envs * self.unroll_length:
            raise ConfigError(
                f"minibatch_size={self.minibatch_size} is out of range; allowed [num_envs, num_envs * unroll_length]"
                f" = [{self.num_envs}, {self.num_envs * self.unroll_length}]"
            )
        for i, entry in enumerate(self.schedule):
            if len(entry) != 3:
                raise ConfigError(f"schedule[{i}]={entry!r} must be (start_fraction, name, value)")
            check_range(f"schedule[{i}].start", entry[0], 0.0, 1.0)
            check_range(f"schedule[{i}].value", entry[2])
        return self
