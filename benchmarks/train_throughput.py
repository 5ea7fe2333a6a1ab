"""End-to-end PPO training throughput on ``arm7``: ours over lane counts, and brax's PPO, in one run.

    python -m benchmarks.train_throughput                      # sizes chosen for the device
    python -m benchmarks.train_throughput --lanes 1024 4096 --brax-lanes 4096 --mode pd
    python -m benchmarks.train_throughput --reset-refresh 0.125 1.0   # reset pool vs a fresh reset per lane

For each lane count K our PPO (``jaxrl_robot.agents.ppo``) trains with N = 16 steps per lane per
iteration and 4 actor + 4 critic updates on mini-batches of K·N/4; one call of the jitted chunk
runs ``--chunk-iters`` iterations. Compilation is timed apart (``lower().compile()``), then the
median of ``--repeats`` timed chunk calls (``block_until_ready``) gives env-steps/s (env steps
include everything: acting, physics, returns, updates). ``--reset-refresh`` lists the auto-reset
settings to run (``PPOConfig.reset_refresh``: below 1 the lanes restart from a pool of pre-drawn
episodes, 1 draws a fresh reset for every lane at every step); the ratio uses the first.

brax's ``ppo.train`` (``benchmarks/peers/brax_ppo.py``, with its labelled JAX-compat shim) runs on
the same env object and device with the same K, N, four mini-batch updates per iteration and
2 x 200 networks; its own per-epoch ``training/sps`` is used, the first (compiling) epoch dropped.

Results: ``benchmarks/results/<device>-train_throughput-<mode>.json`` and ``.md``.
"""

from __future__ import annotations

import argparse
import os
import platform
import statistics
import time
from typing import Any

import jax
import numpy as np

import envs_mjx
from benchmarks import provenance
from benchmarks.arguments import positive
from benchmarks.peers.brax_ppo import run_brax_ppo
from benchmarks.timing import compile_and_time
from jaxrl_robot.agents.ppo import PPOConfig, make_trainer

RESULTS = os.path.join(os.path.dirname(os.path.abspath(__file__)), "results")
SEEDS = "fixed in the code: ours PRNGKey(0), brax seed 0, every case"


def device_label() -> str:
    d = jax.devices()[0]
    label = f"cpu-{os.cpu_count()}core" if d.platform == "cpu" else f"{d.platform}-{d.device_kind}"
    return label.replace(" ", "_").lower()


def bench_ours(
    env: Any,
    lanes: int,
    unroll: int,
    chunk_iters: int,
    repeats: int,
    updates: int,
    reset_refresh: float,
    mesh: jax.sharding.Mesh | None = None,
    lane_group: int = 0,
) -> dict[str, Any]:
    """Steps/s of our PPO at ``lanes`` lanes over ``mesh`` (default all devices; compile apart, median of repeats)."""
    cfg = PPOConfig(
        num_envs=lanes, unroll_length=unroll, minibatch_size=lanes * unroll // updates, actor_updates=updates,
        critic_updates=updates, batch_norm=False, sigma=(0.5,), actor_hidden=(200, 200), critic_hidden=(200, 200),
        total_steps=lanes * unroll * chunk_iters, episode_length=int(env.episode_length), reset_refresh=reset_refresh,
        lane_group=lane_group,
    )  # fmt: skip
    trainer = make_trainer(cfg, env, mesh=mesh, iterations_per_update=chunk_iters)
    state = jax.block_until_ready(jax.jit(trainer.init)(jax.random.PRNGKey(0)))
    compile_s, times, _ = compile_and_time(trainer.update, state, repeats)
    med = statistics.median(times)
    return {
        "impl": "jaxrl_robot",
        "lanes": lanes,
        "devices": int(mesh.devices.size) if mesh is not None else len(jax.devices()),
        "reset_refresh": reset_refresh,
        "lane_group": lane_group,
        "unroll": unroll,
        "steps_per_call": trainer.env_steps_per_update,
        "compile_s": compile_s,
        "times_s": times,
        "median_s": med,
        "steps_per_s": trainer.env_steps_per_update / med,
    }


def bench_brax(env: Any, lanes: int, unroll: int, chunk_iters: int, repeats: int, updates: int) -> dict[str, Any]:
    out = run_brax_ppo(
        env, num_envs=lanes, unroll_length=unroll, num_minibatches=updates, iterations_per_epoch=chunk_iters,
        epochs=repeats, episode_length=int(env.episode_length),
    )  # fmt: skip
    return {"impl": "brax.ppo", "lanes": lanes, "unroll": unroll, "steps_per_s": out["timed_sps_median"], **out}


def markdown_head(title: str, result: dict[str, Any], *notes: str) -> list[str]:
    """``[# title, "", settings, ""]``: the title and the run's settings (jax, date, N, updates per
    iteration, iterations per timed call, repeats, then ``notes``) of a PPO throughput table."""
    u, r = result["updates"], result
    settings = (
        f"jax {r['jax']}, {r['date']}; N = {r['unroll']} steps per lane per iteration, {u} actor + {u} critic updates "
        f"per iteration, {r['chunk_iters']} iterations per timed call, median of {r['repeats']}"
    )
    return [f"# {title}", "", "; ".join([settings, *notes]) + ".", ""]


