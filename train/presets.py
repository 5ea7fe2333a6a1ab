"""Hyper-parameter presets per (algorithm, environment).

PPO presets:

* ``thesis`` — the thesis's setting: K = 4 workers; arm: N = 8, 5 actor and 5 critic updates on
  32 transitions, 2000 episodes' worth of steps (Table 5.2, §5.4); mobile robot: N = 16, 8 updates
  on 32 of 64, 3000 episodes, piecewise RSI + shrinking early-termination limit (Table 5.3, §5.5).
  The arm keeps the thesis's batch-norm actor (batch renormalisation, moving averages decaying
  at 0.999).
* ``cpu`` — a few dozen lanes, sized for a 2-core CPU (the default without an accelerator);
  larger learning rates and no batch-norm (more stable here than the thesis's BN actor).
* ``fast`` — thousands of lanes per GPU (the default with an accelerator); PPO's on ``arm7`` grows with the
  devices (:func:`arm_fast_on_devices`).
* ``brax`` (PPO, DDPG and TD3) — PPO: brax's published PPO settings for its standard tasks
  (:data:`BRAX_PPO`, converted by :func:`brax_ppo_config`, with our fields of :data:`BRAX_PPO_TUNED`
  over the tasks it names); DDPG and TD3: brax's SAC lanes and memory with TD3's own update settings and
  our tuned entries over them (:data:`BRAX_SAC`, :data:`TD3_OWN`, :data:`BRAX_SAC_TUNED`,
  :func:`brax_sac_ddpg_config`).
* ``playground`` (PPO, DDPG and TD3) — MuJoCo Playground's own brax settings for ``--env playground:<Name>``
  of its ``dm_control_suite`` (``brax_ppo_config`` / ``brax_sac_config``), converted as brax's rows are
  (:func:`playground_ppo_config`, :func:`playground_sac_ddpg_config`).
* ``auto`` — ``brax`` for the tasks of :data:`BRAX_PPO` (PPO) or :data:`BRAX_SAC` (DDPG, TD3), ``playground``
  where Playground has settings for the env, else ``fast`` on a GPU/TPU backend, else ``cpu``.

Environment settings (reward, physics mode, …) stay apart from algorithm settings: a preset
returns a :class:`PPOConfig` and env overrides separately.

The presets are settings only; the measurements that chose them are in
``benchmarks/results/why-presets.md``, by section.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from typing import Any

import jax

from envs_mjx.unicycle import UnicycleConfig
from jaxrl_robot import parallel
from jaxrl_robot.agents.a2c import A2CConfig, A3CConfig
from jaxrl_robot.agents.ddpg import DDPGConfig
from jaxrl_robot.agents.ppo import PPOConfig

__all__ = [
    "a2c_preset",
    "arm_fast_on_devices",
    "ARM_FAST_STEPS",
    "BRAX_COLUMNS",
    "BRAX_PPO",
    "brax_ppo_config",
    "BRAX_PPO_SEGMENTS",
    "BRAX_PPO_TUNED",
    "BRAX_SAC",
    "BRAX_SAC_COLUMNS",
    "brax_sac_ddpg_config",
    "brax_sac_task",
    "BRAX_SAC_TUNED",
    "brax_task",
    "ddpg_config_of_sac_row",
    "ddpg_env_overrides",
    "DDPG_PRESETS",
    "distribute",
    "lstm_variant",
    "PLAYGROUND_PEERS",
    "playground_ppo_config",
    "playground_row",
    "playground_sac_ddpg_config",
    "playground_task",
    "ppo_config_of_row",
    "ppo_default_devices",
    "ppo_env_overrides",
    "ppo_preset",
    "PPO_PRESETS",
    "PRESETS",
    "RACING_ENV",
    "resolve_preset",
    "TD3_OWN",
    "tracking_schedule",
    "two_stage_variant",
    "UNICYCLE_A_P",
    "unicycle_a_p",
    "UNICYCLE_A_P_FAST",
]

PPO_PRESETS = ("auto", "thesis", "cpu", "fast", "brax", "playground")
PRESETS = ("auto", "thesis", "cpu", "fast")
"""The presets of every algorithm; ``brax`` and ``playground`` are PPO's, DDPG's and TD3's (:data:`DDPG_PRESETS`)."""


