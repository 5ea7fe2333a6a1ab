"""Train distributed PPO with GAE: ``python -m train.ppo --env arm7``.

Defaults come from a preset (``train/presets/``) chosen by ``--preset`` (``auto`` picks
``fast`` on a GPU, ``cpu`` otherwise) for ``--env``; every hyper-parameter flag overrides it.
``python -m train.ppo --env arm7 --help`` lists the flags with that preset's values.

Examples::

    python -m train.ppo --env arm7                          # CPU-sized default
    python -m train.ppo --env arm7 --reward path --seed 3
    python -m train.ppo --env unicycle --env-config trajectory=ellipse
    python -m train.ppo --env arm7 --preset thesis --objective kl
    python -m train.ppo --env unicycle --policy lstm        # recurrent actor and critic (thesis §5.7)
    python -m train.ppo --env unicycle --pretrain action-search --pretrain-episodes 200   # two-stage (§5.6)
    python -m train.ppo --resume runs/ppo-arm7-20260101-120000

The run options (``--env``, ``--seed``, ``--out``, ``--resume``, ``--chunks``, the process
options of a run over several hosts, …) are ``train.options.RunOptions``.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Annotated, Any

import tyro
from jax.sharding import Mesh

from jaxrl_robot.agents.ppo import PPOConfig
from train.cli import AlgorithmCLI, exit_process, iterations_per_chunk
from train.envs import env_overrides, episode_length
from train.options import RunOptions
from train.presets import ppo_default_devices, ppo_env_overrides, ppo_preset

__all__ = ["CLI", "Args", "build", "main", "parse"]


@dataclass
class Args(RunOptions):
    """Distributed PPO with GAE (thesis ch. 5) on an MJX robot environment."""

    ppo: Annotated[PPOConfig, tyro.conf.OmitArgPrefixes] = field(default_factory=PPOConfig)
    """PPO hyper-parameters (defaults: the preset's values)."""


def env_settings(args: Args) -> dict[str, Any]:
    """The preset's env options, then ``--reward`` and ``--env-config``."""
    user = env_overrides(args)
    preset = ppo_env_overrides(args.preset, args.env, args.ppo.pretrain, args.ppo.policy, user.get("trajectory"))
    return {**preset, **user}


def preset(args: Args, env: Any) -> PPOConfig:
    """The :class:`PPOConfig` of ``args.preset`` for ``env`` and the ``--policy`` / ``--pretrain`` chosen."""
    variant = {"policy": args.ppo.policy, "pretrain": args.ppo.pretrain, "devices": args.devices}
    return ppo_preset(args.preset, args.env, episode_length(env), int(env.action_size), **variant)[0]


def default_devices(args: Args) -> int:
    """``--devices`` when not given: 1 for the ``fast`` main job on ``arm7``, else 0 (every device)
    (:func:`train.presets.ppo_default_devices`)."""
    return ppo_default_devices(args.preset, args.env, args.ppo.policy, args.ppo.pretrain)


def make_trainer(args: Args, env: Any, cfg: PPOConfig, mesh: Mesh):
    """The PPO trainer: ``--chunks`` chunks of whole iterations over the lane mesh."""
    from jaxrl_robot.agents.ppo import make_trainer as make_ppo_trainer

    per_chunk = iterations_per_chunk(cfg.total_iterations, args.chunks)
    return make_ppo_trainer(cfg, env, mesh=mesh, iterations_per_update=per_chunk), per_chunk


CLI = AlgorithmCLI(
    name="ppo", args_type=Args, config_type=PPOConfig, preset=preset, make_trainer=make_trainer,
    env_settings=env_settings, preset_fields=("policy", "pretrain"), default_devices=default_devices,
)  # fmt: skip


# parse(argv=None) -> Args (the preset's defaults for --env, then every flag); build(args) -> (env, trainer,
# config dict) of a fresh or resumed run; main(argv=None) -> exit code
parse, build, main = CLI.parse, CLI.build, CLI.main

if __name__ == "__main__":
    exit_process(main())
