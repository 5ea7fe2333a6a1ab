"""Presets from the peers' published settings: brax's PPO and SAC rows (:data:`BRAX_PPO`, :data:`BRAX_SAC`)
and MuJoCo Playground's ``brax_ppo_config`` / ``brax_sac_config``, converted to our configs."""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

from jaxrl_robot.agents.ddpg import DDPGConfig
from jaxrl_robot.agents.ppo import PPOConfig

BRAX_COLUMNS = ("num_timesteps", "num_envs", "batch_size", "num_minibatches", "unroll_length",
                "num_updates_per_batch", "discounting", "entropy_cost", "reward_scaling", "learning_rate",
                "episode_length")  # fmt: skip
"""The columns of :data:`BRAX_PPO`: the arguments of brax's ``ppo.train`` they are."""

# brax's training notebook (github.com/google/brax, notebooks/training.ipynb, `train_fn`). reacher's row
# there also repeats each action 4 times (action_repeat=4), left out here (`python -m benchmarks.brax_tasks
# --row action_repeat=4` runs both sides so, ours through envs_mjx.ActionRepeatWrapper); the notebook
# trains hopper with SAC, so its PPO row here is the notebook's ant row (its locomotion PPO setting).
BRAX_PPO: dict[str, dict[str, float]] = {
    task: dict(zip(BRAX_COLUMNS, row, strict=True))
    for task, row in {
        #                            steps  envs  batch mb unroll passes  γ     entropy reward lr    T
        "inverted_pendulum":        (2e6,   2048, 1024, 32, 5,  4,  0.97, 1e-2, 10, 3e-4, 1000),
        "inverted_double_pendulum": (20e6,  2048, 1024, 32, 5,  4,  0.97, 1e-2, 10, 3e-4, 1000),
        "reacher":                  (50e6,  2048, 256,  32, 50, 8,  0.95, 1e-3, 5,  3e-4, 1000),
        "halfcheetah":              (50e6,  2048, 512,  32, 20, 8,  0.95, 1e-3, 1,  3e-4, 1000),
        "hopper":                   (50e6,  4096, 2048, 32, 5,  4,  0.97, 1e-2, 10, 3e-4, 1000),
    }.items()
}  # fmt: skip
"""brax's PPO settings per brax task, in brax's terms (converted by :func:`brax_ppo_config`)."""


def brax_ppo_config(task: str, action_size: int, segments: bool | None = None, tuned: bool = True,
                    **row: float) -> PPOConfig:  # fmt: skip
    """The :class:`PPOConfig` of ``BRAX_PPO[task]``, its entries updated by ``row`` (``KeyError``
    naming the tasks for an unknown one), with the task's :data:`BRAX_PPO_TUNED` fields over it
    unless ``tuned=False`` (those win over ``row``: ``tuned=False`` gives the row alone).

    brax collects ``batch_size · num_minibatches`` unrolls of ``unroll_length`` steps per training
    step and makes ``num_updates_per_batch`` passes of ``num_minibatches`` mini-batches over them.
    Here one iteration is ``num_envs`` lanes × ``unroll_length`` (N) steps, so N = those unrolls per
    lane × ``unroll_length``. The networks and the policy are brax's (``make_ppo_networks`` defaults:
    policy 4 × 32 and value 5 × 256 with swish, no batch-norm; the action is ``tanh`` of a Gaussian
    sample whose σ(s) = softplus(·) + 0.001 comes from an output layer of the policy, starting at
    softplus(0) ≈ 0.7, with the squashed action's entropy), clip ε 0.3 and GAE λ 0.95 (brax's
    defaults), normalised observations and advantages, one Adam learning rate for both.

    Two updates (``segments``; None: the task's entry of :data:`BRAX_PPO_SEGMENTS`):

    * ``segments=True``, brax's own update: mini-batches of ``batch_size`` unrolls of ``unroll_length``
      steps drawn from all lanes, advantages and value targets recomputed on each with the current
      critic (``advantage_segment``), actor and critic stepping together ``num_updates_per_batch ·
      num_minibatches`` times per batch.
    * ``segments=False``, the thesis's update (Algorithm 8): advantages once per batch, a mini-batch
      holds ``batch_size · unroll_length`` transitions rounded down to a multiple of the lanes (B / K
      from every lane); actor and critic each take as many steps as brax's passes cover, the critic
      on each batch first (``critic_first``), which brings the advantages nearer to brax's.

    Which update each task takes, as measured beside brax's PPO: ``benchmarks/results/why-presets.md``
    § brax PPO update.
    """
    if task not in BRAX_PPO:
        raise KeyError(f"no brax PPO settings for {task!r}; known: {', '.join(BRAX_PPO)}")
    segments = task in BRAX_PPO_SEGMENTS if segments is None else segments
    config = ppo_config_of_row({**BRAX_PPO[task], **row}, action_size, segments)
    return config.replace(**(BRAX_PPO_TUNED.get(task, {}) if tuned else {}))


