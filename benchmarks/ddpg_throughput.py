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
one at the same per-device work (the default mesh is every device: run it on 1 and 2 GPUs, the
second with ``--baseline`` naming the first's JSON).

Scaling: ``--baseline FILE`` (a run on fewer devices) adds a table pairing every distributed row
with the baseline's row of the same work per device (lanes, synchronous workers and collecting
workers per device; the same updates per iteration and mini-batch per worker).  Synchronous
workers average their gradients into one update, so more devices at the same per-device work
keep the update rate at best and multiply the transitions learned from per update; the table
gives both ratios: updates/s and learner transitions/s (updates/s × transitions per update).

``--lane-maps auto vmap shard_map`` times every case under each lane map of ``jaxrl_robot.parallel`` (``auto``:
the run's own choice), e.g. the single learner on the kinematic arm on two GPUs::

    CUDA_VISIBLE_DEVICES=0,1 python -m benchmarks.ddpg_throughput --env arm7 --env-config mode=kinematic \
        --kinds single --lanes 1024 --lane-maps vmap shard_map

Results: ``benchmarks/results/<device>-ddpg_throughput.json`` and ``.md``.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import statistics
import time
from collections.abc import Iterator
from typing import Any

import jax

import envs_mjx
from benchmarks import provenance
from benchmarks.arguments import positive
from benchmarks.timing import compile_and_time
from benchmarks.tracking_report import pairs
from benchmarks.train_throughput import RESULTS, device_label
from jaxrl_robot import parallel
from jaxrl_robot.agents.core import lane_map_of
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


@contextlib.contextmanager
def lane_map(impl: str) -> Iterator[None]:
    """Inside: the trainers built take lane map ``impl`` (``auto``: the run's own choice,
    ``parallel.lane_map_impl``), through ``$JAXRL_LANE_MAP``; the variable is restored after."""
    before = os.environ.get(parallel.IMPL_ENV)
    if impl == "auto":
        os.environ.pop(parallel.IMPL_ENV, None)
    else:
        os.environ[parallel.IMPL_ENV] = impl
    try:
        yield
    finally:
        os.environ.pop(parallel.IMPL_ENV, None)
        if before is not None:
            os.environ[parallel.IMPL_ENV] = before


def bench(kind: str, lanes: int, args: argparse.Namespace, impl: str = "auto") -> dict[str, Any]:
    """Time one case under lane map ``impl`` (``--lane-maps``); returns its settings and figures."""
    env = envs_mjx.make(args.env, **pairs(args.env_config))
    config = config_for(kind, lanes, args)
    with lane_map(impl):
        trainer = make_trainer(config, env, iterations_per_update=args.iterations)
        used = lane_map_of(env, parallel.lane_mesh())
    state = jax.block_until_ready(jax.jit(trainer.init)(jax.random.PRNGKey(0)))
    before = int(state.updates)
    compile_s, times, state = compile_and_time(trainer.update, state, args.repeats, donate=True)
    calls = args.repeats + 1  # the warm-up call learns too
    updates_per_call = (int(state.updates) - before) / calls
    med = statistics.median(times)
    return {
        "kind": kind, "lanes": config.lanes, "num_envs": config.num_envs, "unroll": args.unroll,
        "updates_per_iteration": args.updates, "transitions_per_update": args.sync_workers * args.batch,
        "sync_workers": args.sync_workers if kind == "distributed" else 1, "batch": args.batch,
        "iterations_per_call": args.iterations, "devices": jax.device_count(), "lane_map": used, "compile_s": compile_s,
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
        "| kind | lane map | lanes | unroll | updates / iteration | transitions / update | env steps/s | updates/s "
        "| × single (steps/s) | × single (updates/s) | compile s |",
        "|---|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|",
    ]
    single = {(r["lanes"], r["updates_per_iteration"], r.get("lane_map")): r for r in result["runs"]
              if r["kind"] == "single"}  # fmt: skip
    for r in result["runs"]:
        peer = single.get((r["lanes"], r["updates_per_iteration"], r.get("lane_map")))
        ratio_s = f"{r['env_steps_per_s'] / peer['env_steps_per_s']:.2f}" if peer and peer is not r else "—"
        ratio_u = f"{r['updates_per_s'] / peer['updates_per_s']:.2f}" if peer and peer is not r else "—"
        goal = r["env_steps_per_s"] >= GOAL_STEPS and r["updates_per_s"] >= GOAL_UPDATES
        steps = f"{r['env_steps_per_s']:,.0f}"
        lines.append(
            f"| {r['kind']} | {r.get('lane_map', '—')} | {r['lanes']} | {r['unroll']} | {r['updates_per_iteration']} "
            f"| {r['transitions_per_update']} | {'**' + steps + '**' if goal else steps} "
            f"| {r['updates_per_s']:,.0f} | {ratio_s} | {ratio_u} | {r['compile_s']:.1f} |"
        )
    lines += ["", "Bold: both goals met in that row.", ""]
    if result.get("baseline"):
        lines += scaling_lines(result, result["baseline"])
    return "\n".join(lines)


def per_device(row: dict[str, Any], devices: int) -> tuple:
    """The work per device of a distributed row: (lanes, synchronous workers, updates, batch)."""
    return (row["lanes"] / devices, row["sync_workers"] / devices, row["updates_per_iteration"], row["batch"])


def scaling_rows(result: dict[str, Any], baseline: dict[str, Any]) -> list[dict[str, Any]]:
    """Every distributed row of ``result`` paired with the ``baseline`` row of the same per-device work:
    ``{"lanes", "base_lanes", "updates_ratio", "transitions_ratio", ...}`` (ratios ``result / baseline``)."""
    base = {per_device(r, baseline["devices"]): r for r in baseline["runs"] if r["kind"] == "distributed"}
    out = []
    for r in result["runs"]:
        b = base.get(per_device(r, result["devices"])) if r["kind"] == "distributed" else None
        if b is None:
            continue
        moved = r["updates_per_s"] * r["transitions_per_update"], b["updates_per_s"] * b["transitions_per_update"]
        out.append({
            "lanes": r["lanes"], "base_lanes": b["lanes"], "sync_workers": r["sync_workers"],
            "base_sync_workers": b["sync_workers"], "updates_per_s": r["updates_per_s"],
            "base_updates_per_s": b["updates_per_s"], "updates_ratio": r["updates_per_s"] / b["updates_per_s"],
            "transitions_per_s": moved[0], "base_transitions_per_s": moved[1], "transitions_ratio": moved[0] / moved[1],
            "steps_ratio": r["env_steps_per_s"] / b["env_steps_per_s"],
        })  # fmt: skip
    return out


def scaling_lines(result: dict[str, Any], baseline: dict[str, Any]) -> list[str]:
    """The Markdown scaling table against ``baseline`` (see :func:`scaling_rows`)."""
    n, m = result["devices"], baseline["devices"]
    lines = [
        f"## {n} devices against {m} at the same work per device",
        "",
        f"Baseline: `{baseline['command']}` on {baseline['device']} × {m} (commit {baseline['commit']}).",
        "",
        f"| lanes ({n} / {m}) | sync workers ({n} / {m}) | updates/s ({n} / {m}) | × | learner transitions/s "
        f"({n} / {m}) | × | env steps/s × |",
        "|---|---|---|---:|---|---:|---:|",
    ]
    for r in scaling_rows(result, baseline):
        lines.append(
            f"| {r['lanes']} / {r['base_lanes']} | {r['sync_workers']} / {r['base_sync_workers']} "
            f"| {r['updates_per_s']:,.0f} / {r['base_updates_per_s']:,.0f} | {r['updates_ratio']:.2f} "
            f"| {r['transitions_per_s']:,.0f} / {r['base_transitions_per_s']:,.0f} | {r['transitions_ratio']:.2f} "
            f"| {r['steps_ratio']:.2f} |"
        )
    return lines + [""]


def load_baseline(path: str) -> dict[str, Any]:
    """A baseline run's JSON (``--baseline``); a one-line error if it is not one."""
    try:
        with open(path) as f:
            data = json.load(f)
        if data.get("benchmark") != "ddpg_throughput":
            raise ValueError("not a ddpg_throughput result")
    except (OSError, ValueError) as e:
        raise SystemExit(f"error: --baseline {path}: {e}") from None
    return {k: data[k] for k in ("command", "commit", "device", "devices", "runs")}


def main(argv: list[str] | None = None) -> dict[str, Any]:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    on_gpu = jax.default_backend() != "cpu"
    p.add_argument("--env", default="unicycle", help="an envs_mjx name (unicycle, scara, arm7, ...)")
    p.add_argument("--env-config", nargs="*", default=[], help="env settings KEY=VALUE")
    p.add_argument("--kinds", nargs="+", default=["distributed", "single"], choices=["distributed", "single"])
    p.add_argument("--lanes", type=positive, nargs="+", default=[4096, 16384, 65536] if on_gpu else [64, 256])
    p.add_argument("--unroll", type=positive, default=4, help="steps per lane per iteration")
    p.add_argument("--updates", type=positive, nargs="+", default=[32] if on_gpu else [8],
                   help="learner updates per iteration")  # fmt: skip
    p.add_argument("--sync-workers", type=positive, default=4)
    p.add_argument("--batch", type=positive, default=32, help="transitions per synchronous worker and update")
    p.add_argument("--iterations", type=positive, default=10 if on_gpu else 2, help="iterations per timed call")
    p.add_argument("--repeats", type=positive, default=5 if on_gpu else 3)
    p.add_argument("--set", nargs="*", default=[], help="further DDPG fields FIELD=VALUE")
    p.add_argument("--lane-maps", nargs="+", default=["auto"], choices=["auto", *parallel.IMPLS],
                   help="lane maps to time each case under (auto: the run's own choice, "
                   "jaxrl_robot.parallel.lane_map_impl; vmap / shard_map through JAXRL_LANE_MAP)")  # fmt: skip
    provenance.add_args(p)
    p.add_argument("--baseline", help="the JSON of a run on fewer devices: adds the scaling table")
    p.add_argument("--out", default=RESULTS)
    args = p.parse_args(argv)
    baseline = load_baseline(args.baseline) if args.baseline else None
    prov = provenance.record("benchmarks.ddpg_throughput", argv, seeds=SEEDS, allow_dirty=args.allow_dirty)
    result = {
        "benchmark": "ddpg_throughput", "provenance": prov, "device": device_label(), "devices": jax.device_count(),
        "env": args.env, "command": prov["command"], "commit": prov["commit"], "jax": jax.__version__,
        "date": time.strftime("%Y-%m-%d"), "repeats": args.repeats, "iterations": args.iterations, "runs": [],
        "baseline": baseline,
    }  # fmt: skip
    stem = f"{args.out}/{device_label()}x{jax.device_count()}-ddpg_throughput-{args.env}"
    for lanes in args.lanes:
        for updates in args.updates:
            for kind in args.kinds:
                for impl in args.lane_maps:
                    row = bench(kind, lanes, argparse.Namespace(**{**vars(args), "updates": updates}), impl)
                    result["runs"].append(row)
                    print(kind, row["lane_map"], lanes, updates, f"{row['env_steps_per_s']:,.0f} steps/s",
                          f"{row['updates_per_s']:,.0f} updates/s", flush=True)  # fmt: skip
                    provenance.write(stem, result, to_markdown(result), echo=True)
    return result


if __name__ == "__main__":
    main()
