"""PPO tracking errors on the unicycle beside the thesis's Tables 5.4-5.7, seeds vmapped in one program.

    python -m benchmarks.ppo_tracking        # sine + ellipse; mlp, two-stage, lstm; 3 seeds
    python -m benchmarks.ppo_tracking --methods mlp --trajectories sine --set gamma=0.995 --label gamma0995

Each (trajectory, method) trains ``--seeds`` agents of the ``--preset`` (``fast`` on a GPU),
vmapped over their keys (``--seed-map``; the recurrent one on the CPU: one compiled run per
key), then runs every agent's test episode from ``t = 0`` (``envs_mjx.tracking.rollout``; a
recurrent policy carries its LSTM state from the table's entry for step 0).  Metric: per axis,
the sum over the test episode of |reference − real| (x, y in m, θ in rad), as the thesis's
tables.  ``--set FIELD=VALUE`` overrides PPO hyper-parameters and ``--env-config KEY=VALUE``
unicycle settings (e.g.
``a_p=10``, ``observation=extended``; on top of the preset's, ``train.presets.ppo_env_overrides``)
for every run; ``--label`` names the variant.
"""

from __future__ import annotations

import argparse
import dataclasses
from typing import Any

import jax

import envs_mjx
from benchmarks import seeds as bench_seeds
from benchmarks import tracking_report
from benchmarks.tracking_report import GOAL, THESIS, pairs
from envs_mjx import tracking
from jaxrl_robot.agents.ppo import make_train, make_trainer
from jaxrl_robot.types import as_recurrent
from train.presets import ppo_preset
from train.seeds import SEED_MAPS

METHODS = {"mlp": ("mlp", "none"), "two-stage": ("mlp", "action-search"), "lstm": ("lstm", "none")}
"""method -> (policy, pretrain)."""



def run_case(trajectory: str, method: str, args: argparse.Namespace) -> dict[str, Any]:
    """Train ``args.seeds`` agents of one method on one trajectory; their test-episode error sums."""
    policy, pretrain = METHODS[method]
    probe = envs_mjx.make("unicycle", trajectory=trajectory)
    config, env_overrides = ppo_preset(args.preset, "unicycle", probe.episode_length, probe.action_size, policy,
                                       pretrain, trajectory)  # fmt: skip
    env = envs_mjx.make("unicycle", **{**env_overrides, "trajectory": trajectory, **pairs(args.env_config)})
    config = config.replace(**pairs(args.set))
    if args.total_steps:
        config = config.replace(total_steps=args.total_steps)
    trainer = make_trainer(config, env)

    def test(state):
        pol = as_recurrent(trainer.policy(state))
        return tracking.rollout(env, pol.step, None, pol.carry)

    keys = bench_seeds.keys(args.seed_ids)
    vmapped = seeds_vmapped(args.seed_map, config.policy)
    result, metrics, compile_s, train_s = tracking_report.train_seeds(make_train(config, env), test, keys, vmapped)
    return tracking_report.summarise(
        result, metrics, "reward",
        reference=trajectory, method=method, label=args.label,
        config={"total_steps": config.total_steps, "num_envs": config.num_envs, "policy": config.policy,
                "pretrain": config.pretrain, "gamma": config.gamma, "set": args.set, "env_config": args.env_config},
        algo_config=dataclasses.asdict(config), env_config=dataclasses.asdict(env.config),
        seeds=args.seeds, seeds_vmapped=vmapped,
        env_steps=int(trainer.env_steps_per_update * trainer.num_updates),
        compile_s=compile_s, train_s=train_s, thesis=THESIS[(trajectory, method)], goal=GOAL[trajectory],
    )  # fmt: skip


def seeds_vmapped(seed_map: str, policy: str, backend: str | None = None) -> bool:
    """Whether the seeds run as one vmapped program: ``seed_map`` ``'vmap'`` / ``'loop'``, or ``'auto'``:
    vmapped, except the recurrent policy on the CPU backend (vmapping it stalled XLA:CPU, jax 0.10.2),
    which runs one compiled program per seed."""
    if seed_map != "auto":
        return seed_map == "vmap"
    return policy == "mlp" or (backend or jax.default_backend()) != "cpu"


def to_markdown(result: dict[str, Any]) -> str:
    return tracking_report.to_markdown(
        result, f"PPO tracking on unicycle, `{result['preset']}` preset",
        "Seeds vmapped in one program (`--seed-map auto`: the lstm on the CPU one compiled program per seed).",
    )


def main(argv: list[str] | None = None) -> dict[str, Any]:
    return tracking_report.cli("ppo_tracking", __doc__, ("trajectories", ["sine", "ellipse"]),
                               (list(METHODS), list(METHODS)), run_case, to_markdown, argv,
                               extra_args=add_seed_map)  # fmt: skip


def add_seed_map(p: argparse.ArgumentParser) -> None:
    """``--seed-map auto|vmap|loop`` (:func:`seeds_vmapped`)."""
    p.add_argument("--seed-map", default="auto", choices=SEED_MAPS,
                   help="seeds as one vmapped program or one program each (auto: vmap, except lstm on the CPU)")


if __name__ == "__main__":
    main()
