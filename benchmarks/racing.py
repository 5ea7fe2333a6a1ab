"""Thesis Tables 6.2–6.3: racing among nine opponents, 20 laps on each of the four roads.

    python -m benchmarks.racing --preset fast --seeds 3 --methods expert imitation ddpg td3

Methods: ``expert`` (the scripted driver, :func:`envs_mjx.racecar.expert_action`; no training),
``imitation`` (the actor after the imitation stage alone: ``pretrain_steps = total_steps``),
``ddpg`` (imitation, then DDPG: ``train.ddpg --env racecar``) and ``td3`` (imitation, then TD3:
``train.td3 --env racecar``), each with the preset's settings (``train/presets/``), trained on
the training road only.  The seeds of a method run as one vmapped program.  Per road and seed:
laps ending in success, a collision, out of the track or stalled (:data:`envs_mjx.racecar.LAP_OUTCOMES`),
the laps whose collisions touched another car or a wall,
mean overtakes and mean speed; the goal is at least 19 successes of 20 on every road with at
most one collision.  Writes ``benchmarks/results/<device>-racing[-label].md`` and ``.json``.
"""

from __future__ import annotations

import argparse
import os
import time
from typing import Any

import jax
import numpy as np

import envs_mjx
from benchmarks import provenance
from benchmarks import seeds as bench_seeds
from benchmarks.arguments import nonnegative, positive
from benchmarks.tracking_report import pairs, train_seeds
from envs_mjx import racetrack
from envs_mjx.racecar import CONTACTS, LAP_OUTCOMES, expert_action, lap_summary, make_lap_test
from jaxrl_robot.agents.ddpg import make_train, make_trainer
from train.presets import ddpg_env_overrides, ddpg_preset
from train.td3 import TD3_SETTINGS

METHODS = ("expert", "imitation", "ddpg", "td3")
ROADS = tuple(racetrack.ROADS)
THESIS = {  # (success, collision, out of track, overtakes) of 20 laps, Tables 6.2 (DDPG) and 6.3 (TD3)
    "ddpg": {"train": (18, 2, 0, 2.65), "test1": (16, 2, 2, 2.55), "test2": (17, 2, 1, 2.6), "test3": (18, 1, 1, 2.85)},
    "td3": {"train": (18, 2, 0, 2.6), "test1": (17, 2, 1, 2.65), "test2": (18, 1, 1, 2.9), "test3": (17, 2, 1, 2.7)},
}
GOAL = "≥ 19/20 successes on every road, ≤ 1 collision"


def device_label() -> str:
    d = jax.devices()[0]
    return "cpu" if d.platform == "cpu" else f"gpu-{d.device_kind}".replace(" ", "_").lower()


def config_for(method: str, preset: str, env: Any, overrides: dict[str, Any]):
    """The DDPGConfig of ``method`` (imitation, ddpg, td3) under ``preset`` with ``overrides``."""
    cfg = ddpg_preset(preset, "racecar", int(env.episode_length))
    if method == "td3":
        cfg = cfg.replace(**TD3_SETTINGS)
    cfg = cfg.replace(**overrides)
    if method == "imitation":  # after the overrides: a --set total_steps still imitates for the whole run
        cfg = cfg.replace(pretrain_steps=cfg.total_steps)
    return cfg.validate()


def per_seed(results: dict[str, np.ndarray]) -> list[dict[str, dict]]:
    """``[S, R, laps]`` lap arrays -> one :func:`lap_summary` per seed."""
    seeds = np.asarray(results["success"]).shape[0]
    return [lap_summary({k: np.asarray(v)[i] for k, v in results.items()}, ROADS) for i in range(seeds)]


