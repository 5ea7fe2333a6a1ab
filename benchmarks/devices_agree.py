"""Every trainer on one device and on all devices: the same run up to float summation order.

    python -m benchmarks.devices_agree                      # every case, fast preset, 2 chunks
    python -m benchmarks.devices_agree --cases ppo:arm7 a2c:arm7 --chunks 3
    python -m benchmarks.devices_agree --cases ppo:brax:reacher --preset brax --extra "--advantage-segment 50 \
        --no-critic-first --minibatch-size 409600 --actor-updates 4 --critic-updates 4"   # brax's update

A case ``algo:env`` is built by the algorithm's own command line (``train.<algo>.parse`` and
``build`` with ``--preset fast`` (or ``--preset``) ``--devices D``), once on a 1-device mesh and once on all devices,
with the same seed and the same total lanes. Both runs make ``--chunks`` jitted chunk calls of one
training iteration each (so float reordering has little room to grow); the
table gives the largest absolute difference of any parameter leaf (``*params*`` fields of the
state) and of each reported metric, the devices' lane-map implementation, and the steps/s of the
last chunk (compile apart). Results: ``benchmarks/results/<device>x<gpus>-devices_agree.json``.
"""

from __future__ import annotations

import argparse
import importlib
import os
import shlex
import time
from typing import Any

import jax
import numpy as np

from benchmarks import provenance
from benchmarks.arguments import positive
from benchmarks.train_throughput import RESULTS, device_label
from jaxrl_robot import parallel
from jaxrl_robot.agents.core import lane_map_of

CASES = ["ppo:arm7", "ppo:unicycle", "ppo:scara", "a2c:arm7", "a3c:arm7", "ddpg:arm7"]


def _build(
    algo: str, env: str, devices: int, extra: list[str], preset: str = "fast"
) -> tuple[Any, Any, dict[str, Any]]:
    """``(env, trainer, config)`` of ``train.<algo>``'s command line for ``env`` on ``devices`` devices."""
    module = importlib.import_module("train.a2c" if algo in ("a2c", "a3c") else f"train.{algo}")
    # --chunks 10**9: one training iteration (rollout + updates; one cycle for DDPG) per chunk call
    argv = ["--env", env, "--preset", preset, "--devices", str(devices), "--chunks", str(10**9), *extra]
    if algo in ("a2c", "a3c"):
        args = module.parse(argv, algo)
        built, trainer, config = module.build(args, algo)
    else:
        args = module.parse(argv)
        built, trainer, config = module.build(args)
    return built, trainer, config


def _params(state: Any) -> dict[str, np.ndarray]:
    """Leaves of every ``*params*`` field of the state, by path."""
    out = {}
    for path, leaf in jax.tree_util.tree_leaves_with_path(jax.device_get(state)):
        name = jax.tree_util.keystr(path)
        if "params" in name and np.issubdtype(np.asarray(leaf).dtype, np.floating):
            out[name] = np.asarray(leaf)
    return out


def run_case(case: str, chunks: int, extra: list[str], preset: str = "fast") -> dict[str, Any]:
    algo, env = case.split(":", 1)  # the env may hold a colon: ppo:brax:halfcheetah
    n_all = len(jax.devices())
    res: dict[str, Any] = {"case": case, "devices": [1, n_all]}
    outs = {}
    for d in (1, n_all):
        built, trainer, config = _build(algo, env, d, extra, preset)
        init, update = jax.jit(trainer.init), jax.jit(trainer.update)
        state = init(jax.random.PRNGKey(0))
        t0 = time.perf_counter()
        for _ in range(chunks):
            t = time.perf_counter()
            state, metrics = jax.block_until_ready(update(state))
            last = time.perf_counter() - t
        res[f"wall_s_{d}"] = time.perf_counter() - t0
        res[f"steps_per_s_{d}"] = trainer.env_steps_per_update / last
        res[f"lane_map_{d}"] = lane_map_of(built, parallel.lane_mesh(d))
        outs[d] = (_params(state), {k: float(v) for k, v in jax.device_get(metrics).items()})
    (p1, m1), (pn, mn) = outs[1], outs[n_all]
    res["max_param_diff"] = max(float(np.max(np.abs(p1[k] - pn[k]))) for k in p1)
    res["max_param_abs"] = max(float(np.max(np.abs(p1[k]))) for k in p1)
    res["metric_diff"] = {k: mn[k] - m1[k] for k in m1 if np.isfinite(m1[k]) and np.isfinite(mn.get(k, np.nan))}
    res["metrics_1"], res["metrics_n"] = m1, mn
    return res


def main(argv: list[str] | None = None) -> dict[str, Any]:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--cases", nargs="+", default=CASES)
    p.add_argument("--chunks", type=positive, default=2)
    p.add_argument("--extra", default="", help="further flags for every case's command line, in one quoted string")
    p.add_argument("--preset", default="fast", help="every case's --preset (brax: a brax task's)")
    p.add_argument("--out", default=RESULTS)
    provenance.add_args(p)
    args = p.parse_args(argv)
    prov = provenance.record("benchmarks.devices_agree", argv, seeds="PRNGKey(0) for every case (fixed in the code)",
                             allow_dirty=args.allow_dirty)  # fmt: skip
    rows = []
    for case in args.cases:
        try:
            r = run_case(case, args.chunks, shlex.split(args.extra), args.preset)
        except Exception as e:  # one failing case is recorded, the others still run
            r = {"case": case, "error": repr(e)[:600]}
        rows.append(r)
        if "error" in r:
            print(f"{case:14s} ERROR {r['error']}", flush=True)
        else:
            md = max((abs(v) for v in r["metric_diff"].values()), default=0.0)
            n = r["devices"][1]
            print(f"{case:14s} max|Δparam| {r['max_param_diff']:.2e} (max|param| {r['max_param_abs']:.2g})  "
                  f"max|Δmetric| {md:.2e}  steps/s 1: {r['steps_per_s_1']:,.0f}  "
                  f"{n}: {r['steps_per_s_' + str(n)]:,.0f}  ({r['lane_map_' + str(n)]})", flush=True)  # fmt: skip
    result = {"benchmark": "devices_agree", "provenance": prov, "device": device_label(), "gpus": len(jax.devices()),
              "jax": jax.__version__, "date": time.strftime("%Y-%m-%d %H:%M"), "chunks": args.chunks, "runs": rows}
    provenance.write(os.path.join(args.out, f"{result['device']}x{result['gpus']}-devices_agree"), result, None)
    return result


if __name__ == "__main__":
    main()
