"""DDPG's (TD3's, SAC's) presets per environment family, and their distributed variant."""

from __future__ import annotations

import jax

from jaxrl_robot.agents.ddpg import DDPGConfig
from train.presets.names import _family, _precise_arm, resolve_preset
from train.presets.peers import brax_sac_ddpg_config, brax_sac_task, playground_sac_ddpg_config


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


def off_policy_default_devices(distributed: bool) -> int:
    """``--devices`` of ``train.ddpg`` / ``train.td3`` / ``train.sac`` when the command line gives none: 1 for the
    single learner in a run of one process, 0 (every device) for distributed DDPG and runs over several processes.

    The single learner splits only the acting lanes over devices; the replay memory and every update are
    replicated, so a second device cannot shorten an update and adds the gathering of each iteration's transitions.
    Measured on two H200s: DDPG + HER on ``arm7`` and ``arm7_precise`` (``fast``) ran 31–39 s per chunk of
    1.02 M env steps on two devices against 0.9 s on one (the first chunk apart), and reached the target after
    41–78 s of training against 1.9–2.7 s (``benchmarks/results/gpu-nvidia_h200-time_to_solve-ddpg-x2.md``).
    That slowness was the ``vmap`` lane map's: under ``shard_map``, which the kinematic arm now takes on several
    devices (``jaxrl_robot.parallel.lane_map_impl``), two H200s ran it at one's speed (1.17 M against 1.16 M
    env-steps/s, ``benchmarks/results/gpu-nvidia_h200x4-lane_map-ddpg.md``), no faster.
    ``--devices N`` still spreads the lanes."""
    return 0 if distributed or jax.process_count() > 1 else 1