def resolve_preset(name: str, env_name: str | None = None, algo: str = "ppo") -> str:
    """``auto`` → ``brax`` for a PPO run on a task of :data:`BRAX_PPO` or a DDPG / TD3 run on one of
    :data:`BRAX_SAC`, ``playground`` for such a run on a ``playground:<Name>`` env with MuJoCo Playground's
    settings (:func:`playground_task`), else ``fast`` on an accelerator backend, else ``cpu``; other names
    unchanged (validated: ``brax`` and ``playground`` are PPO's, DDPG's and TD3's)."""
    valid, table = {"ppo": (PPO_PRESETS, BRAX_PPO), "ddpg": (DDPG_PRESETS, BRAX_SAC), "td3": (DDPG_PRESETS, BRAX_SAC),
                    "sac": (DDPG_PRESETS, BRAX_SAC)}.get(algo, (PRESETS, {}))  # fmt: skip
    if name not in valid:
        raise ValueError(f"unknown preset {name!r}; valid presets: {', '.join(valid)}")
    if name == "auto":
        if env_name is not None and _brax_task_of(env_name, table):
            return "brax"
        if playground_task(env_name, algo):
            return "playground"
        return "fast" if parallel.on_accelerator() else "cpu"
    return name


def _family(env_name: str) -> str:
    """``arm``, ``tracking``, ``racing`` or ``other``: the family of ``env_name`` whose presets it takes."""
    base = env_name.split(":")[-1]
    if base in ("arm7", "arm7_precise"):
        return "arm"
    if base in ("unicycle", "scara"):
        return "tracking"
    if base == "racecar":
        return "racing"
    return "other"


def _precise_arm(env_name: str) -> bool:
    """Whether ``env_name`` is ``arm7_precise`` (1 cm goal threshold): PPO and A2C/A3C learn σ there
    (why: ``benchmarks/results/why-presets.md`` § PPO arm7_precise)."""
    return env_name.split(":")[-1] == "arm7_precise"


DDPG_PRESETS = ("auto", "thesis", "cpu", "fast", "brax", "playground")
"""DDPG's and TD3's presets: ``brax`` is :func:`brax_sac_ddpg_config` of the env's :data:`BRAX_SAC` task
(hopper's row for other envs, with the env's own episode length); ``playground`` is
:func:`playground_sac_ddpg_config` of a ``playground:<Name>`` env."""


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


def tracking_schedule(rsi_end: float = 2 / 3, narrow_end: float = 5 / 6, origin_start: float | None = None) -> tuple:
    """Thesis §5.5 curriculum as a PPO ``schedule`` for the tracking envs' episode parameters.

    Until ``rsi_end`` of training: start anywhere on the reference, early-termination limit 20;
    then from ¼-½ of the reference, limit 15; from ``narrow_end`` on: from the first quarter,
    limit 10 (episodes 0-2000, 2000-2500, 2500-3000 of 3000); from ``origin_start`` on (if given):
    from ``t = 0`` (the LSTM run of §5.7: 2000 / 400 / 400 / 200 episodes).
    """
    stages = [(0.0, 0.0, 1.0, 20.0), (rsi_end, 0.25, 0.5, 15.0), (narrow_end, 0.0, 0.25, 10.0)]
    if origin_start is not None:
        stages.append((origin_start, 0.0, 0.0, 10.0))
    out = []
    for start, lo, hi, limit in stages:
        out += [(start, "start_lo", lo), (start, "start_hi", hi), (start, "et_limit", limit)]
    return tuple(out)


def ppo_env_overrides(
    name: str, env_name: str, pretrain: str = "none", policy: str = "mlp", trajectory: str | None = None
) -> dict:
    """Env settings a preset needs (the user's ``--env-config`` goes on top); ``pretrain``,
    ``policy``: PPO's ``--pretrain`` and ``--policy``; ``trajectory``: the unicycle's (None: the
    env's default), which with them picks the unicycle's ``a_p`` (:func:`unicycle_a_p`).

    ``arm7`` under ``thesis`` and ``cpu`` runs in ``kinematic`` mode — the thesis's setting, and
    the one that is fast on a CPU: MJX's ``pd`` physics of the 7-link chain compiles and runs
    slowly on CPUs (see the foundation benchmark). ``fast`` keeps the env's default (``pd``).

    ``unicycle`` trains with a sharper position term than Eq. 3.23's ``a_p = 1`` (:func:`unicycle_a_p`;
    why: ``benchmarks/results/why-presets.md`` § unicycle a_p); ``thesis`` keeps a_p = 1.
    """
    name = resolve_preset(name)
    if _family(env_name) == "arm" and name in ("thesis", "cpu"):
        return {"mode": "kinematic"}
    if env_name.split(":")[-1] == "unicycle" and name in UNICYCLE_A_P:
        method = "two-stage" if pretrain == "action-search" else policy
        return {"a_p": unicycle_a_p(name, method, trajectory)}
    return {}


UNICYCLE_A_P = {"cpu": 100.0, "fast": 300.0}
"""Eq. 3.23's ``a_p`` of the unicycle under the ``cpu`` and ``fast`` presets (every algorithm), except
:data:`UNICYCLE_A_P_FAST` (why: ``benchmarks/results/why-presets.md`` § unicycle a_p)."""

