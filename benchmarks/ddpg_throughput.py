"""Distributed DDPG throughput: collected env-steps/s and learner updates/s, beside single-learner DDPG.

    python -m benchmarks.ddpg_throughput                          # unicycle; GPU: 4k-64k lanes
    python -m benchmarks.ddpg_throughput --env scara --lanes 1024 4096 --updates 16 32

One timed call runs ``--iterations`` iterations of the 'steps' schedule (``trainer.update``, the
state carried on the device, donated); compile time apart, one warm-up call, the median of
``--repeats`` calls.  Per iteration every lane steps ``--unroll`` times, then the learner makes
``--updates`` updates:

* ``distributed``: distributed DDPG (thesis §4.2) with ``--sync-workers`` synchronous workers
  (each sampling its own prioritised mini-batch of ``--batch`` transitions, gradients averaged:
  ``sync_workers × batch`` transitions per update, 4 × 32 in the thesis) and as many collecting
  workers (fetching the parameters every 5 iterations); the lanes are split evenly between the
  two kinds of worker;
* ``single``: single-learner DDPG on the same lanes with one batch of ``sync_workers × batch``.

Both use PER, the thesis's 300-100 networks and a memory of 10^6.  Env steps/s counts every lane's
steps (collecting workers' included); updates/s counts the learner's updates (read from the
state's update counter, not assumed).  Goals (issue 12): ≥ 1 M collected env-steps/s on one H200
while the learner keeps ≥ 2 000 updates/s of 4 × 32 transitions; 2 GPUs ≥ 1.8 × the updates/s of
one at the same per-device work (the default mesh is every device: run it on 1 and 2 GPUs).

Results: ``benchmarks/results/<device>-ddpg_throughput.json`` and ``.md``.
"""

from __future__ import annotations

import argparse
import statistics
import time
from typing import Any

import jax

import envs_mjx
from benchmarks import provenance
from benchmarks.timing import compile_and_time
from benchmarks.tracking_report import pairs
from benchmarks.train_throughput import RESULTS, device_label
from jaxrl_robot.agents.ddpg import DDPGConfig, make_trainer

GOAL_STEPS, GOAL_UPDATES = 1_000_000, 2_000
SEEDS = "PRNGKey(0) for every case (fixed in the code)"


