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

The package: :mod:`train.presets.names` (preset names, ``auto``), :mod:`train.presets.peers` (brax's and
Playground's rows, converted), :mod:`train.presets.envs` (env settings that go with a preset),
:mod:`train.presets.on_policy` (PPO, A2C/A3C) and :mod:`train.presets.off_policy` (DDPG, TD3, SAC); every name
of :data:`__all__` is importable from ``train.presets``.
"""

from train.presets.envs import (
    RACING_ENV,
    UNICYCLE_A_P,
    UNICYCLE_A_P_FAST,
    ddpg_env_overrides,
    ppo_env_overrides,
    tracking_schedule,
    unicycle_a_p,
)
from train.presets.names import (
    DDPG_PRESETS,
    PPO_PRESETS,
    PRESETS,
    resolve_preset,
)
from train.presets.off_policy import (
    ddpg_preset,
    distribute,
    off_policy_default_devices,
)
from train.presets.on_policy import (
    ARM_FAST_STEPS,
    a2c_preset,
    arm_fast_on_devices,
    lstm_variant,
    ppo_default_devices,
    ppo_preset,
    two_stage_variant,
)
from train.presets.peers import (
    BRAX_COLUMNS,
    BRAX_PPO,
    BRAX_PPO_SEGMENTS,
    BRAX_PPO_TUNED,
    BRAX_SAC,
    BRAX_SAC_COLUMNS,
    BRAX_SAC_TUNED,
    PLAYGROUND_PEERS,
    TD3_OWN,
    brax_ppo_config,
    brax_sac_ddpg_config,
    brax_sac_task,
    brax_task,
    ddpg_config_of_sac_row,
    playground_ppo_config,
    playground_row,
    playground_sac_ddpg_config,
    playground_task,
    ppo_config_of_row,
)

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
    "ddpg_preset",
    "distribute",
    "lstm_variant",
    "off_policy_default_devices",
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
