"""Our PPO beside brax's own on brax's standard tasks: return at equal env steps, wall time, steps/s.

    python -m benchmarks.brax_tasks                                   # 5 tasks, 3 seeds, brax's budgets
    python -m benchmarks.brax_tasks --tasks inverted_pendulum --seeds 3
    python -m benchmarks.brax_tasks --tasks reacher --steps 5000000    # a shorter budget for both

Both train on the same env object (``brax.envs.get_environment(task, backend=--backend)``, MJX by
default) for the same env steps with the settings of :data:`train.presets.BRAX_PPO`: brax's
``ppo.train`` takes the row as it is; ours takes it through :func:`train.presets.brax_ppo_config`
(``python -m train.ppo --env brax:<task>`` picks the same preset). Our seeds run through one compiled
program called per seed (``--seed-map vmap``: one vmapped program), brax's one after another.

* **return**: brax: its own final evaluation (``eval/episode_reward``, deterministic policy, 128
  episodes of ``episode_length`` steps); ours: the deterministic policy on ``--eval-episodes`` fresh
  episodes of the same length (:func:`jaxrl_robot.evaluation.run_test_episodes`). Mean ± std over seeds.
* **wall**: from the call to the trained parameters, compilation included (per seed: the seeds' total
  over their number); brax's includes the 10 evaluations its ``ppo.train`` runs along the way
  (128 episodes each), ours has no evaluation inside training; **env steps/s**: env steps of all
  seeds over that wall time.

Goals (issue 15): per task our return ≥ brax's and our wall per seed ≤ brax's. Results:
``benchmarks/results/<device>-brax_tasks.json`` and ``.md`` with one learning-curve figure per task.
"""

from __future__ import annotations

import argparse
import os
import time
from typing import Any

import jax
import numpy as np

from benchmarks import provenance
from benchmarks.train_throughput import RESULTS, device_label
from jaxrl_robot import plots
from jaxrl_robot.agents.ppo import make_trainer
from jaxrl_robot.evaluation import run_test_episodes
from train.presets import BRAX_PPO, brax_ppo_config


