"""The main job as a user runs it, timed from outside: ``python -m train.ppo --env arm7`` in fresh processes.

    python -m benchmarks.main_job [--seeds 1000000 1000001 1000002] [--devices 1] [-- <train.ppo flags>]

The first process compiles into an empty persistent-cache folder (a cold start); the same seed runs
again from that folder (a warm start: every program found in the cache, the same result), then the
other seeds, warm. For each process: the wall time of the whole process, its ``eval.json`` parts
(``startup_s``: from the process's start to the run's, i.e. imports, device start and building the
env and trainer; ``compile_s``: the first chunk, compilation included; ``train_s``; ``eval_s``), the
programs compiled and the cache's hits, and success within 5 / 2 / 1 cm.

The default seeds are the first three of the report range (:mod:`benchmarks.seeds`), on which no preset
or setting can have been chosen; the results file records which range each seed is in. Results go to
``benchmarks/results/<device>-main_job[-<label>].{md,json}`` with the provenance of
:mod:`benchmarks.provenance`; the device is read in a child process so that this one never holds
the GPU.
"""

from __future__ import annotations

import argparse
import glob
import json
import os
import subprocess
import sys
import tempfile
import time
from typing import Any

from benchmarks import provenance
from benchmarks import seeds as bench_seeds

RESULTS = os.path.join(os.path.dirname(os.path.abspath(__file__)), "results")
FIELDS = ("startup_s", "compile_s", "train_s", "eval_s", "wall_s")


def _child_env(cache: str, devices: int | None) -> dict[str, str]:
    env = dict(os.environ, PYTHONUNBUFFERED="1", JAXRL_ROBOT_COMPILE_CACHE=cache)
    env.pop("JAX_COMPILATION_CACHE_DIR", None)
    if devices:
        env["CUDA_VISIBLE_DEVICES"] = ",".join(str(i) for i in range(devices))
    return env


def device_info(devices: int | None) -> dict[str, Any]:
    """:func:`benchmarks.provenance.device` as a child process with the same devices sees it."""
    code = "import json; from benchmarks.provenance import device; print(json.dumps(device()))"
    out = subprocess.run([sys.executable, "-c", code], env=_child_env("off", devices), cwd=provenance.REPO,
                         capture_output=True, text=True, check=True)  # fmt: skip
    return json.loads(out.stdout.strip().splitlines()[-1])


def run_once(seed: int, cache: str, out: str, devices: int | None, flags: list[str]) -> dict[str, Any]:
    """One ``python -m train.ppo --env arm7 --seed SEED`` process: its wall time and ``eval.json``."""
    before = set(glob.glob(os.path.join(out, "ppo-arm7-*")))
    cmd = [sys.executable, "-m", "train.ppo", "--env", "arm7", "--seed", str(seed), "--out", out, *flags]
    t0 = time.perf_counter()
    proc = subprocess.run(cmd, env=_child_env(cache, devices), cwd=provenance.REPO, capture_output=True, text=True)
    wall = time.perf_counter() - t0
    if proc.returncode != 0:
        raise RuntimeError(f"{' '.join(cmd)} exited {proc.returncode}:\n{proc.stderr[-3000:]}")
    (run_dir,) = set(glob.glob(os.path.join(out, "ppo-arm7-*"))) - before
    with open(os.path.join(run_dir, "eval.json")) as f:
        result = json.load(f)
    return {"seed": seed, "process_wall_s": round(wall, 2), "run_dir": run_dir, "eval": result}


def table(rows: list[dict[str, Any]]) -> str:
    head = ("| process | seed | success 5 / 2 / 1 cm | process wall s | start-up s | first chunk (compile) s | "
            "training s | evaluation s | programs | cache hits |")  # fmt: skip
    lines = [head, "|---|---:|---|---:|---:|---:|---:|---:|---:|---:|"]
    for r in rows:
        e, c = r["eval"], r["eval"].get("compile", {})
        success = " / ".join(f"{100 * e.get(f'success_{k}', float('nan')):.0f} %" for k in ("5cm", "2cm", "1cm"))
        lines.append(
            f"| {r['kind']} | {r['seed']} | {success} | {r['process_wall_s']:.1f} | {e.get('startup_s') or 0:.1f} | "
            f"{e['compile_s']:.1f} | {e['train_s'] - e['compile_s']:.1f} | {e['eval_s']:.2f} | "
            f"{c.get('programs', '?')} | {c.get('cache_hits', '?')} |"
        )
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    ours, flags = (argv[: argv.index("--")], argv[argv.index("--") + 1 :]) if "--" in argv else (argv, [])
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--seeds", type=int, nargs="+", default=bench_seeds.seed_ids("report", 3),
                   help="seeds (first: cold and warm; default: the first three of the report range, "
                   "benchmarks.seeds)")
    p.add_argument("--devices", type=int, default=0, help="GPUs the processes see (CUDA_VISIBLE_DEVICES; 0: all)")
    p.add_argument("--label", default="", help="suffix of the results file")
    p.add_argument("--out", default=RESULTS)
    provenance.add_args(p)
    args = p.parse_args(ours)
    dev = device_info(args.devices or None)
    purposes = sorted({bench_seeds.purpose_of(k) for k in args.seeds})
    prov = provenance.record("benchmarks.main_job", argv, allow_dirty=args.allow_dirty, device_info=dev,
                             seeds=bench_seeds.record("/".join(purposes), args.seeds,
                                                      "train.ppo --seed k"))  # fmt: skip
    rows = []
    with tempfile.TemporaryDirectory(prefix="main-job-") as tmp:
        cache, out = os.path.join(tmp, "xla"), os.path.join(tmp, "runs")
        plan = [("cold", args.seeds[0]), ("warm", args.seeds[0])] + [("warm", s) for s in args.seeds[1:]]
        for kind, seed in plan:
            row = {"kind": kind, **run_once(seed, cache, out, args.devices or None, flags)}
            rows.append(row)
            e = row["eval"]
            print(f"{kind} seed {seed}: success {e.get('success_rate')} process wall {row['process_wall_s']:.1f} s "
                  f"(start-up {e.get('startup_s')}, first chunk {e['compile_s']:.1f}, train {e['train_s']:.1f}, "
                  f"eval {e['eval_s']:.2f}; {e['compile']['programs']} programs, {e['compile']['cache_hits']} "
                  "cache hits)", flush=True)  # fmt: skip
    label = f"cpu-{dev['cpu_cores'] or 0}core" if dev["platform"] == "cpu" else f"gpu-{dev['name']}"
    if dev["count"] > 1:
        label += f"-x{dev['count']}"
    name = label.replace(" ", "_").lower() + "-main_job" + (f"-{args.label}" if args.label else "")
    stem = os.path.join(args.out, name)
    text = "\n".join([
        f"# The main job, `python -m train.ppo --env arm7 {' '.join(flags)}`, in fresh processes — "
        f"{provenance.device_words(dev)}",
        "",
        "Cold: an empty compilation-cache folder; warm: the folder the processes before filled. Process wall: "
        "from the process's start to its exit; start-up: to the run's start (imports, devices, env and trainer); "
        "first chunk: its compilation included; training: the other chunks; evaluation: after training "
        "(its program compiled in the background while training runs).",
        "",
        table(rows),
        "",
    ])  # fmt: skip
    for r in rows:
        r.pop("run_dir")
    provenance.write(stem, {"provenance": prov, "rows": rows}, text, echo=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