def to_markdown(result: dict[str, Any]) -> str:
    lines = [
        *markdown_head(
            f"PPO training throughput on arm7 ({result['env_config']['mode']}) — {result['device']}", result
        ),
        "| implementation | auto-reset | lanes | env-steps/s | compile s (brax: first epoch incl. compile) |",
        "|---|---|---:|---:|---:|",
    ]
    for r in result["runs"]:
        comp = r.get("compile_s", r.get("first_epoch_s", float("nan")))
        refresh = r.get("reset_refresh")
        reset = "cached first state" if refresh is None else ("fresh" if refresh >= 1 else f"pool, refresh {refresh:g}")
        lines.append(f"| {r['impl']} | {reset} | {r['lanes']} | {r['steps_per_s']:,.0f} | {comp:.1f} |")
    if result.get("ratio") is not None:
        lines += ["", f"Ratio ours / brax at {result['ratio_lanes']} lanes: **{result['ratio']:.2f}x**; best ours / "
                  f"brax: **{result['best_ratio']:.2f}x**."]  # fmt: skip
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> dict[str, Any]:
    on_cpu = jax.default_backend() == "cpu"
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--lanes", type=positive, nargs="+",
                   default=[32, 128, 512] if on_cpu else [1024, 4096, 16384, 65536])  # fmt: skip
    p.add_argument("--brax-lanes", type=positive, nargs="*", default=None, help="lane counts for brax (default: ours'")
    p.add_argument("--unroll", type=positive, default=16)
    p.add_argument("--updates", type=positive, default=4)
    p.add_argument("--chunk-iters", type=positive, default=4)
    p.add_argument("--repeats", type=positive, default=3)
    p.add_argument("--mode", default=None, help="arm7 physics mode (default: kinematic on CPU, pd otherwise)")
    p.add_argument(
        "--reset-refresh",
        type=float,
        nargs="+",
        default=[PPOConfig().reset_refresh],
        help="auto-reset refresh fractions for ours (the ratio uses the first)",
    )
    p.add_argument("--no-brax", action="store_true")
    p.add_argument("--out", default=RESULTS)
    provenance.add_args(p)
    args = p.parse_args(argv)
    prov = provenance.record("benchmarks.train_throughput", argv, seeds=SEEDS,
                             allow_dirty=args.allow_dirty)  # fmt: skip
    mode = args.mode or ("kinematic" if on_cpu else "pd")
    env = envs_mjx.make("arm7", mode=mode)
    runs = []
    for refresh in args.reset_refresh:
        for lanes in args.lanes:
            r = bench_ours(env, lanes, args.unroll, args.chunk_iters, args.repeats, args.updates, refresh)
            print(f"ours  refresh={refresh:g} lanes={lanes:6d}  {r['steps_per_s']:12,.0f} steps/s  "
                  f"compile {r['compile_s']:.1f}s", flush=True)  # fmt: skip
            runs.append(r)
    brax_lanes = args.lanes if args.brax_lanes is None else args.brax_lanes
    if not args.no_brax:
        for lanes in brax_lanes:
            try:
                r = bench_brax(env, lanes, args.unroll, args.chunk_iters, args.repeats, args.updates)
            except Exception as e:  # a peer failure is recorded, not fatal
                r = {"impl": "brax.ppo", "lanes": lanes, "steps_per_s": float("nan"), "error": repr(e)[:500]}
            print(f"brax  lanes={lanes:6d}  {r['steps_per_s']:12,.0f} steps/s", flush=True)
            runs.append(r)
    result: dict[str, Any] = {
        "benchmark": "train_throughput",
        "provenance": prov,
        "device": device_label(),
        "device_kind": jax.devices()[0].device_kind,
        "jax": jax.__version__,
        "host": platform.node(),
        "date": time.strftime("%Y-%m-%d %H:%M"),
        "env": "arm7",
        "env_config": {"mode": mode},
        "unroll": args.unroll,
        "updates": args.updates,
        "chunk_iters": args.chunk_iters,
        "repeats": args.repeats,
        "xla_flags": os.environ.get("XLA_FLAGS", ""),
        "runs": runs,
    }
    first = args.reset_refresh[0]
    ours = {r["lanes"]: r["steps_per_s"] for r in runs if r["impl"] == "jaxrl_robot" and r["reset_refresh"] == first}
    theirs = {r["lanes"]: r["steps_per_s"] for r in runs if r["impl"] == "brax.ppo" and np.isfinite(r["steps_per_s"])}
    common = sorted(set(ours) & set(theirs))
    if common:
        lanes = common[-1]
        result["ratio_lanes"] = lanes
        result["ratio"] = ours[lanes] / theirs[lanes]
        result["best_ratio"] = max(ours.values()) / max(theirs.values())
        print(f"ratio ours/brax at {lanes} lanes: {result['ratio']:.2f}x; best/best {result['best_ratio']:.2f}x")
    stem = os.path.join(args.out, f"{result['device']}-train_throughput-{mode}")
    provenance.write(stem, result, to_markdown(result), echo=True)
    return result


if __name__ == "__main__":
    main()