def brax_row(task: str, num_envs: int) -> dict[str, float]:
    """The task's :data:`BRAX_PPO` row; with ``num_envs`` that many envs and the batch scaled alike
    (the same unrolls per env and mini-batches per pass: a small machine's version of the task)."""
    row = dict(BRAX_PPO[task])
    if num_envs:
        row["batch_size"] = max(1, int(row["batch_size"] * num_envs) // int(row["num_envs"]))
        row["num_envs"] = num_envs
    return row


def ours(env: Any, task: str, row: dict[str, float], steps: int, seeds: int, eval_episodes: int,
         seed_map: str = "loop") -> dict[str, Any]:  # fmt: skip
    """Train our PPO on ``seeds`` keys, one vmapped program (``seed_map='vmap'``) or one compiled
    program called per key (``'loop'``); returns, curves and wall time (compilation included)."""
    config = brax_ppo_config(task, int(env.action_size), **row).replace(total_steps=steps)
    trainer = make_trainer(config, env)

    def train(key: jax.Array) -> tuple[Any, Any]:
        state = trainer.init(key)
        return jax.lax.scan(lambda s, _: trainer.update(s), state, None, length=trainer.num_updates)

    def test(state: Any, key: jax.Array) -> jax.Array:
        return run_test_episodes(key, env, trainer.policy(state), eval_episodes, config.episode_length)["return"]

    keys, eval_keys = jax.random.split(jax.random.PRNGKey(0), seeds), jax.random.split(jax.random.PRNGKey(1), seeds)
    t0 = time.perf_counter()
    if seed_map == "vmap":
        states, metrics = jax.block_until_ready(jax.jit(jax.vmap(train))(keys))
        wall = time.perf_counter() - t0
        returns = np.asarray(jax.jit(jax.vmap(test))(states, eval_keys)).mean(axis=1)
        per_chunk = np.asarray(metrics["episode_return"])  # [seeds, chunks]: training episodes (NaN: none ended)
    else:
        train_one, test_one = jax.jit(train), jax.jit(test)
        runs = [jax.block_until_ready(train_one(k)) for k in keys]
        wall = time.perf_counter() - t0
        returns = np.array([float(np.mean(test_one(st, k))) for (st, _), k in zip(runs, eval_keys, strict=True)])
        per_chunk = np.stack([np.asarray(m["episode_return"]) for _, m in runs])
    done = trainer.env_steps_per_update * (np.arange(per_chunk.shape[1]) + 1)
    return {"returns": returns.tolist(), "wall_s": wall, "wall_per_seed_s": wall / seeds, "seed_map": seed_map,
            "env_steps": int(done[-1]), "env_steps_per_s": seeds * done[-1] / wall,
            "curve_steps": done.tolist(), "curves": per_chunk.tolist()}  # fmt: skip


def theirs(env: Any, row: dict[str, float], steps: int, seeds: int) -> dict[str, Any]:
    """brax's ``ppo.train`` with the task's ``row`` (brax's terms), one seed after another."""
    from benchmarks.peers.brax_ppo import train_published

    runs = [train_published(env, row, steps, seed) for seed in range(seeds)]
    walls = [r["wall_s"] for r in runs]
    return {"returns": [r["final_return"] for r in runs], "wall_s": float(sum(walls)),
            "wall_per_seed_s": float(np.mean(walls)), "env_steps": runs[0]["env_steps"],
            "env_steps_per_s": sum(r["env_steps"] for r in runs) / sum(walls),
            "curve_steps": runs[0]["curve_steps"], "curves": [r["curve"] for r in runs]}  # fmt: skip


def to_markdown(result: dict[str, Any]) -> str:
    out = [f"# Our PPO beside brax's PPO on brax's tasks — {result['device']}", "",
           f"Backend `{result['backend']}`; {result['seeds']} seeds of ours ({result['seed_map']}), "
           f"{result['brax_seeds']} of brax's (one after another); the same env steps and settings "
           "(`train.presets.BRAX_PPO`). Return: deterministic "
           "policy on fresh episodes (ours: "
           f"{result['eval_episodes']} episodes; brax: its own final evaluation). Wall: compilation included. "
           "Bold: at the goal (our return ≥ brax's; our wall per seed ≤ brax's).", "",
           "| task | env steps | brax return | our return | brax wall per seed s | our wall per seed s "
           "| brax env steps/s | our env steps/s | our / brax return |",
           "|---|---:|---:|---:|---:|---:|---:|---:|---:|"]  # fmt: skip
    for t in result["tasks"]:
        b, o = t["brax"], t["ours"]
        rb, ro = np.mean(b["returns"]), np.mean(o["returns"])
        won, fast = ro >= rb, o["wall_per_seed_s"] <= b["wall_per_seed_s"]
        cell = f"{ro:.1f} ± {np.std(o['returns']):.1f}"
        wall = f"{o['wall_per_seed_s']:.0f}"
        out.append(f"| {t['task']} | {o['env_steps']:,} | {rb:.1f} ± {np.std(b['returns']):.1f} "
                   f"| {'**' + cell + '**' if won else cell} | {b['wall_per_seed_s']:.0f} "
                   f"| {'**' + wall + '**' if fast else wall} | {b['env_steps_per_s']:,.0f} "
                   f"| {o['env_steps_per_s']:,.0f} | {ro / rb if rb else float('nan'):.2f} |")  # fmt: skip
        out.append("")
    for t in result["tasks"]:
        out.append(f"![{t['task']}]({os.path.basename(result['figures'])}/{t['task']}.png)")
    return "\n".join(out) + "\n"


def figure(task: dict[str, Any], out_dir: str) -> str | None:
    """Ours: mean return of the training episodes that ended in each chunk; brax: its evaluations."""
    curves = {
        name: [[{"env_steps": x, "episode_return": y} for x, y in zip(task[name]["curve_steps"], seed, strict=True)]
               for seed in task[name]["curves"]]
        for name in ("ours", "brax") if task[name].get("curves")
    }  # fmt: skip
    return plots.plot_seed_bands(curves, "episode_return", out_dir, f"{task['task']}.png", task["task"])


def main(argv: list[str] | None = None) -> dict[str, Any]:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--tasks", nargs="+", default=list(BRAX_PPO), choices=list(BRAX_PPO))
    p.add_argument("--seeds", type=int, default=3)
    p.add_argument("--brax-seeds", type=int, default=0, help="brax's seeds (0: --seeds)")
    p.add_argument("--steps", type=int, default=0, help="env steps per seed (0: brax's budget of the task)")
    p.add_argument("--backend", default="mjx", help="brax physics backend (mjx, generalized, positional, spring)")
    p.add_argument("--eval-episodes", type=int, default=128)
    p.add_argument("--num-envs", type=int, default=0, help="envs of both trainers, batch scaled alike (0: the row's)")
    p.add_argument("--no-brax", action="store_true", help="ours only")
    p.add_argument("--seed-map", default="loop", choices=["loop", "vmap"],
                   help="our seeds: one program called per seed, or one vmapped program (XLA's CPU compiler "
                   "stops with a floating point exception on the vmapped MJX program, jax 0.10.2)")  # fmt: skip
    p.add_argument("--out", default=RESULTS)
    provenance.add_args(p)
    args = p.parse_args(argv)
    from brax import envs as brax_envs

    brax_seeds = args.brax_seeds or args.seeds
    prov = provenance.record("benchmarks.brax_tasks", argv, seeds=f"ours: split(PRNGKey(0), {args.seeds}); brax: "
                             f"seed 0..{brax_seeds - 1}", commit=args.commit)  # fmt: skip
    stem = f"{args.out}/{device_label()}-brax_tasks"
    result = {"benchmark": "brax_tasks", "provenance": prov, "device": device_label(), "backend": args.backend,
              "seeds": args.seeds, "seed_map": args.seed_map, "brax_seeds": brax_seeds,
              "eval_episodes": args.eval_episodes,
              "figures": stem + "-figures", "tasks": []}  # fmt: skip
    os.makedirs(result["figures"], exist_ok=True)
    for task in args.tasks:
        env = brax_envs.get_environment(task, backend=args.backend)
        steps = args.steps or int(BRAX_PPO[task]["num_timesteps"])
        settings = brax_row(task, args.num_envs)
        row = {"task": task, "settings": settings,
               "ours": ours(env, task, settings, steps, args.seeds, args.eval_episodes, args.seed_map)}
        print(task, "ours", [round(r, 1) for r in row["ours"]["returns"]], f"{row['ours']['wall_s']:.0f} s", flush=True)
        if not args.no_brax:
            row["brax"] = theirs(env, settings, steps, brax_seeds)
            print(task, "brax", [round(r, 1) for r in row["brax"]["returns"]], f"{row['brax']['wall_s']:.0f} s",
                  flush=True)  # fmt: skip
        else:
            row["brax"] = {**row["ours"], "returns": [float("nan")] * args.seeds, "curves": []}
        figure(row, result["figures"])
        result["tasks"].append(row)
        provenance.write(stem, result, to_markdown(result), echo=task == args.tasks[-1])
    return result


if __name__ == "__main__":
    main()
