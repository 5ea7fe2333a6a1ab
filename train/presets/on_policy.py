"""PPO's and A2C/A3C's presets per environment (with their LSTM and two-stage variants)."""

from __future__ import annotations

import math

import jax

from jaxrl_robot.agents.a2c import A2CConfig, A3CConfig
from jaxrl_robot.agents.ppo import PPOConfig
from train.presets.envs import ppo_env_overrides, tracking_schedule
from train.presets.names import _family, _precise_arm, resolve_preset
from train.presets.peers import brax_ppo_config, brax_task, playground_ppo_config


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