def config_for(kind: str, lanes: int, args: argparse.Namespace) -> DDPGConfig:
    """The DDPGConfig of one case: ``kind`` 'distributed' or 'single', ``lanes`` acting lanes in all."""
    w = args.sync_workers
    base = DDPGConfig(
        schedule="steps", total_steps=10**12, unroll_length=args.unroll, updates_per_iteration=args.updates,
        learning_starts=1, buffer_size=1_000_000, per=True, actor_hidden=(300, 100), critic_hidden=(300, 100),
        noise="gaussian", noise_scale=(0.1,), **pairs(args.set),
    )  # fmt: skip
    if kind == "single":
        return base.replace(num_envs=lanes, batch_size=w * args.batch)
    if lanes % (2 * w):
        raise SystemExit(f"error: --lanes {lanes} must be a multiple of 2 x --sync-workers ({2 * w})")
    return base.replace(distributed=True, num_envs=lanes // 2, batch_size=args.batch, sync_workers=w,
                        collect_workers=w, collect_lanes=lanes // (2 * w), fetch_every=5)  # fmt: skip


def bench(kind: str, lanes: int, args: argparse.Namespace) -> dict[str, Any]:
    """Time one case; returns its settings and figures."""
    env = envs_mjx.make(args.env, **pairs(args.env_config))
    config = config_for(kind, lanes, args)
    trainer = make_trainer(config, env, iterations_per_update=args.iterations)
    state = jax.block_until_ready(jax.jit(trainer.init)(jax.random.PRNGKey(0)))
    before = int(state.updates)
    compile_s, times, state = compile_and_time(trainer.update, state, args.repeats, donate=True)
    calls = args.repeats + 1  # the warm-up call learns too
    updates_per_call = (int(state.updates) - before) / calls
    med = statistics.median(times)
    return {
        "kind": kind, "lanes": config.lanes, "num_envs": config.num_envs, "unroll": args.unroll,
        "updates_per_iteration": args.updates, "transitions_per_update": args.sync_workers * args.batch,
        "iterations_per_call": args.iterations, "devices": jax.device_count(), "compile_s": compile_s,
        "call_s": med, "call_s_all": times, "env_steps_per_s": trainer.env_steps_per_update / med,
        "updates_per_s": updates_per_call / med, "updates_per_call": updates_per_call,
    }  # fmt: skip


def to_markdown(result: dict[str, Any]) -> str:
    lines = [
        f"# DDPG throughput on {result['env']} — {result['device']} × {result['devices']}",
        "",
        f"`{result['command']}` at commit {result['commit']} (jax {result['jax']}, {result['date']}). "
        f"Median of {result['repeats']} calls of {result['iterations']} iterations after a warm-up call "
        "(compile apart); PER, 300-100 nets, memory 10^6. `distributed`: half the lanes acting for the "
        "synchronous workers, half for the collecting workers. Goals: ≥ 1 M env-steps/s with ≥ 2 000 "
        "updates/s (4 × 32 transitions) on one H200.",
        "",
        "| kind | lanes | unroll | updates / iteration | transitions / update | env steps/s | updates/s "
        "| × single (steps/s) | × single (updates/s) | compile s |",
        "|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|",
    ]
    single = {(r["lanes"], r["updates_per_iteration"]): r for r in result["runs"] if r["kind"] == "single"}
    for r in result["runs"]:
        peer = single.get((r["lanes"], r["updates_per_iteration"]))
        ratio_s = f"{r['env_steps_per_s'] / peer['env_steps_per_s']:.2f}" if peer and peer is not r else "—"
        ratio_u = f"{r['updates_per_s'] / peer['updates_per_s']:.2f}" if peer and peer is not r else "—"
        goal = r["env_steps_per_s"] >= GOAL_STEPS and r["updates_per_s"] >= GOAL_UPDATES
        steps = f"{r['env_steps_per_s']:,.0f}"
        lines.append(
            f"| {r['kind']} | {r['lanes']} | {r['unroll']} | {r['updates_per_iteration']} "
            f"| {r['transitions_per_update']} | {'**' + steps + '**' if goal else steps} "
            f"| {r['updates_per_s']:,.0f} | {ratio_s} | {ratio_u} | {r['compile_s']:.1f} |"
        )
    lines += ["", "Bold: both goals met in that row.", ""]
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> dict[str, Any]:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    on_gpu = jax.default_backend() != "cpu"
    p.add_argument("--env", default="unicycle", help="an envs_mjx name (unicycle, scara, arm7, ...)")
    p.add_argument("--env-config", nargs="*", default=[], help="env settings KEY=VALUE")
    p.add_argument("--kinds", nargs="+", default=["distributed", "single"], choices=["distributed", "single"])
    p.add_argument("--lanes", type=int, nargs="+", default=[4096, 16384, 65536] if on_gpu else [64, 256])
    p.add_argument("--unroll", type=int, default=4, help="steps per lane per iteration")
    p.add_argument("--updates", type=int, nargs="+", default=[32] if on_gpu else [8],
                   help="learner updates per iteration")  # fmt: skip
    p.add_argument("--sync-workers", type=int, default=4)
    p.add_argument("--batch", type=int, default=32, help="transitions per synchronous worker and update")
    p.add_argument("--iterations", type=int, default=10 if on_gpu else 2, help="iterations per timed call")
    p.add_argument("--repeats", type=int, default=5 if on_gpu else 3)
    p.add_argument("--set", nargs="*", default=[], help="further DDPG fields FIELD=VALUE")
    provenance.add_args(p)
    p.add_argument("--out", default=RESULTS)
    args = p.parse_args(argv)
    prov = provenance.record("benchmarks.ddpg_throughput", argv, seeds=SEEDS, commit=args.commit)
    result = {
        "benchmark": "ddpg_throughput", "provenance": prov, "device": device_label(), "devices": jax.device_count(),
        "env": args.env, "command": prov["command"], "commit": prov["commit"], "jax": jax.__version__,
        "date": time.strftime("%Y-%m-%d"), "repeats": args.repeats, "iterations": args.iterations, "runs": [],
    }  # fmt: skip
    stem = f"{args.out}/{device_label()}x{jax.device_count()}-ddpg_throughput-{args.env}"
    for lanes in args.lanes:
        for updates in args.updates:
            for kind in args.kinds:
                row = bench(kind, lanes, argparse.Namespace(**{**vars(args), "updates": updates}))
                result["runs"].append(row)
                print(kind, lanes, updates, f"{row['env_steps_per_s']:,.0f} steps/s",
                      f"{row['updates_per_s']:,.0f} updates/s", flush=True)  # fmt: skip
                provenance.write(stem, result, to_markdown(result), echo=True)
    return result


if __name__ == "__main__":
    main()
