"""Train A2C: ``python -m train.a2c --env arm7 --reward ordinary|path`` (A3C: ``python -m train.a3c``).

Defaults come from a preset (``train/presets.py``, :func:`~train.presets.a2c_preset`) chosen by
``--preset`` (``auto`` picks ``fast`` on a GPU, ``cpu`` otherwise) for ``--env``; every
hyper-parameter flag overrides it. ``python -m train.a2c --env arm7 --help`` lists the flags
with that preset's values.

The run directory, progress, checkpoints, resume and evaluation (success over
``--eval-episodes`` test episodes, mean extra distance) are ``train/common.py``'s. Besides its
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

import argparse
import dataclasses
import sys
from dataclasses import dataclass, field
from typing import Annotated, Any

import tyro

from jaxrl_robot.agents.a2c import A2CConfig, A3CConfig
from train import common
from train.ppo import env_overrides, make_env
from train.presets import a2c_preset, ppo_env_overrides, resolve_preset

__all__ = ["A2CArgs", "A3CArgs", "build", "main", "parse"]

ALGOS = ("a2c", "a3c")


@dataclass
class _RunArgs:
    env: str = "arm7"
    """Environment: a registered name (envs_mjx.names()) or brax:<name> for brax's own envs."""
    preset: str = "auto"
    """Hyper-parameter preset: auto (fast on a GPU, else cpu), thesis, cpu or fast (presets may also
    set env options: arm7 runs in kinematic mode under thesis and cpu; --env-config overrides)."""
    seed: int = 0
    """Random seed of the run (training); evaluation uses a separate stream derived from it."""
    reward: str | None = None
    """Reward function of the env (arm7: ordinary, path, shaped, sparse); None keeps the env's default."""
    env_config: tuple[str, ...] = ()
    """Further env settings as KEY=VALUE (e.g. mode=pd, obs=no_goal)."""
    out: str = "runs"
    """Parent folder of the run directory runs/<algo>-<env>-<time>/."""
    resume: str | None = None
    """Continue the run in this directory (its config.json is used; other flags are ignored)."""
    chunks: int = 50
    """Reporting chunks per run: metrics, progress and checkpoints happen between chunks."""
    checkpoint_every: int = 10
    """Chunks between checkpoints (the last chunk is always saved)."""
    eval_episodes: int = 100
    """Test episodes of the final evaluation (reaching envs)."""
    devices: int = 0
    """Devices to spread the lanes over (0: all local devices)."""
    stop_after_steps: int = 0
    """Stop early, resumably, once this many env step slots are done (0: run to the end)."""
    progress: bool | None = None
    """Show a progress bar (default: only on a terminal and not under CI)."""


@dataclass
class A2CArgs(_RunArgs):
    """Synchronous advantage actor-critic (thesis §4.1.2) on an MJX robot environment."""

    a2c: Annotated[A2CConfig, tyro.conf.OmitArgPrefixes] = field(default_factory=A2CConfig)
    """A2C hyper-parameters (defaults: the preset's values)."""


@dataclass
class A3CArgs(_RunArgs):
    """Asynchronous advantage actor-critic (thesis §4.1.1), reproduced deterministically, on an MJX env."""

    a3c: Annotated[A3CConfig, tyro.conf.OmitArgPrefixes] = field(default_factory=A3CConfig)
    """A3C hyper-parameters (defaults: the preset's values)."""


_ARGS = {"a2c": A2CArgs, "a3c": A3CArgs}
_CONFIGS = {"a2c": A2CConfig, "a3c": A3CConfig}


def _check_algo(algo: str) -> None:
    if algo not in ALGOS:
        raise ValueError(f"unknown algorithm {algo!r}; valid: {', '.join(ALGOS)}")


def _episode_length(env: Any, cfg_len: int = 0) -> int:
    return int(cfg_len or getattr(env, "episode_length", 0) or 1000)


