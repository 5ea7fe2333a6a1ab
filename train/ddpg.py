"""Train DDPG with prioritised and hindsight replay: ``python -m train.ddpg --env arm7``.

Defaults come from a preset (``train/presets/``) chosen by ``--preset`` (``auto`` picks
``fast`` on a GPU, ``cpu`` otherwise, and ``brax`` on ``brax:hopper`` and ``brax:walker2d``) for ``--env``
and ``--reward``; every hyper-parameter flag overrides it.  ``python -m train.ddpg --env arm7 --reward
sparse --help`` lists the flags with that preset's values.

Examples (the rows of thesis Table 3.1 and the DDPG rows of Tables 4.3-4.5)::

    python -m train.ddpg --env arm7 --reward sparse --her final
    python -m train.ddpg --env arm7 --reward sparse --her future --her-k 4
    python -m train.ddpg --env arm7 --reward shaped --her random --her-k 2
    python -m train.ddpg --env arm7 --reward shaped --her none --per --env-config obs=no_goal
    python -m train.ddpg --env unicycle --trajectory ellipse --preset thesis
    python -m train.ddpg --resume runs/ddpg-arm7-20260101-120000

Racing (thesis ch. 6): the ``racecar`` preset imitates the env's expert driver first
(``--pretrain imitation``, the default there; ``--pretrain none`` trains from scratch), then
fine-tunes with DDPG (``train.td3``: TD3) under the OU noise of Table 6.1; the evaluation drives
``--eval-episodes`` laps on each road::

    python -m train.ddpg --env racecar --eval-episodes 20
    python -m train.td3 --env racecar --pretrain-steps 2000000

Distributed DDPG (thesis §4.2, Algorithms 4-6) is ``--distributed``: the preset's distributed
variant (``thesis``: 4 synchronous workers with 32 transitions each per update, 4 collecting
workers fetching the parameters every 5 steps, a shared memory of 200 000), which
``--sync-workers``, ``--collect-workers``, ``--collect-lanes``, ``--fetch-every`` and
``--collect-noise-factors`` change::

    python -m train.ddpg --env scara --preset thesis --distributed
    python -m train.ddpg --env unicycle --trajectory sine --distributed --sync-workers 8

The run options are ``train.options.RunOptions``; ``--trajectory`` and the default of ``--chunks``
are DDPG's own. A run writes ``runs/ddpg-<env>-<time>/`` (config, metrics.csv, TensorBoard, checkpoints with
the replay memory and sum-tree, so ``--resume`` continues exactly; figures; ``eval.json``).
"""

from __future__ import annotations

import dataclasses
import sys
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Annotated, Any, ClassVar

import tyro
from jax.sharding import Mesh

from jaxrl_robot.agents.ddpg import DDPGConfig
from jaxrl_robot.agents.ddpg import make_trainer as make_ddpg_trainer
from jaxrl_robot.agents.off_policy import OffPolicyConfig
from jaxrl_robot.types import Trainer
from train.cli import AlgorithmCLI, exit_process, iterations_per_chunk
from train.envs import BuiltEnv, env_overrides, episode_length
from train.options import RunOptions
from train.presets import ddpg_env_overrides, ddpg_preset, off_policy_default_devices

__all__ = ["CLI", "Args", "OffPolicyCLI", "OffPolicyOptions", "build", "chunked", "distributed_flag", "main", "parse"]


@dataclass
class OffPolicyOptions(RunOptions):
    """The run options of the off-policy command lines (``train.ddpg``, ``train.td3``, ``train.sac``, …)."""

    chunks: int = 0
    """Reporting chunks per run, 0 or more (0: one per epoch for the 'episodes' schedule, 50 for 'steps')."""
    trajectory: str | None = None
    """Reference trajectory of a tracking env (unicycle: sine, ellipse); None keeps the env's default."""

    ranges: ClassVar[dict[str, tuple[int, int | None]]] = {**RunOptions.ranges, "chunks": (0, None)}


@dataclass
class Args(OffPolicyOptions):
    """DDPG (thesis ch. 3) with optional PER and HER on an MJX robot environment.
    --distributed: distributed DDPG (thesis §4.2), synchronous workers averaging their gradients
    and collecting workers with stale parameter copies, sharing one prioritised replay; the
    defaults become the preset's distributed variant (thesis: 4 + 4 workers, 4 x 32 transitions
    per update, memory 200 000)."""

    ddpg: Annotated[DDPGConfig, tyro.conf.OmitArgPrefixes] = field(default_factory=DDPGConfig)
    """DDPG hyper-parameters (defaults: the preset's values)."""


def env_settings(args: OffPolicyOptions) -> dict[str, Any]:
    """Env settings: the preset's (:func:`train.presets.ddpg_env_overrides`), then ``--reward``,
    ``--trajectory`` and ``--env-config KEY=VALUE``."""
    user = {**({} if args.trajectory is None else {"trajectory": args.trajectory}), **env_overrides(args)}
    return {**ddpg_env_overrides(args.preset, args.env, method_of(args), user.get("trajectory")), **user}