UNICYCLE_A_P_FAST = {("two-stage", "sine"): 1000.0, ("lstm", "sine"): 1000.0, ("distributed", "sine"): 1000.0}
"""``(method, trajectory) -> a_p`` under ``fast`` where 1000 tracked better than 300
(``benchmarks/results/why-presets.md`` § unicycle a_p)."""


def unicycle_a_p(name: str, method: str, trajectory: str | None = None) -> float:
    """The unicycle's ``a_p`` under preset ``name`` (``cpu`` or ``fast``) for ``method`` (PPO's
    ``mlp``, ``lstm``, ``two-stage``; ``ddpg``, ``distributed``, ``td3``, ``distributed-td3``) on
    ``trajectory`` (None: the env's default)."""
    trajectory = trajectory or UnicycleConfig.trajectory
    if name == "fast":
        return UNICYCLE_A_P_FAST.get((method, trajectory), UNICYCLE_A_P[name])
    return UNICYCLE_A_P[name]


RACING_ENV = {"road": "random", "opponent_speeds": True, "opponent_offsets": True, "distance_scale": "log",
              "end_on_collision": True}
"""``racecar`` under ``cpu`` and ``fast``: train on a bank of generated roads, see the opponents' closing
speeds and offsets across the road, log-scaled distances, and end an episode at a collision
(why: ``benchmarks/results/why-presets.md`` § racing env)."""


def ddpg_env_overrides(name: str, env_name: str, method: str = "ddpg", trajectory: str | None = None) -> dict:
    """Env settings a DDPG preset needs (the user's ``--env-config`` goes on top): a sharper reward.
    ``method`` (``ddpg``, ``distributed``, ``td3``, ``distributed-td3``) and ``trajectory`` pick the
    unicycle's ``a_p`` (:func:`unicycle_a_p`).

    ``unicycle``: the sharper position term of :func:`ppo_env_overrides` (:data:`UNICYCLE_A_P`).
    ``scara``: ``cpu`` Eq. 3.22's coefficient 50 instead of 2; ``fast`` 1000 and the ``extended``
    observation (the error to the next reference point).  ``racecar`` under ``cpu`` and ``fast``:
    :data:`RACING_ENV`.  ``thesis`` keeps Eq. 3.22-3.23.  Why: ``benchmarks/results/why-presets.md``
    § unicycle a_p, § scara reward.
    """
    name = resolve_preset(name)
    if name not in ("cpu", "fast"):
        return {}
    scara = {"cpu": {"reward_coef": 50.0}, "fast": {"reward_coef": 1000.0, "observation": "extended"}}[name]
    sharper = {"unicycle": {"a_p": unicycle_a_p(name, method, trajectory)}, "scara": scara, "racecar": RACING_ENV}
    return sharper.get(env_name.split(":")[-1], {})


def ppo_preset(
    name: str, env_name: str, episode_length: int, action_size: int, policy: str = "mlp", pretrain: str = "none",
    trajectory: str | None = None, devices: int = 1,
) -> tuple[PPOConfig, dict]:
    """``(PPOConfig, env overrides)`` of preset ``name`` for ``env_name`` (overrides: :func:`ppo_env_overrides`).

    Args:
      name: one of :data:`PPO_PRESETS`.
      env_name: registry name (``arm7``, ``unicycle``, ``scara``) or ``brax:<name>``.
      episode_length: the env's time limit (sizes the thesis budgets given in episodes).
      action_size: the env's action dimension (sizes σ for envs without a thesis value).
      policy: ``'lstm'``: the recurrent variant (:func:`lstm_variant`).
      pretrain: ``'action-search'``: two-stage training (:func:`two_stage_variant`).
      trajectory: the unicycle's trajectory for the env overrides (None: the env's default).
      devices: the devices the lanes are spread over (``--devices``; 0: every device): ``fast`` on ``arm7``
        scales its lanes with them (:func:`arm_fast_on_devices`).
    """
    env_overrides = ppo_env_overrides(resolve_preset(name, env_name), env_name, pretrain, policy, trajectory)
    config = _ppo_base_preset(name, env_name, episode_length, action_size, policy == "mlp" and pretrain == "none")
    if resolve_preset(name, env_name) == "fast" and env_name == "arm7" and policy == "mlp" and pretrain == "none":
        config = arm_fast_on_devices(config, devices or jax.device_count())
    if policy == "lstm":
        config = lstm_variant(config, resolve_preset(name), _family(env_name))
    if pretrain != "none":
        config = two_stage_variant(config, resolve_preset(name), episode_length).replace(pretrain=pretrain)
    return config, env_overrides


ARM_FAST_STEPS = {1: 3_000_000, 2: 4_000_000, 4: 5_000_000}
"""PPO ``fast`` on ``arm7``: env steps by device count, with 4 096 lanes and mini-batches of 8 192 per device
(why: ``benchmarks/results/why-presets.md`` § PPO fast arm). Other counts: 3 M + 1 M per doubling."""