def ppo_config_of_row(b: Mapping[str, Any], action_size: int, segments: bool) -> PPOConfig:
    """The :class:`PPOConfig` of a row of brax's ``ppo.train`` settings ``b`` (the :data:`BRAX_COLUMNS`;
    ``normalize_observations``, default True, where the row has it; other entries are not ours to
    convert): the conversion :func:`brax_ppo_config` describes, brax's own update with ``segments``."""
    lanes = int(b["num_envs"])
    unrolls = max(1, int(b["batch_size"] * b["num_minibatches"]) // lanes)
    n = unrolls * int(b["unroll_length"])
    minibatch = max(lanes, (int(b["batch_size"] * b["unroll_length"]) // lanes) * lanes)
    updates = max(1, round(b["num_updates_per_batch"] * lanes * n / minibatch))
    brax_update = {}
    if segments:
        brax_update = dict(advantage_segment=int(b["unroll_length"]), critic_first=False,
                           minibatch_size=int(b["batch_size"] * b["unroll_length"]),
                           actor_updates=int(b["num_updates_per_batch"] * b["num_minibatches"]),
                           critic_updates=int(b["num_updates_per_batch"] * b["num_minibatches"]))  # fmt: skip
    config = PPOConfig(
        num_envs=lanes, unroll_length=n, minibatch_size=minibatch, actor_updates=updates, critic_updates=updates,
        total_steps=int(b["num_timesteps"]), gamma=float(b["discounting"]), gae_lambda=0.95, clip_eps=0.3,
        entropy_coef=float(b["entropy_cost"]), reward_scale=float(b["reward_scaling"]),
        actor_lr=float(b["learning_rate"]), critic_lr=float(b["learning_rate"]), sigma=(0.7,) * action_size,
        learn_std=True, state_std=True, tanh_actions=True, activation="swish", critic_first=True,
        normalize_obs=bool(b.get("normalize_observations", True)), normalize_advantages=True, batch_norm=False,
        actor_hidden=(32, 32, 32, 32), critic_hidden=(256,) * 5, episode_length=int(b["episode_length"]),
        reset_refresh=1.0,
    )  # fmt: skip
    return config.replace(**brax_update)


BRAX_PPO_SEGMENTS = ("halfcheetah", "reacher")
"""The tasks whose ``brax`` preset trains with brax's own update (:func:`brax_ppo_config`'s
``segments``), ahead of the thesis's update there; the others are ahead with the thesis's."""

BRAX_PPO_TUNED: dict[str, dict[str, float | str]] = {
    # Adam at 1e-3 (MuJoCo Playground's dm_control suite PPO setting) annealed linearly to 0 over the run
    # (purejaxrl's and CleanRL's anneal_lr), the global gradient norm clipped at 1.
    "reacher": dict(lr_schedule="linear", actor_lr=1e-3, critic_lr=1e-3, max_grad_norm=1.0),
}
"""Our :class:`PPOConfig` fields over a task's converted :data:`BRAX_PPO` row (:func:`brax_ppo_config`'s
``tuned``) on the tasks where they take ours past brax's own PPO and the row alone does not.

reacher's, as measured: ``benchmarks/results/why-presets.md`` § brax PPO tuned."""

BRAX_SAC_COLUMNS = ("num_timesteps", "num_envs", "batch_size", "grad_updates_per_step", "discounting",
                    "reward_scaling", "learning_rate", "episode_length", "max_replay_size", "min_replay_size")
"""The columns of :data:`BRAX_SAC`: the arguments of brax's ``sac.train`` they are."""

# brax's training notebook (github.com/google/brax, notebooks/training.ipynb, `train_fn`): the tasks it
# trains with SAC, with their settings as given there.
BRAX_SAC: dict[str, dict[str, float]] = {
    task: dict(zip(BRAX_SAC_COLUMNS, row, strict=True))
    for task, row in {
        #            steps      envs batch upd  gamma  rs  lr    ep    replay     min
        "hopper":   (6_553_600, 128, 512,  64, 0.997, 30, 6e-4, 1000, 1_048_576, 8192),
        "walker2d": (7_864_320, 128, 128,  32, 0.997, 5,  6e-4, 1000, 1_048_576, 8192),
    }.items()
}  # fmt: skip
"""brax's SAC settings per brax task, in brax's terms (converted by :func:`brax_sac_ddpg_config`)."""


TD3_OWN = dict(updates_per_env_step=1, batch_size=256, learning_rate=3e-4, random_start=True, gamma=0.99,
               reward_scale=1.0, noise_scale=0.1)
"""TD3's own settings (Fujimoto et al. 2018; also Stable-Baselines3's TD3 defaults) for brax's SAC tasks:
one update per env step on mini-batches of 256 at learning rate 3e-4, uniform random actions until
learning starts, γ 0.99 on unscaled rewards, exploration σ 0.1. :func:`brax_sac_ddpg_config` puts them
in place of the row's unless ``own_settings=False``, with a task's :data:`BRAX_SAC_TUNED` entries over them.

As measured: ``benchmarks/results/why-presets.md`` § TD3 own settings."""

BRAX_SAC_TUNED: dict[str, dict[str, float]] = {
    # two updates per env step (an update-to-data ratio of 2) instead of TD3's one
    "hopper": dict(updates_per_env_step=2),
    "walker2d": dict(updates_per_env_step=2),
}
"""Entries of :data:`TD3_OWN` replaced per task (:func:`brax_sac_ddpg_config`'s ``tuned``), measured with
TD3 (DDPG takes them too, unmeasured).

Why: ``benchmarks/results/why-presets.md`` § brax SAC tuned."""


def brax_sac_ddpg_config(task: str, own_settings: bool = True, tuned: bool = True, **row: float) -> DDPGConfig:
    """The DDPG :class:`DDPGConfig` of ``BRAX_SAC[task]`` (entries updated by ``row``; ``KeyError`` naming
    the tasks for an unknown one); TD3 adds ``train.td3.TD3_SETTINGS``.

    brax's SAC steps ``num_envs`` envs once, then makes ``grad_updates_per_step`` updates on
    mini-batches of ``batch_size``, from a memory of ``max_replay_size`` filled to ``min_replay_size``
    first: here ``num_envs`` lanes, ``unroll_length`` 1, the same memory, ``learning_starts =
    min_replay_size``, brax's SAC networks (2 × 256) and τ 0.005, normalised observations, Gaussian
    exploration where SAC samples its stochastic policy. The rest:

    * ``own_settings=True`` (default), :data:`TD3_OWN` with the task's :data:`BRAX_SAC_TUNED` entries over
      it unless ``tuned=False``: ``num_envs`` updates per iteration (one per env step; two with the tuned
      entries of hopper and walker2d) on mini-batches of 256 at learning rate 3e-4, random actions before
      learning starts (``random_start``), γ 0.99, rewards unscaled, exploration σ 0.1;
    * ``own_settings=False``: the row's — ``grad_updates_per_step`` updates on ``batch_size`` at its
      ``learning_rate``, its ``discounting`` and ``reward_scaling``, the actor acting from the first step
      with σ 0.1 (TD3's)."""
    if task not in BRAX_SAC:
        raise KeyError(f"no brax SAC settings for {task!r}; known: {', '.join(BRAX_SAC)}")
    own = {**TD3_OWN, **(BRAX_SAC_TUNED.get(task, {}) if tuned else {})} if own_settings else None
    return ddpg_config_of_sac_row({**BRAX_SAC[task], **row}, own)


def ddpg_config_of_sac_row(b: Mapping[str, Any], own: Mapping[str, Any] | None) -> DDPGConfig:
    """The :class:`DDPGConfig` of a row of brax's ``sac.train`` settings ``b`` (the :data:`BRAX_SAC_COLUMNS`;
    ``normalize_observations``, default True, where the row has it): the conversion
    :func:`brax_sac_ddpg_config` describes, with ``own`` (:data:`TD3_OWN`'s keys) in place of the row's
    update settings, or the row's where ``own`` is None."""
    lanes = int(b["num_envs"])
    own_settings, o = own is not None, own or {}
    if own_settings:
        updates, batch, lr = lanes * int(o["updates_per_env_step"]), int(o["batch_size"]), float(o["learning_rate"])
        gamma, scale, sigma = float(o["gamma"]), float(o["reward_scale"]), float(o["noise_scale"])
    else:
        updates, batch, lr = int(b["grad_updates_per_step"]), int(b["batch_size"]), float(b["learning_rate"])
        gamma, scale, sigma = float(b["discounting"]), float(b["reward_scaling"]), 0.1
    return DDPGConfig(
        schedule="steps", total_steps=int(b["num_timesteps"]), num_envs=lanes, unroll_length=1,
        updates_per_iteration=updates, batch_size=batch, buffer_size=int(b["max_replay_size"]),
        learning_starts=int(b["min_replay_size"]), random_start=own_settings and bool(o["random_start"]),
        gamma=gamma, reward_scale=scale, actor_lr=lr, critic_lr=lr, tau=0.005,
        normalize_obs=bool(b.get("normalize_observations", True)), actor_hidden=(256, 256),
        critic_hidden=(256, 256), noise="gaussian", noise_scale=(sigma,), episode_length=int(b["episode_length"]),
    )  # fmt: skip


def _brax_task_of(env_name: str, table: dict) -> str | None:
    """The task of ``env_name`` (``brax:<task>``) if ``table`` has a row for it, else None."""
    prefix, _, task = env_name.partition(":")
    return task if prefix == "brax" and task in table else None


def brax_task(env_name: str) -> str | None:
    """The :data:`BRAX_PPO` task of ``env_name`` (``brax:<task>``), or None."""
    return _brax_task_of(env_name, BRAX_PPO)


def brax_sac_task(env_name: str) -> str | None:
    """The :data:`BRAX_SAC` task of ``env_name`` (``brax:<task>``), or None."""
    return _brax_task_of(env_name, BRAX_SAC)


PLAYGROUND_PEERS = {"ppo": "ppo", "ddpg": "sac", "td3": "sac", "sac": "sac"}
"""Our algorithm -> the brax trainer whose MuJoCo Playground settings its ``playground`` preset converts."""


def playground_row(env_name: str, peer: str = "ppo") -> dict[str, Any] | None:
    """MuJoCo Playground's own settings of brax's ``ppo.train`` (``peer='ppo'``: its ``brax_ppo_config``) or
    ``sac.train`` (``'sac'``: ``brax_sac_config``) for ``env_name`` (``playground:<Name>`` or ``<Name>``) of
    its ``dm_control_suite`` (``mujoco_playground.config.dm_control_suite_params``), as a dict in brax's
    argument names (``network_factory`` a dict of its keywords); None for an env of another suite.

    Raises:
      PlaygroundMissingError: MuJoCo Playground is not installed (a ``ValueError`` naming the extra).
    """
    from envs_mjx import playground

    name = env_name.removeprefix(playground.PREFIX)
    playground.require(f"--env {playground.PREFIX}{name}")
    if playground.suite_of(name) != "dm_control_suite":
        return None
    from mujoco_playground.config import dm_control_suite_params as params

    config = (params.brax_ppo_config if peer == "ppo" else params.brax_sac_config)(name)
    return config.to_dict()


def playground_task(env_name: str | None, algo: str = "ppo") -> str | None:
    """The Playground name of ``env_name`` (``playground:<Name>``) if Playground has settings for ``algo``'s
    peer there (:func:`playground_row`; ``algo`` one of :data:`PLAYGROUND_PEERS`), else None."""
    from envs_mjx import playground

    if not env_name or not env_name.startswith(playground.PREFIX) or algo not in PLAYGROUND_PEERS:
        return None
    playground.require(f"--env {env_name}")
    name = env_name.removeprefix(playground.PREFIX)
    if playground.suite_of(name) is None:
        return None
    return name if playground_row(name, PLAYGROUND_PEERS[algo]) is not None else None


def _playground_row_for(env_name: str, peer: str, row: Mapping[str, Any]) -> dict[str, Any]:
    """:func:`playground_row` with ``row`` over it; ``ValueError`` for an env without one."""
    base = playground_row(env_name, peer) if env_name.startswith("playground:") else None
    if base is None:
        raise ValueError(f"--preset playground: {env_name!r} has no MuJoCo Playground {peer.upper()} settings; it "
                         "needs --env playground:<Name> of Playground's dm_control_suite")  # fmt: skip
    b = {**base, **row}
    if int(b.get("action_repeat", 1)) != 1:
        raise ValueError(f"--preset playground: Playground's settings for {env_name} repeat each action "
                         f"{b['action_repeat']} times (action_repeat), which train.* do not; use --preset cpu")
    return b


def playground_ppo_config(env_name: str, action_size: int, segments: bool = True, **row: Any) -> PPOConfig:
    """The :class:`PPOConfig` of MuJoCo Playground's ``brax_ppo_config`` for ``env_name``
    (``playground:<Name>`` of its ``dm_control_suite``), entries updated by ``row``: converted as
    :func:`brax_ppo_config` converts brax's rows (:func:`ppo_config_of_row`; brax's networks, tanh-squashed
    actions, normalised observations), brax's own update by default (``segments``), as Playground trains
    with brax's PPO. Playground's dm_control rows: 60 M env steps (100 M on AcrobotSwingup*, SwimmerSwimmer6,
    WalkerRun), 2048 envs, batch 1024, 32 mini-batches, unrolls of 30, 16 passes, γ 0.995 (0.95 on
    BallInCup and FingerSpin), rewards × 10, Adam 1e-3, entropy 1e-2, episodes of the env's 1000 steps.

    Raises:
      ValueError: ``env_name`` has no such settings, or they repeat actions (``action_repeat`` > 1).
      PlaygroundMissingError: MuJoCo Playground is not installed.
    """
    return ppo_config_of_row(_playground_row_for(env_name, "ppo", row), action_size, segments)


def playground_sac_ddpg_config(env_name: str, own_settings: bool = True, **row: Any) -> DDPGConfig:
    """The DDPG :class:`DDPGConfig` of MuJoCo Playground's ``brax_sac_config`` for ``env_name``
    (``playground:<Name>`` of its ``dm_control_suite``), entries updated by ``row``: converted as
    :func:`brax_sac_ddpg_config` converts brax's SAC rows (:func:`ddpg_config_of_sac_row`), with
    :data:`TD3_OWN` unless ``own_settings=False``; TD3 adds ``train.td3.TD3_SETTINGS``. Playground's rows:
    5 M env steps (10 M on some tasks), 128 envs, memory 4 194 304 filled to 8192 first, 8 updates of 512
    per step at 1e-3, γ 0.99; its SAC critic's layer norm has no counterpart here.

    Raises:
      ValueError: ``env_name`` has no such settings, or they repeat actions (``action_repeat`` > 1).
      PlaygroundMissingError: MuJoCo Playground is not installed.
    """
    return ddpg_config_of_sac_row(_playground_row_for(env_name, "sac", row), TD3_OWN if own_settings else None)
