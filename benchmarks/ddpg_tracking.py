"""DDPG, TD3 and distributed DDPG tracking errors beside the thesis's Tables 4.3-4.5, seeds vmapped.

    python -m benchmarks.ddpg_tracking                    # scara, sine, ellipse; ddpg, td3, distributed; 3 seeds
    python -m benchmarks.ddpg_tracking --references sine --methods td3 --env-config a_p=100 --label ap100

Each (reference, method) trains ``--seeds`` agents of the ``--preset`` (``fast`` on a GPU) vmapped
over their keys in one program, then runs every agent's deterministic test episode from ``t = 0``
(``envs_mjx.tracking.rollout``).  The methods are the command lines' configurations:

- ``ddpg``: ``python -m train.ddpg``'s preset (for tracking, ``cpu`` and ``fast`` already use twin
  critics and a policy delay of 2, see ``train/presets/``);
- ``td3``: ``python -m train.td3``'s (that preset with target smoothing, Eq. 6.2-6.3);
- ``distributed``: ``python -m train.ddpg --distributed`` (thesis §4.2: synchronous workers
  averaging gradients, collecting workers with copies fetched every 5 iterations);
- ``distributed-td3``: ``python -m train.td3 --distributed``.

References: ``scara`` (the SCARA's reference, Table 4.3), ``sine`` and ``ellipse`` (the unicycle's,
Tables 4.4-4.5).  ``--set FIELD=VALUE`` overrides DDPG fields and ``--env-config KEY=VALUE`` env
settings (on top of the preset's, ``train.presets.ddpg_env_overrides``) for every run; ``--label``
names the variant.
"""

from __future__ import annotations

import argparse
import dataclasses
from typing import Any

import envs_mjx
from benchmarks import seeds as bench_seeds
from benchmarks import tracking_report
from benchmarks.tracking_report import GOAL, THESIS, pairs
from envs_mjx import tracking
from jaxrl_robot.agents.ddpg import make_train, make_trainer
from train.presets import ddpg_env_overrides, ddpg_preset
from train.td3 import TD3_SETTINGS

REFERENCES = {"scara": ("scara", {}), "sine": ("unicycle", {"trajectory": "sine"}),
              "ellipse": ("unicycle", {"trajectory": "ellipse"})}  # fmt: skip
"""reference -> (env name, env settings)."""

METHODS = {"ddpg": (False, {}), "td3": (False, TD3_SETTINGS), "distributed": (True, {}),
           "distributed-td3": (True, TD3_SETTINGS)}  # fmt: skip
"""method -> (distributed, config changes)."""



def config_for(reference: str, method: str, args: argparse.Namespace, env: Any):
    """The DDPGConfig of ``method`` on ``reference`` under ``args`` (preset, ``--set``, ``--total-steps``)."""
    env_name = REFERENCES[reference][0]
    distributed, changes = METHODS[method]
    config = ddpg_preset(args.preset, env_name, env.episode_length, distributed=distributed)
    config = config.replace(**changes, **pairs(args.set))
    if args.total_steps:
        config = config.replace(total_steps=args.total_steps)
    return config


def run_case(reference: str, method: str, args: argparse.Namespace) -> dict[str, Any]:
    """Train ``args.seeds`` agents of one method on one reference; their test-episode error sums."""
    env_name, settings = REFERENCES[reference]
    user = {**settings, **pairs(args.env_config)}
    preset = ddpg_env_overrides(args.preset, env_name, method, user.get("trajectory"))
    env = envs_mjx.make(env_name, **{**preset, **user})
    config = config_for(reference, method, args, env)
    trainer = make_trainer(config, env)

    def test(state):
        return tracking.rollout(env, trainer.policy(state))

    keys = bench_seeds.keys(args.seed_ids)
    result, metrics, compile_s, train_s = tracking_report.train_seeds(make_train(config, env), test, keys, True)
    fields = ("total_steps", "num_envs", "batch_size", "gamma", "twin_critics", "target_noise", "policy_delay",
              "sync_workers", "collect_workers", "fetch_every")
    return tracking_report.summarise(
        result, metrics, "episode_return",
        reference=reference, method=method, label=args.label,
        config={**{f: getattr(config, f) for f in fields}, "distributed": config.distributed,
                "set": args.set, "env_config": args.env_config},
        algo_config=dataclasses.asdict(config), env_config=dataclasses.asdict(env.config),
        seeds=args.seeds, seeds_vmapped=True,
        env_steps=int(trainer.env_steps_per_update * trainer.num_updates),
        updates=int(metrics["updates"][0, -1]),
        compile_s=compile_s, train_s=train_s, thesis=THESIS.get((reference, method)), goal=GOAL[reference],
    )  # fmt: skip


def to_markdown(result: dict[str, Any]) -> str:
    return tracking_report.to_markdown(
        result, f"DDPG-family tracking, `{result['preset']}` preset",
        "Seeds vmapped in one program; `ddpg` = `train.ddpg`'s preset, `td3` = `train.td3`'s, "
        "`distributed` = `train.ddpg --distributed`.", third="θ / z",
    )


def main(argv: list[str] | None = None) -> dict[str, Any]:
    methods = (["ddpg", "td3", "distributed"], list(METHODS))
    return tracking_report.cli("ddpg_tracking", __doc__, ("references", list(REFERENCES)), methods, run_case,
                               to_markdown, argv)  # fmt: skip


if __name__ == "__main__":
    main()