def algo_config(args: OffPolicyOptions) -> OffPolicyConfig | None:
    """The config of ``args``: its field holding an :class:`OffPolicyConfig` (``args.ddpg``, ``args.td3``,
    ``args.sac``, …); None for bare options."""
    return next((v for v in vars(args).values() if isinstance(v, OffPolicyConfig)), None)


def method_of(args: OffPolicyOptions) -> str:
    """``ddpg``, ``distributed``, ``td3`` or ``distributed-td3``: the algorithm ``args`` configure (SAC's
    presets are DDPG's)."""
    name = "td3" if getattr(args, "td3", None) is not None else "ddpg"
    config = algo_config(args)
    if config is not None and config.distributed:
        return "distributed" if name == "ddpg" else "distributed-td3"
    return name


def preset(args: OffPolicyOptions, env: Any, distributed: bool = False) -> DDPGConfig:
    """The :class:`DDPGConfig` of ``args.preset`` for ``env`` and its reward (the env's default if not given);
    its distributed variant with ``distributed``."""
    reward = args.reward or getattr(getattr(env, "config", None), "reward", None)
    her = getattr(algo_config(args), "her", "none")
    return ddpg_preset(args.preset, args.env, episode_length(env), reward, distributed=distributed, her=her)


def distributed_flag(argv: list[str]) -> bool:
    """Whether the command line asks for distributed DDPG: the last of ``--distributed`` / ``--no-distributed``."""
    flags = [a for a in argv if a in ("--distributed", "--no-distributed")]
    return bool(flags) and flags[-1] == "--distributed"


@dataclass(frozen=True)
class OffPolicyCLI(AlgorithmCLI):
    """An :class:`~train.cli.AlgorithmCLI` whose preset also depends on ``--distributed``
    (read ahead of the full parse, like ``--env``); ``preset`` takes ``distributed=``, and so does the
    ``--devices`` taken when none is given (:func:`train.presets.off_policy_default_devices`: one device for the
    single learner).  Its preset names are DDPG's (``brax`` and ``playground`` among them)."""

    presets: str = "ddpg"

    def parse_with_env(self, argv: list[str] | None = None) -> tuple[Any, BuiltEnv | None]:
        argv = sys.argv[1:] if argv is None else list(argv)
        flag = distributed_flag(argv)
        ahead = dataclasses.replace(self, preset=lambda args, env: self.preset(args, env, distributed=flag),
                                    default_devices=lambda args: off_policy_default_devices(flag))  # fmt: skip
        return AlgorithmCLI.parse_with_env(ahead, argv)


def chunked(make_algo_trainer: Callable[..., Trainer]) -> Callable[..., tuple[Trainer, int]]:
    """The CLI's ``make_trainer(args, env, cfg, mesh) -> (trainer, iterations per chunk)`` of an off-policy
    library trainer (``jaxrl_robot.agents.ddpg.make_trainer``, ``…sac.make_trainer``) over the lane mesh:
    ``--chunks`` chunks, or one per epoch ('episodes') or 50 ('steps')."""

    def make_trainer(args: OffPolicyOptions, env: Any, cfg: OffPolicyConfig, mesh: Mesh) -> tuple[Trainer, int]:
        if args.chunks > 0:
            per_chunk = iterations_per_chunk(cfg.iterations, args.chunks)
        elif cfg.schedule == "episodes":
            per_chunk = cfg.cycles_per_epoch
        else:
            per_chunk = iterations_per_chunk(cfg.iterations, 50)
        return make_algo_trainer(cfg, env, mesh=mesh, iterations_per_update=per_chunk), per_chunk

    return make_trainer


make_trainer = chunked(make_ddpg_trainer)
"""The DDPG (and TD3) trainer of the CLI: ``(args, env, cfg, mesh) -> (trainer, iterations per chunk)``."""


CLI = OffPolicyCLI(
    name="ddpg", args_type=Args, config_type=DDPGConfig, preset=preset, make_trainer=make_trainer,
    env_settings=env_settings, env_fields=("trajectory",), preset_fields=("her",),
)  # fmt: skip


def _args_from_saved(run_dir: str, current: Args) -> Args:
    """The arguments saved in ``run_dir`` (resuming it); ``--stop-after-steps``, ``--progress`` and the
    process options from ``current``."""
    return CLI.args_from_saved(run_dir, current)


def parse(argv: list[str] | None = None) -> Args:
    """Parse the command line: preset defaults for ``--env``/``--reward`` first, then every flag."""
    return CLI.parse(argv)


def build(args: Args):
    """``(env, trainer, config dict)`` for ``args`` (a fresh run or a saved config)."""
    return CLI.build(args)


def main(argv: list[str] | None = None) -> int:
    """Entry point; returns the process exit code."""
    return CLI.main(argv)


if __name__ == "__main__":
    exit_process(main())
