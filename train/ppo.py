"""Train distributed PPO with GAE: ``python -m train.ppo --env arm7``.

Defaults come from a preset (``train/presets.py``) chosen by ``--preset`` (``auto`` picks
``fast`` on a GPU, ``cpu`` otherwise) for ``--env``; every hyper-parameter flag overrides it.
``python -m train.ppo --env arm7 --help`` lists the flags with that preset's values.

Examples::

    python -m train.ppo --env arm7                          # CPU-sized default
    python -m train.ppo --env arm7 --reward path --seed 3
    python -m train.ppo --env unicycle --env-config trajectory=ellipse
    python -m train.ppo --env arm7 --preset thesis --objective kl
    python -m train.ppo --resume runs/ppo-arm7-20260101-120000
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
from dataclasses import dataclass
from typing import Annotated, Any

import tyro

from jaxrl_robot.agents.ppo import PPOConfig
from train import common
from train.presets import ppo_env_overrides, ppo_preset, resolve_preset

__all__ = ["Args", "build", "main"]

BRAX_PREFIX = "brax:"


@dataclass
class Args:
    """Distributed PPO with GAE (thesis ch. 5) on an MJX robot environment."""

    ppo: Annotated[PPOConfig, tyro.conf.OmitArgPrefixes]
    """PPO hyper-parameters (defaults: the preset's values)."""
    env: str = "arm7"
    """Environment: a registered name (envs_mjx.names()) or brax:<name> for brax's own envs."""
    preset: str = "auto"
    """Hyper-parameter preset: auto (fast on a GPU, else cpu), thesis, cpu or fast (presets may also
    set env options: arm7 runs in kinematic mode under thesis and cpu; --env-config overrides)."""
    seed: int = 0
    """Random seed of the run (training); evaluation uses a separate stream derived from it."""
    reward: str | None = None
    """Reward function of the env (arm7: sparse, shaped, ordinary, path); None keeps the env's default."""
    env_config: tuple[str, ...] = ()
    """Further env settings as KEY=VALUE (e.g. mode=kinematic, trajectory=ellipse)."""
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
    """Stop early, resumably, once this many env steps are done (0: run to the end)."""
    progress: bool | None = None
    """Show a progress bar (default: only on a terminal and not under CI)."""


def _parse_value(text: str) -> Any:
    try:
        value = json.loads(text)
    except json.JSONDecodeError:
        return text
    return tuple(value) if isinstance(value, list) else value


def env_overrides(args: Any) -> dict[str, Any]:
    """Env settings from ``--reward`` and ``--env-config KEY=VALUE``."""
    out: dict[str, Any] = {}
    if args.reward is not None:
        out["reward"] = args.reward
    for item in args.env_config or ():
        if "=" not in item:
            raise ValueError(f"--env-config {item!r}: expected KEY=VALUE")
        k, v = item.split("=", 1)
        out[k.strip().replace("-", "_")] = _parse_value(v.strip())
    return out


def make_env(name: str, overrides: dict[str, Any]):
    """An unbatched env: ``envs_mjx.make(name, **overrides)`` or ``brax.envs.get_environment``."""
    import envs_mjx

    if name.startswith(BRAX_PREFIX):
        from brax import envs as brax_envs

        bname = name[len(BRAX_PREFIX) :]
        if bname not in brax_envs._envs:
            raise ValueError(f"unknown brax environment {bname!r}; valid: {', '.join(sorted(brax_envs._envs))}")
        return brax_envs.get_environment(bname, **overrides)
    if name not in envs_mjx.names():
        raise ValueError(
            f"unknown environment {name!r}; valid names: {', '.join(envs_mjx.names())} (or brax:<name>)"
        )
    return envs_mjx.make(name, **overrides)


def _episode_length(env, cfg_len: int = 0) -> int:
    """The configured time limit, else the env's ``episode_length``, else 1000 (brax's default)."""
    return int(cfg_len or getattr(env, "episode_length", 0) or 1000)


def build(args: Args):
    """``(env, trainer, config dict)`` for ``args`` (a fresh run or a saved config)."""
    from jaxrl_robot import parallel
    from jaxrl_robot.agents.ppo import make_trainer

    env = make_env(args.env, {**ppo_env_overrides(args.preset, args.env), **env_overrides(args)})
    cfg = args.ppo
    if not cfg.episode_length:
        cfg = cfg.replace(episode_length=_episode_length(env))
    cfg.validate()
    mesh = parallel.lane_mesh(args.devices or None)
    total_iterations = -(-cfg.total_steps // (cfg.num_envs * cfg.unroll_length))
    per_chunk = max(1, -(-total_iterations // max(args.chunks, 1)))
    trainer = make_trainer(cfg, env, mesh=mesh, iterations_per_update=per_chunk)
    config = {
        "algo": "ppo",
        "args": {k: v for k, v in dataclasses.asdict(args).items() if k != "ppo"},
        "ppo": dataclasses.asdict(cfg),
        "iterations_per_chunk": per_chunk,
        "devices": mesh.shape[parallel.LANES],
    }
    return env, trainer, config


def _preparse(argv: list[str]) -> argparse.Namespace:
    pre = argparse.ArgumentParser(add_help=False)
    pre.add_argument("--env", default="arm7")
    pre.add_argument("--preset", default="auto")
    pre.add_argument("--resume", default=None)
    pre.add_argument("--reward", default=None)
    pre.add_argument("--env-config", dest="env_config", nargs="*", default=())
    known, _ = pre.parse_known_args(argv)
    return known


def _args_from_saved(run_dir: str, argv_args: Args) -> Args:
    saved = common.load_config(run_dir)
    a = dict(saved["args"])
    ppo = dict(saved["ppo"])
    for k in ("sigma", "actor_hidden", "critic_hidden"):
        ppo[k] = tuple(ppo[k])
    ppo["schedule"] = tuple((s, n, v) for s, n, v in ppo["schedule"])
    a["env_config"] = tuple(a.get("env_config", ()))
    a["resume"] = run_dir
    a["stop_after_steps"] = argv_args.stop_after_steps
    a["progress"] = argv_args.progress
    return Args(ppo=PPOConfig(**ppo), **a)


def parse(argv: list[str] | None = None) -> Args:
    """Parse the command line: preset defaults for ``--env`` first, then every flag."""
    argv = sys.argv[1:] if argv is None else list(argv)
    known = _preparse(argv)
    preset = known.preset
    if known.resume:
        default_cfg = PPOConfig()
    else:
        preset = resolve_preset(known.preset)
        probe = make_env(known.env, {**ppo_env_overrides(preset, known.env), **env_overrides(known)})
        default_cfg, _ = ppo_preset(preset, known.env, _episode_length(probe), int(probe.action_size))
    args = tyro.cli(Args, args=argv, default=Args(ppo=default_cfg, env=known.env, preset=preset))
    args = dataclasses.replace(args, preset=resolve_preset(args.preset))
    if args.resume:
        args = _args_from_saved(args.resume, args)
    return args


def main(argv: list[str] | None = None) -> int:
    """Entry point; returns the process exit code."""
    return common.cli_main("ppo", lambda: parse(argv), lambda args: build(args))


if __name__ == "__main__":
    sys.exit(main())
