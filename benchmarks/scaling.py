"""PPO training throughput over lanes and GPUs: weak and strong scaling, brax's PPO beside it.

    python -m benchmarks.scaling                          # arm7 pd and unicycle, sizes for the machine
    python -m benchmarks.scaling --envs arm7 --one 8192 32768 --weak 16384 32768 --strong 65536
    python -m benchmarks.scaling --envs arm7 --one --weak 4096 32768 --strong 131072 --brax --device-counts 2 4 \
        --env-config jacobian=sparse --lane-maps vmap shard_map

One process drives every configuration: a 1-device mesh (``parallel.lane_mesh(1)``) for the
one-GPU rows, a 2-device mesh for the two-GPU rows (lanes split over the mesh by
``jaxrl_robot.parallel``). Per configuration our PPO (``benchmarks.train_throughput.bench_ours``:
N = 16, 4 actor + 4 critic mini-batch updates, 2 x 200 networks) is compiled apart and timed as the
median of ``--repeats`` chunk calls of ``--chunk-iters`` iterations (``block_until_ready``).

* ``--one``: lane counts on one GPU (is throughput non-decreasing in the lanes?);
* ``--weak``: lanes per GPU; each runs on 1 GPU with L lanes and on D GPUs with L x D lanes, for each D of
  ``--device-counts`` (default: every GPU);
  efficiency = steps/s(D GPUs) / (D x steps/s(1 GPU));
* ``--strong``: total lanes, on 1 GPU and on each of ``--device-counts``;
* ``--lane-group``: our PPO also with the env stepped in groups of this many lanes per device
  (``PPOConfig.lane_group``) wherever the lanes per device exceed it (0: never);
* ``--lane-maps``: the lane maps of ``jaxrl_robot.parallel`` the several-device cases run under (``auto``: the
  run's own, ``vmap``, ``shard_map``; each one-device case runs once under its own, the baseline);
* ``--env-config KEY=VALUE``: env settings over the benchmark's (e.g. ``jacobian=sparse``);
* ``--brax``: lane counts of brax's PPO on one GPU (``benchmarks/peers/brax_ppo.py``; it uses every
  visible device, so it runs on a 1-GPU process: ``CUDA_VISIBLE_DEVICES`` = the first GPU).

Results: ``benchmarks/results/<device>x<gpus>-scaling.json`` and ``.md``.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import subprocess
import sys
import time
from typing import Any

import jax

import envs_mjx
from benchmarks import provenance
from benchmarks.arguments import nonnegative, positive
from benchmarks.ddpg_throughput import lane_map
from benchmarks.tracking_report import pairs
from benchmarks.train_throughput import (
    RESULTS,
    SEEDS,
    bench_brax,
    bench_ours,
    device_label,
    markdown_head,
)
from jaxrl_robot import parallel
from jaxrl_robot.agents.core import lane_map_of

ENV_CONFIGS = {"arm7": {"mode": "pd"}, "unicycle": {"mode": "dynamic"}, "scara": {}}


def _row(env_name: str, kind: str, devices: int, r: dict[str, Any]) -> dict[str, Any]:
    return {"env": env_name, "kind": kind, "devices": devices, **r}


def device_counts(requested: list[int], available: int) -> list[int]:
    """The device counts of the several-device rows: ``requested`` (``--device-counts``; default every device),
    each at most ``available`` (a larger one is a one-line error), 1 left out (the one-device rows are always run)."""
    counts = requested or [available]
    too_many = [d for d in counts if d > available]
    if too_many:
        raise SystemExit(f"error: --device-counts {too_many[0]}: only {available} device(s) visible")
    return sorted({d for d in counts if d > 1})


def plan_cases(args: argparse.Namespace, counts: list[int]) -> list[tuple]:
    """``(kind, devices, lanes[, lane group])`` cases in order: ``--one`` on one device, ``--weak`` lanes per
    device on 1 and each of ``counts`` devices, ``--strong`` lanes in all on 1 and each of ``counts``, then the
    lane-group variants of the cases with more lanes per device than ``--lane-group``."""
    plan: list[tuple] = [("one", 1, k) for k in args.one]
    for per in args.weak:
        plan += [("weak", 1, per)] + [("weak", d, per * d) for d in counts]
    for total in args.strong:
        plan += [("strong", 1, total)] + [("strong", d, total) for d in counts]
    if args.lane_group:
        plan += [(f"{kind}, lane group {args.lane_group}", devs, lanes, args.lane_group) for kind, devs, lanes in plan
                 if lanes // devs > args.lane_group]  # fmt: skip
    return plan


def run_ours(env_name: str, args: argparse.Namespace, on_row: Any = None) -> list[dict[str, Any]]:
    """Our PPO over :func:`plan_cases` (each case measured once however many kinds name it); ``on_row(rows)``
    after each row (the partial results are written as they come)."""
    env = envs_mjx.make(env_name, **env_config(env_name, args))
    plan = plan_cases(args, device_counts(args.device_counts, len(jax.devices())))
    done: dict[tuple[int, int, int, str], dict[str, Any]] = {}
    rows = []
    for kind, devs, lanes, *group in plan:
        group = group[0] if group else 0
        for impl in ("auto",) if devs == 1 else args.lane_maps:  # one device: its own lane map, the baseline
            if (devs, lanes, group, impl) not in done:
                mesh = parallel.lane_mesh(devs)
                try:
                    with lane_map(impl):
                        r = bench_ours(env, lanes, args.unroll, args.chunk_iters, args.repeats, args.updates,
                                       args.reset_refresh, mesh=mesh, lane_group=group)  # fmt: skip
                        r["lane_map"] = lane_map_of(env, mesh)
                except Exception as e:  # e.g. out of memory: recorded, the sweep goes on
                    r = {"impl": "jaxrl_robot", "lanes": lanes, "steps_per_s": float("nan"), "error": repr(e)[:400]}
                done[(devs, lanes, group, impl)] = r
                print(f"{env_name:9s} ours {devs} GPU(s) lanes={lanes:7d} group={group:6d} "
                      f"{r.get('lane_map', impl):9s} {r['steps_per_s']:14,.0f} steps/s compile "
                      f"{r.get('compile_s', float('nan')):.1f}s", flush=True)  # fmt: skip
            rows.append(_row(env_name, kind, devs, done[(devs, lanes, group, impl)]))
            if on_row is not None:
                on_row(rows)
    return rows


def env_config(env_name: str, args: argparse.Namespace) -> dict[str, Any]:
    """The env's settings: :data:`ENV_CONFIGS`' with ``--env-config`` over them."""
    return {**ENV_CONFIGS[env_name], **pairs(args.env_config)}


def run_brax(env_name: str, args: argparse.Namespace) -> list[dict[str, Any]]:
    env = envs_mjx.make(env_name, **env_config(env_name, args))
    rows = []
    for lanes in args.brax:
        try:
            r = bench_brax(env, lanes, args.unroll, args.chunk_iters, args.repeats, args.updates)
        except Exception as e:  # a peer failure is recorded, not fatal
            r = {"impl": "brax.ppo", "lanes": lanes, "steps_per_s": float("nan"), "error": repr(e)[:400]}
        print(f"{env_name:9s} brax 1 GPU(s) lanes={lanes:7d} {r['steps_per_s']:14,.0f} steps/s", flush=True)
        rows.append(_row(env_name, "brax", 1, r))
    return rows


def _brax_in_subprocess(args: argparse.Namespace, tmp: str) -> list[dict[str, Any]]:
    """brax's PPO in a process that sees only the first GPU (it pmaps over every visible device)."""
    env = dict(os.environ, CUDA_VISIBLE_DEVICES=os.environ.get("CUDA_VISIBLE_DEVICES", "0").split(",")[0])
    cmd = [sys.executable, "-m", "benchmarks.scaling", "--brax-only", tmp, "--envs", *args.envs,
           "--brax", *map(str, args.brax), "--unroll", str(args.unroll), "--updates", str(args.updates),
           "--chunk-iters", str(args.chunk_iters), "--repeats", str(args.repeats)]  # fmt: skip
    proc = subprocess.run(cmd, env=env, text=True)
    if proc.returncode != 0 or not os.path.exists(tmp):
        return [{"kind": "brax", "impl": "brax.ppo", "steps_per_s": float("nan"), "error": f"rc={proc.returncode}"}]
    with open(tmp) as f:
        return json.load(f)