def aggregate(seeds: list[dict[str, dict]]) -> dict[str, dict[str, Any]]:
    """Per road: each outcome's and figure's mean, std and median over seeds, and the per-seed values."""
    out = {}
    for road in ROADS:
        row: dict[str, Any] = {}
        for k in (*LAP_OUTCOMES, *CONTACTS, "overtakes", "speed_kmh"):
            vals = np.array([s[road][k] for s in seeds], float)
            row[k] = {"mean": float(vals.mean()), "std": float(vals.std()), "median": float(np.median(vals)),
                      "seeds": vals.tolist()}  # fmt: skip
        laps = seeds[0][road]["laps"]
        row["met"] = bool(all(s[road]["success"] >= 0.95 * laps and s[road]["collision"] <= 0.05 * laps for s in seeds))
        out[road] = row
    return out


def run_method(method: str, args: argparse.Namespace, env: Any) -> dict[str, Any]:
    """Train (unless ``expert``) ``args.seeds`` seeds and drive ``args.laps`` laps per road with each."""
    test = make_lap_test(env, args.laps, ROADS)
    k_test = jax.random.PRNGKey(args.test_key)
    t0 = time.perf_counter()
    if method == "expert":
        result = jax.device_get(jax.jit(lambda k: test(expert_action, k))(k_test))
        seeds = [lap_summary(result, ROADS)]
        return {"method": method, "seeds": seeds, "roads": aggregate(seeds), "wall_s": time.perf_counter() - t0}
    cfg = config_for(method, args.preset, env, pairs(args.set))
    trainer = make_trainer(cfg, env, iterations_per_update=max(1, cfg.iterations // 20))
    train = make_train(cfg, env, iterations_per_update=max(1, cfg.iterations // 20))

    def lap(state):
        return test(lambda e, s: trainer.policy(state)(s.obs), k_test)

    keys = bench_seeds.keys(args.seed_ids)
    results, metrics, compile_s, train_s = train_seeds(train, lap, keys, vmapped=not args.sequential)
    seeds = per_seed(results)
    curve = {k: np.asarray(metrics[k]).tolist() for k in ("episode_return", "success", "collisions") if k in metrics}
    return {"method": method, "config": {k: v for k, v in vars(cfg).items()}, "seeds": seeds,
            "roads": aggregate(seeds), "compile_s": compile_s, "train_s": train_s,
            "wall_s": time.perf_counter() - t0, "env_steps": cfg.iterations * cfg.lanes * cfg.unroll_length,
            "curves": curve}  # fmt: skip


def seed_cell(meta: dict[str, Any]) -> str:
    """The seeds in words: their ids and range (:mod:`benchmarks.seeds`), or the key they were split from in a
    file written before."""
    if "seed_ids" in meta:
        return f"seeds {', '.join(map(str, meta['seed_ids']))} ({meta['purpose']} range)"
    return f"{meta['seeds']} seeds from key {meta['seed0']}"


def to_markdown(report: dict[str, Any]) -> str:
    meta = report["meta"]
    lines = [
        f"# Racing with opponents, Tables 6.2–6.3 — {meta['device']}",
        "",
        f"`{meta['command']}` at commit {meta['commit']} ({provenance.tree_words(report['provenance'])}); "
        f"preset `{meta['preset']}`, {seed_cell(meta)}, {meta['laps']} laps per road "
        f"per seed (random starts and opponents, test key {meta['test_key']}); env overrides "
        f"{meta['env_overrides']}. Goal: {GOAL}. Cells: mean ± std over seeds of the laps of each outcome "
        "(success / collision / out of track / stalled), the laps whose collisions touched another car and a "
        "wall, mean overtakes per lap, mean speed; the thesis's (success / collision / out / overtakes) beside.",
        "",
        "| method | road | success | collision | car / wall | out of track | stalled | overtakes | km/h | thesis "
        "| met | successes per seed (median) |",
        "|---|---|---:|---:|---:|---:|---:|---:|---:|---|---|---|",
    ]
    for case in report["cases"]:
        for road, row in case["roads"].items():
            cell = lambda k, d=1, row=row: f"{row[k]['mean']:.{d}f} ± {row[k]['std']:.{d}f}"  # noqa: E731
            thesis = THESIS.get(case["method"], {}).get(road)
            th = " / ".join(f"{v:g}" for v in thesis) if thesis else "—"
            seeds = ", ".join(f"{v:g}" for v in row["success"]["seeds"])
            seeds += f" ({row['success']['median']:g})" if "median" in row["success"] else ""
            lines.append(
                f"| {case['method']} | {road} | {cell('success')} | {cell('collision')} | "
                f"{row['car_contact']['mean']:.1f} / {row['wall_contact']['mean']:.1f} | {cell('out_of_track')} | "
                f"{cell('stalled')} | {cell('overtakes', 2)} | {cell('speed_kmh', 0)} | {th} | "
                f"{'yes' if row['met'] else 'no'} | {seeds} |"
            )
    lines += ["", "| method | env steps | compile s | train s | wall s |", "|---|---:|---:|---:|---:|"]
    for case in report["cases"]:
        lines.append(f"| {case['method']} | {case.get('env_steps', 0):,} | {case.get('compile_s', 0):.0f} | "
                     f"{case.get('train_s', 0):.0f} | {case['wall_s']:.0f} |")  # fmt: skip
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> dict[str, Any]:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--methods", nargs="+", default=list(METHODS), choices=METHODS)
    p.add_argument("--preset", default="fast", choices=("thesis", "cpu", "fast"))
    bench_seeds.add_args(p)
    p.add_argument("--laps", type=positive, default=20, help="test laps per road and seed")
    p.add_argument("--test-key", type=nonnegative, default=1)
    p.add_argument("--set", nargs="*", default=[], metavar="FIELD=VALUE", help="DDPGConfig overrides")
    p.add_argument("--env-config", nargs="*", default=[], metavar="KEY=VALUE", help="racecar overrides")
    p.add_argument("--sequential", action="store_true", help="one program per seed instead of vmapped seeds")
    provenance.add_args(p)
    p.add_argument("--label", default="")
    p.add_argument("--out", default=os.path.join(os.path.dirname(__file__), "results"))
    args = p.parse_args(argv)
    overrides = {**ddpg_env_overrides(args.preset, "racecar"), **pairs(args.env_config)}
    env = envs_mjx.make("racecar", **overrides)
    try:
        args.seed_ids = bench_seeds.seed_ids(args.purpose, args.seeds, args.first_seed)
    except ValueError as e:
        p.error(f"--seeds/--first-seed: {e}")
    how = f"training key PRNGKey(seed); test key PRNGKey({args.test_key})"
    seeds = bench_seeds.record(args.purpose, args.seed_ids, how)
    prov = provenance.record("benchmarks.racing", argv, seeds=seeds, allow_dirty=args.allow_dirty)
    meta = {"device": device_label(), "command": prov["command"], "commit": prov["commit"], "preset": args.preset,
            "seeds": args.seeds, "purpose": args.purpose, "seed_ids": args.seed_ids,
            "laps": args.laps, "test_key": args.test_key, "env_overrides": overrides}  # fmt: skip
    report: dict[str, Any] = {"provenance": prov, "meta": meta, "cases": []}
    os.makedirs(args.out, exist_ok=True)
    stem = os.path.join(args.out, f"{meta['device']}-racing" + (f"-{args.label}" if args.label else ""))
    for method in args.methods:
        case = run_method(method, args, env)
        report["cases"].append(case)
        for road, row in case["roads"].items():
            print(
                f"{method:9s} {road:6s} success {row['success']['mean']:5.2f} ± {row['success']['std']:.2f} "
                f"collision {row['collision']['mean']:5.2f} out {row['out_of_track']['mean']:5.2f} "
                f"overtakes {row['overtakes']['mean']:.2f} {row['speed_kmh']['mean']:.0f} km/h",
                flush=True,
            )
        provenance.write(stem, report, to_markdown(report))  # after every method: a cut-off run keeps what it finished
    print(f"wrote {stem}.md")
    return report


if __name__ == "__main__":
    import sys

    main(sys.argv[1:])
