"""Train A2C: ``python -m train.a2c --env arm7 --reward ordinary|path`` (A3C: ``python -m train.a3c``).

Defaults come from a preset (``train/presets/``, :func:`~train.presets.a2c_preset`) chosen by
``--preset`` (``auto`` picks ``fast`` on a GPU, ``cpu`` otherwise) for ``--env``; every
hyper-parameter flag overrides it. ``python -m train.a2c --env arm7 --help`` lists the flags
with that preset's values.

The run directory, progress, checkpoints, resume and evaluation (success over
``--eval-episodes`` test episodes, mean extra distance) are ``train/run.py``'s. Besides its
figures (episode reward, success rate, extra distance) the run draws the thesis's per-worker
episode rewards (``worker_rewards.png``) and, for A3C, the measured gradient staleness
(``staleness.png``).

Examples::

    python -m train.a2c --env arm7 --reward path
    python -m train.a3c --env arm7 --reward ordinary --preset thesis --seed 2
    python -m train.a3c --env arm7 --push-order fixed --lanes-per-worker 4
    python -m train.a2c --resume runs/a2c-arm7-20260101-120000
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from typing import Annotated, Any

import tyro
from jax.sharding import Mesh

from jaxrl_robot.agents.a2c import A2CConfig, A3CConfig
from train.cli import AlgorithmCLI, exit_process, iterations_per_chunk
from train.envs import env_overrides, episode_length
from train.options import RunOptions
from train.presets import a2c_preset, ppo_env_overrides

__all__ = ["A2CArgs", "A3CArgs", "CLI", "CLIS", "build", "draw_figures", "main", "parse"]

ALGOS = ("a2c", "a3c")


@dataclass
class A2CArgs(RunOptions):
    """Synchronous advantage actor-critic (thesis §4.1.2) on an MJX robot environment."""

    a2c: Annotated[A2CConfig, tyro.conf.OmitArgPrefixes] = field(default_factory=A2CConfig)
    """A2C hyper-parameters (defaults: the preset's values)."""


@dataclass
class A3CArgs(RunOptions):
    """Asynchronous advantage actor-critic (thesis §4.1.1), reproduced deterministically, on an MJX env."""

    a3c: Annotated[A3CConfig, tyro.conf.OmitArgPrefixes] = field(default_factory=A3CConfig)
    """A3C hyper-parameters (defaults: the preset's values)."""


def env_settings(args: A2CArgs | A3CArgs) -> dict[str, Any]:
    """The preset's env options (as PPO's), then ``--reward`` and ``--env-config``."""
    return {**ppo_env_overrides(args.preset, args.env), **env_overrides(args)}


def make_trainer(args: A2CArgs | A3CArgs, env: Any, cfg: A2CConfig, mesh: Mesh):
    """The A2C / A3C trainer: ``--chunks`` chunks of whole rounds over the lane mesh."""
    from jaxrl_robot.agents.a2c import make_trainer as make_a2c_trainer

    per_chunk = iterations_per_chunk(cfg.total_iterations, args.chunks)
    return make_a2c_trainer(cfg, env, mesh=mesh, iterations_per_update=per_chunk), per_chunk


def draw_figures(run_dir: str) -> list[str]:
    """The per-worker episode rewards and (A3C) staleness figures of a run directory's metrics."""
    from jaxrl_robot.logging import read_csv
    from jaxrl_robot.plots import plot_staleness, plot_worker_curves

    rows = read_csv(os.path.join(run_dir, "metrics.csv"))
    return plot_worker_curves(rows, run_dir) + plot_staleness(rows, run_dir)


def _cli(algo: str, args_type: type, config_type: type) -> AlgorithmCLI:
    def preset(args: Any, env: Any) -> A2CConfig:
        length, action_size = episode_length(env), int(env.action_size)
        return a2c_preset(args.preset, args.env, length, action_size, asynchronous=algo == "a3c")[0]

    return AlgorithmCLI(
        name=algo, args_type=args_type, config_type=config_type, preset=preset, make_trainer=make_trainer,
        env_settings=env_settings, after=lambda result: draw_figures(result["run_dir"]),
    )  # fmt: skip


CLIS = {"a2c": _cli("a2c", A2CArgs, A2CConfig), "a3c": _cli("a3c", A3CArgs, A3CConfig)}
CLI = CLIS["a2c"]
"""``python -m train.a2c`` (``train.a3c``'s is ``CLIS["a3c"]``)."""


def _check_algo(algo: str) -> AlgorithmCLI:
    if algo not in CLIS:
        raise ValueError(f"unknown algorithm {algo!r}; valid: {', '.join(ALGOS)}")
    return CLIS[algo]


def parse(argv: list[str] | None, algo: str) -> A2CArgs | A3CArgs:
    """Parse the command line: preset defaults for ``--env`` first, then every flag."""
    return _check_algo(algo).parse(argv)


def build(args: A2CArgs | A3CArgs, algo: str):
    """``(env, trainer, config dict)`` for ``args`` (a fresh run or a saved config)."""
    return _check_algo(algo).build(args)


def main(argv: list[str] | None = None, algo: str = "a2c") -> int:
    """Entry point; returns the process exit code."""
    return _check_algo(algo).main(argv)


if __name__ == "__main__":
    exit_process(main())