def arm_fast_on_devices(config: PPOConfig, devices: int) -> PPOConfig:
    """PPO ``fast`` on ``arm7`` over ``devices`` devices: 4 096 lanes and mini-batches of 8 192 per device (the
    same 4 mini-batches per epoch), the steps of :data:`ARM_FAST_STEPS`; more devices learn on more lanes at
    once and need somewhat more env steps, which they run faster."""
    devices = max(1, devices)
    steps = ARM_FAST_STEPS.get(devices, 3_000_000 + 1_000_000 * round(math.log2(devices)))
    return config.replace(num_envs=4096 * devices, minibatch_size=8192 * devices, total_steps=steps)


def ppo_default_devices(name: str, env_name: str, policy: str = "mlp", pretrain: str = "none") -> int:
    """``--devices`` when the command line gives none: 1 for PPO ``fast`` on ``arm7`` (the main job) in a run of
    one process, 0 (every device) otherwise. The main job's 4 096 lanes leave even one GPU waiting on each step's
    latency rather than its arithmetic, so a second GPU adds its all-reduce and lanes without making an
    iteration faster: on two H200s it trained for 5.7–7.0 s (4 M env steps) against 4.6–4.7 s (3 M) on one,
    and reached 95 % after 6.6–8.3 s of training against 4.3–4.8 s
    (``benchmarks/results/gpu-nvidia_h200-x2-main_job-x2-2gpu.md``, ``gpu-nvidia_h200-time_to_solve-arm7-x2.md``).
    ``--devices N`` still spreads it (:func:`arm_fast_on_devices`)."""
    main_job = resolve_preset(name, env_name) == "fast" and env_name == "arm7" and (policy, pretrain) == (
        "mlp", "none")
    return 1 if main_job and jax.process_count() == 1 else 0