def build(args: A2CArgs | A3CArgs, algo: str):
    """``(env, trainer, config dict)`` for ``args`` (a fresh run or a saved config)."""
    from jaxrl_robot import parallel
    from jaxrl_robot.agents.a2c import make_trainer

    _check_algo(algo)
    env = make_env(args.env, {**ppo_env_overrides(args.preset, args.env), **env_overrides(args)})
    cfg = getattr(args, algo)
    if not cfg.episode_length:
        cfg = cfg.replace(episode_length=_episode_length(env))
    cfg.validate()
    mesh = parallel.lane_mesh(args.devices or None)
    total_rounds = -(-cfg.total_steps // (cfg.num_envs * cfg.unroll_length))
    per_chunk = max(1, -(-total_rounds // max(args.chunks, 1)))
    trainer = make_trainer(cfg, env, mesh=mesh, iterations_per_update=per_chunk)
    config = {
        "algo": algo,
        "args": {k: v for k, v in dataclasses.asdict(args).items() if k != algo},
        algo: dataclasses.asdict(cfg),
        "iterations_per_chunk": per_chunk,
        "devices": mesh.shape[parallel.LANES],
    }
    return env, trainer, config


def _preparse(argv: list[str]) -> argparse.Namespace:
    pre = argparse.ArgumentParser(add_help=False)
    pre.add_argument("--env", default="arm7")
    pre.add_argument("--preset", default="auto")
    pre.add_argument("--resume", default=None)
    known, _ = pre.parse_known_args(argv)
    return known


def _args_from_saved(run_dir: str, argv_args: A2CArgs | A3CArgs, algo: str) -> A2CArgs | A3CArgs:
    saved = common.load_config(run_dir)
    if saved.get("algo") != algo:
        raise ValueError(f"--resume {run_dir!r}: a {saved.get('algo')!r} run, not {algo!r}")
    a = dict(saved["args"])
    cfg = dict(saved[algo])
    for k in ("sigma", "actor_hidden", "critic_hidden"):
        cfg[k] = tuple(cfg[k])
    a["env_config"] = tuple(a.get("env_config", ()))
    a["resume"] = run_dir
    a["stop_after_steps"] = argv_args.stop_after_steps
    a["progress"] = argv_args.progress
    return _ARGS[algo](**{algo: _CONFIGS[algo](**cfg)}, **a)


def parse(argv: list[str] | None, algo: str) -> A2CArgs | A3CArgs:
    """Parse the command line: preset defaults for ``--env`` first, then every flag."""
    _check_algo(algo)
    argv = sys.argv[1:] if argv is None else list(argv)
    known = _preparse(argv)
    preset = known.preset
    if known.resume:
        default_cfg = _CONFIGS[algo]()
    else:
        preset = resolve_preset(known.preset)
        probe = make_env(known.env, ppo_env_overrides(preset, known.env))
        default_cfg, _ = a2c_preset(
            preset, known.env, _episode_length(probe), int(probe.action_size), asynchronous=algo == "a3c"
        )
    default = _ARGS[algo](**{algo: default_cfg}, env=known.env, preset=preset)
    args = tyro.cli(_ARGS[algo], args=argv, default=default, prog=f"python -m train.{algo}")
    args = dataclasses.replace(args, preset=resolve_preset(args.preset))
    if args.resume:
        args = _args_from_saved(args.resume, args, algo)
    return args


def draw_figures(run_dir: str) -> list[str]:
    """The per-worker episode rewards and (A3C) staleness figures of a run directory's metrics."""
    import os

    from jaxrl_robot.logging import read_csv
    from jaxrl_robot.plots import plot_staleness, plot_worker_curves

    rows = read_csv(os.path.join(run_dir, "metrics.csv"))
    return plot_worker_curves(rows, run_dir) + plot_staleness(rows, run_dir)


def main(argv: list[str] | None = None, algo: str = "a2c") -> int:
    """Entry point; returns the process exit code."""
    return common.cli_main(
        algo,
        lambda: parse(argv, algo),
        lambda args: build(args, algo),
        after=lambda result: draw_figures(result["run_dir"]),
    )


if __name__ == "__main__":
    sys.exit(main())