def to_markdown(result: dict[str, Any]) -> str:
    lines = [
        *markdown_head(
            f"PPO scaling — {result['device']} x {result['gpus']}", result, f"reset refresh {result['reset_refresh']}"
        ),
        "| env | kind | impl | GPUs | lanes | lanes/GPU | env-steps/s | vs 1 GPU same lanes/GPU | compile s |",
        "|---|---|---|---:|---:|---:|---:|---:|---:|",
    ]
    one = {(r["env"], r["lanes"], r.get("lane_group", 0)): r["steps_per_s"] for r in result["runs"]
           if r["devices"] == 1 and r.get("impl") == "jaxrl_robot"}  # fmt: skip
    several_maps = len({r.get("lane_map") for r in result["runs"] if r["devices"] > 1}) > 1
    for r in result["runs"]:
        d, lanes = r["devices"], r.get("lanes", 0)
        per = lanes // d if d else lanes
        base = one.get((r["env"], per, r.get("lane_group", 0)))
        eff = f"{r['steps_per_s'] / (d * base):.2f} (x{r['steps_per_s'] / base:.2f})" if base and d > 1 else ""
        comp = r.get("compile_s", r.get("first_epoch_s", float("nan")))
        impl = f"{r.get('impl')} ({r['lane_map']})" if several_maps and r.get("lane_map") else r.get("impl")
        lines.append(f"| {r['env']} | {r['kind']} | {impl} | {d} | {lanes} | {per} | "
                     f"{r['steps_per_s']:,.0f} | {eff} | {comp:.1f} |")  # fmt: skip
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> dict[str, Any]:
    on_cpu = jax.default_backend() == "cpu"
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--envs", nargs="+", default=["arm7", "unicycle"], choices=sorted(ENV_CONFIGS))
    p.add_argument("--one", type=positive, nargs="*",
                   default=[64, 128] if on_cpu else [8192, 16384, 32768, 65536, 131072])  # fmt: skip
    p.add_argument("--weak", type=positive, nargs="*", default=[64] if on_cpu else [16384, 32768, 65536])
    p.add_argument("--strong", type=positive, nargs="*", default=[128] if on_cpu else [65536])
    p.add_argument("--brax", type=positive, nargs="*", default=[] if on_cpu else [16384, 32768, 65536])
    p.add_argument("--unroll", type=positive, default=16)
    p.add_argument("--updates", type=positive, default=4)
    p.add_argument("--chunk-iters", type=positive, default=4)
    p.add_argument("--repeats", type=positive, default=3)
    p.add_argument("--reset-refresh", type=float, default=0.125)
    p.add_argument("--lane-group", type=nonnegative, default=0)
    p.add_argument("--device-counts", type=positive, nargs="*", default=[],
                   help="device counts of the several-device rows (default: every device), e.g. 2 4")  # fmt: skip
    p.add_argument("--lane-maps", nargs="+", default=["auto"], choices=["auto", *parallel.IMPLS],
                   help="lane maps of the several-device rows (auto: the run's own choice; one-device rows: auto)")
    p.add_argument("--env-config", nargs="*", default=[], help="env settings KEY=VALUE over the benchmark's own")
    p.add_argument("--out", default=RESULTS)
    p.add_argument("--brax-only", default="", help=argparse.SUPPRESS)
    provenance.add_args(p)
    args = p.parse_args(argv)
    prov = provenance.record("benchmarks.scaling", argv, seeds=SEEDS, allow_dirty=args.allow_dirty)
    if args.brax_only:
        rows = [r for e in args.envs for r in run_brax(e, args)]
        with open(args.brax_only, "w") as f:
            json.dump(rows, f)
        return {"runs": rows}
    os.makedirs(args.out, exist_ok=True)
    device_counts(args.device_counts, len(jax.devices()))  # a count beyond the devices stops before any run
    runs: list[dict[str, Any]] = []
    stem = os.path.join(args.out, f"{device_label()}x{len(jax.devices())}-scaling")

    def write(rows: list[dict[str, Any]]) -> dict[str, Any]:
        result = _result(args, prov, rows)
        provenance.write(stem, result, to_markdown(result))
        return result

    for e in args.envs:  # the file is rewritten after every row: a sweep stopped half-way keeps what it measured
        before = list(runs)
        runs = before + run_ours(e, args, on_row=lambda rows, before=before: write(before + rows))
    if args.brax:
        runs += _brax_in_subprocess(args, os.path.join(args.out, ".brax_rows.json"))
        if os.path.exists(os.path.join(args.out, ".brax_rows.json")):
            os.remove(os.path.join(args.out, ".brax_rows.json"))
    result = write(runs)
    print(to_markdown(result))
    return result


def _result(args: argparse.Namespace, prov: dict[str, Any], runs: list[dict[str, Any]]) -> dict[str, Any]:
    """The results record of ``runs`` (this invocation's settings and provenance)."""
    return {
        "benchmark": "scaling",
        "provenance": prov,
        "device": device_label(),
        "gpus": len(jax.devices()),
        "jax": jax.__version__,
        "host": platform.node(),
        "date": time.strftime("%Y-%m-%d %H:%M"),
        "unroll": args.unroll,
        "updates": args.updates,
        "chunk_iters": args.chunk_iters,
        "repeats": args.repeats,
        "reset_refresh": args.reset_refresh,
        "device_counts": device_counts(args.device_counts, len(jax.devices())),
        "env_configs": {e: env_config(e, args) for e in args.envs},
        "runs": runs,
    }


if __name__ == "__main__":
    main()