def lstm_variant(config: PPOConfig, name: str, family: str) -> PPOConfig:
    """``config`` with the recurrent networks of thesis §5.7: FC 256 → LSTM 256 → FC for actor and
    critic, sequences of 10 steps, each sequence in two of the 8 updates per batch (``thesis``: K = 4
    lanes × 40 steps, mini-batches of one sequence per lane); tracking envs: the curriculum ends with
    200 of 3000 episodes from ``t = 0``; under ``fast`` twice the feed-forward budget
    (``benchmarks/results/why-presets.md`` § PPO LSTM).
    ``brax``: the task's lanes and unrolls (whole sequences), the recurrent policy's clipped actions
    and relu (it has neither the squashed action nor a σ from the state)."""
    if name in ("brax", "playground"):  # each sequence in two of the 8 updates
        lanes, unroll = config.num_envs, max(10, config.unroll_length // 10 * 10)
        minibatch = lanes * 10 * max(1, unroll // 40)
        config = config.replace(tanh_actions=False, clip_actions=True, state_std=False, activation="relu")
    else:
        lanes, unroll, minibatch = {"thesis": (4, 40, 40), "cpu": (32, 40, 320), "fast": (4096, 20, 40960)}[name]
    config = config.replace(
        policy="lstm", actor_hidden=(256,), critic_hidden=(256,), lstm_size=256, seq_length=10, batch_norm=False,
        num_envs=lanes, unroll_length=unroll, minibatch_size=minibatch, actor_updates=8, critic_updates=8,
        total_steps=config.total_steps * (2 if name == "fast" and family == "tracking" else 1),
    )  # fmt: skip
    if family == "tracking":
        config = config.replace(schedule=tracking_schedule(2 / 3, 0.8, 14 / 15))
    return config


def two_stage_variant(config: PPOConfig, name: str, episode_length: int) -> PPOConfig:
    """``config`` with action-search pre-training first (thesis §5.6): 200 episodes of pre-training,
    then PPO for two thirds of the preset's episodes (2000 instead of 3000 under ``thesis``)."""
    pretrain = 200 * episode_length
    return config.replace(pretrain_episodes=200, total_steps=pretrain + (2 * config.total_steps) // 3)


def _ppo_base_preset(name: str, env_name: str, episode_length: int, action_size: int,
                     segments: bool = True) -> PPOConfig:  # fmt: skip
    """The feed-forward PPO preset (see :func:`ppo_preset`); ``segments=False``: the ``brax`` preset
    without brax's own update (which needs the feed-forward policy and no pre-training)."""
    name = resolve_preset(name, env_name)
    family = _family(env_name)
    if name == "brax":
        task = brax_task(env_name) or "inverted_pendulum"
        return brax_ppo_config(task, action_size, None if segments else False)
    if name == "playground":  # the env's own time limit (Playground's row: its default config's)
        return playground_ppo_config(env_name, action_size, segments, episode_length=episode_length)
    if family == "arm":
        # Table 5.2 and §5.4: 2 x 200 nets, batch-norm actor, σ = [0.8, 0.8, 0.1]. Why the rest: why-presets.md
        # § PPO thesis arm, § PPO cpu arm, § PPO fast arm.
        base = PPOConfig(
            actor_lr=1e-4, critic_lr=5e-4, clip_eps=0.2, gamma=0.9, gae_lambda=0.95, sigma=(0.8, 0.8, 0.1),
            actor_hidden=(200, 200), critic_hidden=(200, 200), batch_norm=True,
        )
        presets = {
            "thesis": dict(num_envs=4, unroll_length=8, minibatch_size=32, actor_updates=5, critic_updates=5,
                           total_steps=2000 * episode_length),
            "cpu": dict(num_envs=32, unroll_length=16, minibatch_size=256, actor_updates=8, critic_updates=8,
                        actor_lr=3e-4, critic_lr=1e-3, batch_norm=False, total_steps=400_000),
            "fast": dict(num_envs=4096, unroll_length=8, minibatch_size=8192, actor_updates=8, critic_updates=8,
                         actor_lr=1e-3, critic_lr=1e-3, batch_norm=False, total_steps=12_000_000, reset_refresh=1.0),
        }
        if not _precise_arm(env_name):  # the main job on a CPU: why-presets.md § PPO cpu arm
            presets["cpu"].update(total_steps=150_000, lr_schedule="linear")
    elif family == "tracking":
        # Table 5.3 and §5.5: 256-unit nets, σ = [0.1, 0.01] (unicycle), RSI + early termination.
        unicycle = env_name.endswith("unicycle")
        sigma = (0.1, 0.01) if unicycle else (0.1,) * action_size
        tuned = dict(sigma=(0.1, 0.05) if unicycle else sigma, learn_std=True, normalize_obs=True)
        if unicycle:
            # γ = 0.99 instead of Table 5.3's 0.9 and the adaptive-KL objective: why-presets.md § PPO tracking.
            tuned.update(gamma=0.99, objective="kl")
        base = PPOConfig(
            actor_lr=1e-4, critic_lr=5e-4, clip_eps=0.2, gamma=0.9, gae_lambda=0.95, sigma=sigma,
            actor_hidden=(256, 256), critic_hidden=(256, 256), batch_norm=False, schedule=tracking_schedule(),
        )
        presets = {
            "thesis": dict(num_envs=4, unroll_length=16, minibatch_size=32, actor_updates=8, critic_updates=8,
                           total_steps=3000 * episode_length),
            # A learned σ and normalised observations: why-presets.md § PPO tracking.
            "cpu": dict(num_envs=32, unroll_length=16, minibatch_size=256, actor_updates=8, critic_updates=8,
                        actor_lr=3e-4, critic_lr=1e-3, total_steps=3_000_000, **tuned),
            "fast": dict(num_envs=4096, unroll_length=16, minibatch_size=16384, actor_updates=8, critic_updates=8,
                         actor_lr=1e-3, critic_lr=1e-3, total_steps=30_000_000, **tuned),
        }
        if unicycle:
            # 1 M steps (about 2 min on a 2-core CPU; why-presets.md § PPO tracking).
            presets["cpu"]["total_steps"] = 1_000_000
    else:
        base = PPOConfig(sigma=(0.5,) * action_size, actor_hidden=(64, 64), critic_hidden=(64, 64), batch_norm=False,
                         gamma=0.99, normalize_obs=True, actor_lr=3e-4, critic_lr=3e-4)
        presets = {
            "thesis": dict(num_envs=4, unroll_length=8, minibatch_size=32, actor_updates=5, critic_updates=5,
                           total_steps=200_000),
            "cpu": dict(num_envs=32, unroll_length=16, minibatch_size=256, actor_updates=8, critic_updates=8,
                        total_steps=500_000),
            "fast": dict(num_envs=2048, unroll_length=16, minibatch_size=8192, actor_updates=4, critic_updates=4,
                         total_steps=10_000_000),
        }
    config = base.replace(**presets[name])
    return _precise(config) if _precise_arm(env_name) else config


def _precise(config: PPOConfig) -> PPOConfig:
    """PPO on ``arm7_precise``: a learned σ and normalised observations (see :func:`_precise_arm`)."""
    return config.replace(learn_std=True, normalize_obs=True)


def a2c_preset(
    name: str, env_name: str, episode_length: int, action_size: int, asynchronous: bool = False
) -> tuple[A2CConfig, dict]:
    """``(A2CConfig or A3CConfig, env overrides)`` of preset ``name`` for A2C / A3C (thesis §4.1).

    ``thesis`` — Table 4.2 and §4.1.3: K = 4 workers, each pushing after 8 transitions; lr actor
    1e-4, critic 2e-4, β = 0.01, γ = 0.9, σ = [0.8, 0.8, 0.1]; 2 x 200 nets, batch-norm actor; 2000
    episodes' worth of steps; A3C pushes in a random order. ``cpu`` (32 lanes) and ``fast`` (4096
    lanes) keep the algorithm and the thesis's 4 A3C workers (groups of lanes), drop batch-norm,
    standardise advantages and anneal the learning rates (why: ``benchmarks/results/why-presets.md`` § A2C
    arm). Env overrides as
    :func:`ppo_env_overrides` (arm7 in ``kinematic`` mode under ``thesis`` and ``cpu``).
    """
    name = resolve_preset(name, algo="a2c")
    family = _family(env_name)
    env_overrides = ppo_env_overrides(name, env_name)
    cls = A3CConfig if asynchronous else A2CConfig
    if family == "arm":
        base = cls(
            actor_lr=1e-4, critic_lr=2e-4, entropy_coef=0.01, gamma=0.9, sigma=(0.8, 0.8, 0.1),
            actor_hidden=(200, 200), critic_hidden=(200, 200), batch_norm=True,
        )
        presets = {
            "thesis": dict(num_envs=4, unroll_length=8, total_steps=2000 * episode_length),
            "cpu": dict(num_envs=32, unroll_length=8, actor_lr=1e-3, critic_lr=1e-3, batch_norm=False,
                        normalize_advantages=True, lr_schedule="linear", total_steps=400_000),
            "fast": dict(num_envs=4096, unroll_length=8, actor_lr=1e-3, critic_lr=1e-3, batch_norm=False,
                         normalize_advantages=True, lr_schedule="linear", total_steps=100_000_000),
        }
        if asynchronous:
            # A3C: 4 asynchronous workers as in the thesis, each of 8 (cpu) or 1024 (fast) lanes.
            presets["cpu"]["lanes_per_worker"] = 8
            presets["fast"]["lanes_per_worker"] = 1024
    else:
        base = cls(sigma=(0.5,) * action_size, actor_hidden=(64, 64), critic_hidden=(64, 64), batch_norm=False,
                   gamma=0.99, actor_lr=3e-4, critic_lr=3e-4, entropy_coef=0.0)
        presets = {
            "thesis": dict(num_envs=4, unroll_length=8, total_steps=200_000),
            "cpu": dict(num_envs=32, unroll_length=16, total_steps=500_000),
            "fast": dict(num_envs=2048, unroll_length=16, total_steps=10_000_000),
        }
        if asynchronous:
            presets["fast"]["lanes_per_worker"] = 64
    config = base.replace(**presets[name])
    return (config.replace(learn_std=True) if _precise_arm(env_name) else config), env_overrides


def ddpg_preset(
    name: str, env_name: str, episode_length: int, reward: str | None = None, distributed: bool = False,
    her: str = "none",
) -> DDPGConfig:
    """The :class:`DDPGConfig` of preset ``name`` for ``env_name`` (and the arm's ``reward``);
    with ``distributed``, the distributed DDPG variant of it (:func:`distribute`).

    Arm (Tables 3.1-3.2, §3.4.2): the 'episodes' schedule — epochs × 50 cycles × 16 episodes,
    40 updates per cycle, batch 128, memory 10^6, lr 1e-3 / 1e-3, ε 0.05, γ 0.9, PER α 0.6,
    β0 0.4, +0.001; 3 × 100 nets; 200 epochs for the sparse reward, 100 for the shaped one, and 200
    for every reward on ``arm7_precise``, twice that with ``her='random'`` there; normalised observations
    on ``arm7_precise``; ``cpu`` gives random relabelling goals twice the epochs on ``arm7`` too.
    Exploration: Gaussian σ = 0.2 (the thesis does not give the arm's noise).  With the sparse
    reward, critic targets are clipped to [−1/(1−γ), 0] and a failure (leaving the region) is
    valued as never reaching the goal (``failure_value`` −1/(1−γ)), so that leaving the region
    is no shortcut.  With the shaped reward they are clipped to its return range
    (``Arm7.return_bounds``: [−19.46, 10] at γ = 0.9).  Why: ``benchmarks/results/why-presets.md``
    § DDPG arm.

    Tracking (Table 3.3, §3.5): the 'steps' schedule — one lane, one update per step once 5000
    transitions are stored, memory 50 000, batch 32, lr 1e-4 / 1e-4, ε 0.01, γ 0.9, PER, OU
    noise, 1000 episodes; 300-100 nets.  The actor ends in tanh, not the thesis's sigmoid: our
    tracking envs take actions in [-1, 1] (sigmoid would forbid negative joint steps and turn
    rates).

    ``cpu`` keeps the thesis's update-to-data ratio with a shorter run (for tracking it also changes
    the learning settings, see the comment below); ``fast`` runs many more lanes per cycle on an
    accelerator with proportionally more updates on larger batches.  ``brax`` (brax's tasks, and any
    env on request): :func:`brax_sac_ddpg_config` of the env's :data:`BRAX_SAC` row, hopper's for an env
    without one (with the env's own episode length).
    """
    name = resolve_preset(name, algo="ddpg")
    family = _family(env_name)
    if name == "brax":
        task = brax_sac_task(env_name)
        base = brax_sac_ddpg_config(task or "hopper").replace(**({} if task else {"episode_length": 0}))
        presets = {"brax": {}}
    elif name == "playground":  # the env's own time limit (Playground's row: its default config's)
        base, presets = playground_sac_ddpg_config(env_name, episode_length=episode_length), {"playground": {}}
    elif family == "arm":
        base, presets = _arm_preset(env_name, reward, her)
    elif family == "tracking":
        base, presets = _tracking_preset(episode_length)
    elif family == "racing":
        base, presets = _racing_preset()
    else:
        base, presets = _other_preset()
    config = base.replace(**presets[name])
    return distribute(config, name) if distributed else config


def _arm_preset(env_name: str, reward: str | None, her: str) -> tuple[DDPGConfig, dict]:
    """The arm's base config and preset entries (see :func:`ddpg_preset`)."""
    sparse = reward == "sparse"
    long = sparse or _precise_arm(env_name)
    scale = 2 if _precise_arm(env_name) and her == "random" else 1
    base = DDPGConfig(
        schedule="episodes", epochs=(200 if long else 100) * scale, cycles_per_epoch=50, num_envs=16,
        updates_per_cycle=40, batch_size=128, buffer_size=1_000_000, actor_lr=1e-3, critic_lr=1e-3, tau=0.05,
        gamma=0.9, alpha=0.6, beta0=0.4, beta_increment=0.001, actor_hidden=(100, 100, 100),
        critic_hidden=(100, 100, 100), noise="gaussian", noise_scale=(0.2,),
        target_clip=(-10.0, 0.0) if sparse else (), failure_value=-10.0 if sparse else 0.0,
        clip_targets_to_env=reward == "shaped", normalize_obs=_precise_arm(env_name),
    )
    presets = {
        "thesis": {},
        "cpu": dict(epochs=(20 if long else 10) * (2 if her == "random" else 1)),
        "fast": dict(epochs=(20 if long else 10) * scale, cycles_per_epoch=10, num_envs=1024, updates_per_cycle=400,
                     batch_size=1024),
    }
    return base, presets


def _tracking_preset(episode_length: int) -> tuple[DDPGConfig, dict]:
    """Trajectory tracking's base config and preset entries (Table 3.3; see :func:`ddpg_preset`)."""
    base = DDPGConfig(
        schedule="steps", total_steps=1000 * episode_length, num_envs=1, unroll_length=1,
        updates_per_iteration=1, learning_starts=5000, batch_size=32, buffer_size=50_000, actor_lr=1e-4,
        critic_lr=1e-4, tau=0.01, gamma=0.9, per=True, alpha=0.6, beta0=0.4, beta_increment=0.001,
        actor_hidden=(300, 100), critic_hidden=(300, 100), noise="ou", noise_scale=(0.2,),
        noise_reversion=(0.15,), noise_mean=(0.0,),
    )
    # cpu and fast: normalised observations, γ 0.99 with the reward as a cost, decaying Gaussian
    # exploration, twin critics and a policy delay of 2 (why-presets.md § DDPG tracking); thesis: Table 3.3.
    learning = dict(normalize_obs=True, gamma=0.99, reward_shift=-1.0, termination_metric="early_termination",
                    failure_value=-100.0, noise="gaussian", noise_scale=(0.1,), noise_end_factor=0.2,
                    twin_critics=True, policy_delay=2)  # fmt: skip
    presets = {
        "thesis": {},
        "cpu": dict(num_envs=4, unroll_length=8, updates_per_iteration=32, **learning),
        "fast": dict(num_envs=256, unroll_length=4, updates_per_iteration=32, batch_size=256,
                     buffer_size=1_000_000, total_steps=20_000 * episode_length, **learning),
    }
    return base, presets


def _other_preset() -> tuple[DDPGConfig, dict]:
    """Any other env's base config and preset entries: the usual DDPG settings of continuous control."""
    base = DDPGConfig(schedule="steps", total_steps=200_000, num_envs=4, unroll_length=8, updates_per_iteration=8,
                      learning_starts=1000, batch_size=128, buffer_size=200_000, actor_lr=1e-3, critic_lr=1e-3,
                      tau=0.005, gamma=0.99, actor_hidden=(256, 256), critic_hidden=(256, 256), noise="gaussian",
                      noise_scale=(0.1,))
    presets = {"thesis": {}, "cpu": {},
               "fast": dict(num_envs=256, updates_per_iteration=64, batch_size=1024, total_steps=5_000_000)}
    return base, presets


def _racing_preset() -> tuple[DDPGConfig, dict]:
    """``racecar`` (thesis ch. 6): imitation of the expert driver, then DDPG (TD3 with ``train.td3``).

    ``thesis``: one car, one update per step, the OU noise of Table 6.1 read as (reversion, mean,
    scale) — steering (0.8, 0, 0.2), acceleration (1, 0.5, 0.1), brake (1, −0.1, 0.05) — 4 000
    imitation steps with 50 pairs per update (§6.1.2, Fig. 6.5).  The thesis gives no network
    sizes, learning rates, γ or memory for this task; those here are the usual ones of DDPG on
    TORCS (300-600 nets, lr 1e-4 / 1e-3, γ 0.99, τ 0.001, memory 100 000).  Rewards of 20-40 per
    step are scaled by 0.01 in the critic target (Q stays near 30 at γ = 0.99).
    ``cpu`` (16 lanes) and ``fast`` (1 024 lanes) imitate for half the run on larger mini-batches,
    then fine-tune with the actor anchored to the expert's labels (``imitation_weight``); their
    env is :data:`RACING_ENV` (:func:`ddpg_env_overrides`).  ``fast`` keeps the latest 10^6 pairs,
    imitates at lr 3e-4, then puts the anchor in the actor's loss with weight 1 (``imitation_anchor='loss'``,
    TD3+BC's objective; why: ``benchmarks/results/why-presets.md`` § racing preset).
    """
    base = DDPGConfig(
        schedule="steps", total_steps=100_000, num_envs=1, unroll_length=1, updates_per_iteration=1,
        learning_starts=1000, batch_size=32, buffer_size=100_000, actor_lr=1e-4, critic_lr=1e-3, tau=0.001,
        gamma=0.99, reward_scale=0.01, actor_hidden=(300, 600), critic_hidden=(300, 600), noise="ou",
        noise_reversion=(0.8, 1.0, 1.0), noise_mean=(0.0, 0.5, -0.1), noise_scale=(0.2, 0.1, 0.05),
        pretrain="imitation", pretrain_steps=4000, imitation_batch=50, imitation_updates=4,
    )
    presets = {
        "thesis": {},
        "cpu": dict(num_envs=16, unroll_length=4, updates_per_iteration=4, batch_size=256, buffer_size=200_000,
                    tau=0.005, total_steps=160_000, pretrain_steps=80_000, imitation_batch=256, imitation_updates=16,
                    imitation_weight=1.0, learning_starts=2000, noise_end_factor=0.2),
        "fast": dict(num_envs=1024, unroll_length=4, updates_per_iteration=32, batch_size=1024, normalize_obs=True,
                     buffer_size=1_000_000, tau=0.005, total_steps=24_000_000, pretrain_steps=6_000_000,
                     imitation_batch=1024, imitation_updates=32, imitation_buffer=1_000_000, imitation_lr=3e-4,
                     imitation_weight=1.0, imitation_anchor="loss", learning_starts=10_000, noise_end_factor=0.2),
    }
    return base, presets


def distribute(config: DDPGConfig, name: str) -> DDPGConfig:
    """Distributed DDPG (thesis §4.2) on top of the single learner's preset ``config`` (preset ``name``).

    ``thesis`` and ``cpu``: 4 synchronous workers sharing the ``num_envs`` lanes and 4 collecting
    workers of ``num_envs / 4`` lanes each, mini-batches of 32 per synchronous worker (128
    transitions per update), a shared memory of 200 000 and a fetch every 5 iterations (§4.2.2;
    the tracking rows step one lane per worker, as the thesis's processes did).  ``fast``, ``brax`` and
    ``playground``: 8 + 8 workers (a multiple of 1, 2, 4 or 8 GPUs), the single learner's batch split over the 8
    synchronous workers, memory at least 10^6.  The 'steps' budget counts every lane's steps; it
    grows with the lanes so that the number of iterations and updates stays the preset's (the
    thesis's tracking row: each of the 8 workers runs the 1000 episodes).
    """
    wide = name in ("fast", "brax", "playground")
    workers = 8 if wide else 4
    changes: dict = dict(distributed=True, sync_workers=workers, collect_workers=workers, fetch_every=5,
                         collect_lanes=max(1, config.num_envs // workers))
    if wide:
        changes.update(batch_size=max(1, config.batch_size // workers), buffer_size=max(config.buffer_size, 1_000_000))
    else:
        changes.update(batch_size=32, buffer_size=200_000)
    if config.num_envs % workers:
        changes["num_envs"] = workers * changes["collect_lanes"]
    out = config.replace(**changes)
    if out.schedule == "steps":
        out = out.replace(total_steps=config.iterations * out.lanes * out.unroll_length)
    return out
