"""Train DDPG with prioritised and hindsight replay: ``python -m train.ddpg --env arm7``.

Defaults come from a preset (``train/presets.py``) chosen by ``--preset`` (``auto`` picks
``fast`` on a GPU, ``cpu`` otherwise) for ``--env`` and ``--reward``; every hyper-parameter flag
overrides it.  ``python -m train.ddpg --env arm7 --reward sparse --help`` lists the flags with
that preset's values.

Examples (the rows of thesis Table 3.1 and the DDPG rows of Tables 4.3-4.5)::

    python -m train.ddpg --env arm7 --reward sparse --her final
    python -m train.ddpg --env arm7 --reward sparse --her future --her-k 4
    python -m train.ddpg --env arm7 --reward shaped --her random --her-k 2
    python -m train.ddpg --env arm7 --reward shaped --her none --per --env-config obs=no_goal
    python -m train.ddpg --env unicycle --trajectory ellipse --preset thesis
    python -m train.ddpg --resume runs/ddpg-arm7-20260101-120000

A run writes ``runs/ddpg-<env>-<time>/`` (config, metrics.csv, TensorBoard, checkpoints with
the replay memory and sum-tree, so ``--resume`` continues exactly; figures; ``eval.json``).
"""

from __future__ import annotations

import argparse
import dataclasses
import sys
from dataclasses import dataclass
from typing import Annotated, Any

import tyro

from jaxrl_robot.agents.ddpg import DDPGConfig
from train import common
from train.ppo import _parse_value, make_env
from train.presets import ddpg_preset, resolve_preset

__all__ = ["Args", "build", "main", "parse"]

_TUPLE_FIELDS = ("noise_scale", "noise_mean", "noise_reversion", "actor_hidden", "critic_hidden", "target_clip")


@dataclass
class Args:
    """DDPG (thesis ch. 3) with optional PER and HER on an MJX robot environment."""

    ddpg: Annotated[DDPGConfig, tyro.conf.OmitArgPrefixes]
    """DDPG hyper-parameters (defaults: the preset's values)."""
    env: str = "arm7"
    """Environment: a registered name (envs_mjx.names()) or brax:<name> for brax's own envs."""
    preset: str = "auto"
    """Hyper-parameter preset: auto (fast on a GPU, else cpu), thesis, cpu or fast."""
    seed: int = 0
    """Random seed of the run (training); evaluation uses a separate stream derived from it."""
    reward: str | None = None
    """Reward function of the env (arm7: sparse, shaped, ordinary, path); None keeps the env's default."""
    trajectory: str | None = None
    """Reference trajectory of a tracking env (unicycle: sine, ellipse); None keeps the env's default."""
    env_config: tuple[str, ...] = ()
    """Further env settings as KEY=VALUE (e.g. mode=kinematic, obs=no_goal)."""
    out: str = "runs"
    """Parent folder of the run directory runs/<algo>-<env>-<time>/."""
    resume: str | None = None
    """Continue the run in this directory (its config.json is used; other flags are ignored)."""
    chunks: int = 0
    """Reporting chunks per run (0: one per epoch for the 'episodes' schedule, 50 for 'steps')."""
    checkpoint_every: int = 10
    """Chunks between checkpoints (the last chunk is always saved)."""
    eval_episodes: int = 100
    """Test episodes of the final evaluation (reaching envs)."""
    stop_after_steps: int = 0
    """Stop early, resumably, once this many env steps are done (0: run to the end)."""
    progress: bool | None = None
    """Show a progress bar (default: only on a terminal and not under CI)."""


def env_overrides(args: Args) -> dict[str, Any]:
    """Env settings from ``--reward``, ``--trajectory`` and ``--env-config KEY=VALUE``."""
    out: dict[str, Any] = {}
    if args.reward is not None:
        out["reward"] = args.reward
    if args.trajectory is not None:
        out["trajectory"] = args.trajectory
    for item in args.env_config:
        if "=" not in item:
            raise ValueError(f"--env-config {item!r}: expected KEY=VALUE")
        k, v = item.split("=", 1)
        out[k.strip().replace("-", "_")] = _parse_value(v.strip())
    return out


def _episode_length(env, cfg_len: int = 0) -> int:
    return int(cfg_len or getattr(env, "episode_length", 0) or 1000)


def build(args: Args):
    """``(env, trainer, config dict)`` for ``args`` (a fresh run or a saved config)."""
    from jaxrl_robot.agents.ddpg import make_trainer

    env = make_env(args.env, env_overrides(args))
    cfg = args.ddpg
    if not cfg.episode_length:
        cfg = cfg.replace(episode_length=_episode_length(env))
    cfg.validate()
    if args.chunks > 0:
        per_chunk = max(1, -(-cfg.iterations // args.chunks))
    elif cfg.schedule == "episodes":
        per_chunk = cfg.cycles_per_epoch
    else:
        per_chunk = max(1, -(-cfg.iterations // 50))
    trainer = make_trainer(cfg, env, iterations_per_update=per_chunk)
    config = {
        "algo": "ddpg",
        "args": {k: v for k, v in dataclasses.asdict(args).items() if k != "ddpg"},
        "ddpg": dataclasses.asdict(cfg),
        "iterations_per_chunk": per_chunk,
    }
    return env, trainer, config


def _preparse(argv: list[str]) -> argparse.Namespace:
    pre = argparse.ArgumentParser(add_help=False)
    pre.add_argument("--env", default="arm7")
    pre.add_argument("--preset", default="auto")
    pre.add_argument("--reward", default=None)
    pre.add_argument("--trajectory", default=None)
    pre.add_argument("--resume", default=None)
    known, _ = pre.parse_known_args(argv)
    return known


def _args_from_saved(run_dir: str, argv_args: Args) -> Args:
    saved = common.load_config(run_dir)
    a = dict(saved["args"])
    ddpg = dict(saved["ddpg"])
    for k in _TUPLE_FIELDS:
        ddpg[k] = tuple(ddpg[k])
    a["env_config"] = tuple(a.get("env_config", ()))
    a["resume"] = run_dir
    a["stop_after_steps"] = argv_args.stop_after_steps
    a["progress"] = argv_args.progress
    return Args(ddpg=DDPGConfig(**ddpg), **a)


def parse(argv: list[str] | None = None) -> Args:
    """Parse the command line: preset defaults for ``--env``/``--reward`` first, then every flag."""
    argv = sys.argv[1:] if argv is None else list(argv)
    known = _preparse(argv)
    if known.resume:
        default_cfg = DDPGConfig()
    else:
        preset = resolve_preset(known.preset)
        reward = known.reward
        probe_overrides = {k: v for k, v in (("reward", reward), ("trajectory", known.trajectory)) if v}
        probe = make_env(known.env, probe_overrides)  # sizes the preset's budget (episodes × length)
        reward = reward or getattr(getattr(probe, "config", None), "reward", None)
        default_cfg = ddpg_preset(preset, known.env, _episode_length(probe), reward)
    args = tyro.cli(Args, args=argv, default=Args(ddpg=default_cfg, env=known.env, preset=known.preset))
    if args.resume:
        args = _args_from_saved(args.resume, args)
    return args


def main(argv: list[str] | None = None) -> int:
    """Entry point; returns the process exit code."""
    return common.cli_main("ddpg", lambda: parse(argv), lambda args: build(args))


if __name__ == "__main__":
    sys.exit(main())
