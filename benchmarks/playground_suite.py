"""Every MuJoCo Playground ``dm_control_suite`` env under ``python -m train.ppo``, end to end.

    python -m benchmarks.playground_suite                       # every env of the suite, tiny budget
    python -m benchmarks.playground_suite --names PointMass CheetahRun --total-steps 1024

For each env, one process runs ``python -m train.ppo --env playground:<Name>`` with Playground's own
settings (the ``playground`` preset) shrunk to a few hundred env steps (:data:`TINY`, 16-step episodes
through ``--env-config episode_length=16``): the env is loaded from the package (offline: the suite
ships its models), adapted, trained, checkpointed and evaluated, and its run directory is written. The
table says per env whether that worked (the process's exit status and ``eval.json``), its wall time
with compilation, the final evaluation's mean return, and the last line of the error where it failed.
The returns say nothing of learning at this budget; they show that the numbers are finite. Results:
``benchmarks/results/<device>-playground_suite[-<label>].{md,json}`` with the provenance of
:mod:`benchmarks.provenance`.
"""

from __future__ import annotations

import argparse
import glob
import json
import math
import os
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable
from concurrent.futures import ThreadPoolExecutor
from typing import Any

from benchmarks import provenance
from benchmarks import seeds as bench_seeds
from benchmarks.time_to_solve import device_label

RESULTS = os.path.join(os.path.dirname(os.path.abspath(__file__)), "results")
TINY = ["--num-envs", "4", "--unroll-length", "8", "--minibatch-size", "16", "--actor-updates", "2",
        "--critic-updates", "2", "--actor-hidden", "16", "--critic-hidden", "16", "--advantage-segment", "8",
        "--env-config", "episode_length=16", "--eval-episodes", "4", "--progress", "False"]  # fmt: skip


def suite_names() -> list[str]:
    """The names of Playground's ``dm_control_suite`` (``ValueError`` naming the extra without it)."""
    from envs_mjx import playground

    return list(playground.names("dm_control_suite"))


def command(name: str, steps: int, seed: int, out: str, flags: list[str]) -> list[str]:
    """The ``train.ppo`` command line of one env."""
    return [sys.executable, "-m", "train.ppo", "--env", f"playground:{name}", *TINY, "--total-steps", str(steps),
            "--seed", str(seed), "--out", out, *flags]  # fmt: skip


def run_one(cmd: list[str], out: str) -> dict[str, Any]:
    """One env's process: exit status, wall time, and its ``eval.json``'s figures (else the error's last line)."""
    env = {**os.environ, "PYTHONUNBUFFERED": "1"}
    t0 = time.perf_counter()
    proc = subprocess.run(cmd, env=env, cwd=provenance.REPO, capture_output=True, text=True)
    row: dict[str, Any] = {"rc": proc.returncode, "wall_s": round(time.perf_counter() - t0, 1)}
    runs = glob.glob(os.path.join(out, "ppo-*", "eval.json"))
    if proc.returncode == 0 and runs:
        with open(runs[0]) as f:
            row["eval"] = {k: v for k, v in json.load(f).items() if not isinstance(v, (list, dict))}
    else:
        lines = [line for line in (proc.stderr or proc.stdout).strip().splitlines() if line.strip()]
        row["error"] = lines[-1][:300] if lines else f"exit {proc.returncode}, no output"
    return row


def passed(row: dict[str, Any]) -> bool:
    """Trained and evaluated: exit 0, an ``eval.json``, a finite mean return."""
    ret = row.get("eval", {}).get("mean_return")
    return row["rc"] == 0 and isinstance(ret, (int, float)) and math.isfinite(ret)


def table(rows: list[dict[str, Any]]) -> str:
    lines = ["| env | trained and evaluated | env steps | mean return (4 episodes) | wall s | error |",
             "|---|---|---:|---:|---:|---|"]  # fmt: skip
    for r in rows:
        e = r.get("eval", {})
        ret = f"{e['mean_return']:.3f}" if "mean_return" in e else "—"
        error = r.get("error", "").replace("|", "\\|")
        lines.append(f"| {r['name']} | {'yes' if passed(r) else '**no**'} | {e.get('env_steps', '—')} "
                     f"| {ret} | {r['wall_s']:.1f} | {error} |")  # fmt: skip
    return "\n".join(lines)


def main(argv: list[str] | None = None, runner: Callable[[list[str], str], dict[str, Any]] = run_one) -> int:
    argv = sys.argv[1:] if argv is None else argv
    ours, flags = (argv[: argv.index("--")], argv[argv.index("--") + 1 :]) if "--" in argv else (argv, [])
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--names", nargs="+", default=None, help="envs of dm_control_suite (default: all)")
    p.add_argument("--total-steps", type=int, default=256, help="env steps of each run (default 256)")
    p.add_argument("--jobs", type=int, default=1, help="envs run at once, each in its own process (default 1)")
    p.add_argument("--purpose", default="report", choices=bench_seeds.PURPOSES)
    p.add_argument("--label", default="", help="suffix of the results file")
    p.add_argument("--out", default=RESULTS)
    provenance.add_args(p)
    args = p.parse_args(ours)
    if args.jobs < 1 or args.total_steps < 1:
        p.error(f"--jobs {args.jobs} / --total-steps {args.total_steps}: both at least 1")
    try:
        known = suite_names()
    except ValueError as e:
        p.error(str(e))
    names = args.names or known
    unknown = [n for n in names if n not in known]
    if unknown:
        p.error(f"--names {unknown[0]!r}: not in dm_control_suite; valid: {', '.join(known)}")
    (seed,) = bench_seeds.seed_ids(args.purpose, 1)
    dev = provenance.device()
    prov = provenance.record("benchmarks.playground_suite", argv, allow_dirty=args.allow_dirty, device_info=dev,
                             seeds=bench_seeds.record(args.purpose, [seed], "train.ppo --seed k"))  # fmt: skip

    def one(name: str) -> dict[str, Any]:
        with tempfile.TemporaryDirectory(prefix="pg-suite-") as out:
            row = {"name": name, **runner(command(name, args.total_steps, seed, out, flags), out)}
        print(f"{name}: {'ok' if passed(row) else 'FAILED ' + row.get('error', '')} ({row['wall_s']:.1f} s)",
              flush=True)  # fmt: skip
        return row

    with ThreadPoolExecutor(args.jobs) as pool:  # the processes run apart; threads only wait for them
        rows = list(pool.map(one, names))
    ok = sum(map(passed, rows))
    shown = " ".join(TINY + ["--total-steps", str(args.total_steps)] + flags)
    text = "\n".join([
        f"# MuJoCo Playground's dm_control_suite under `python -m train.ppo` — {provenance.device_words(dev)}",
        "",
        f"Each env in a process of its own: `python -m train.ppo --env playground:<Name> {shown} --seed {seed}` "
        "(the `playground` preset: Playground's own `brax_ppo_config`, shrunk to a few hundred env steps). Trained "
        "and evaluated: exit 0, `eval.json` written, a finite mean return. The returns say nothing of learning at "
        "this budget. Wall: the whole process, start-up and compilation included"
        f"{f', {args.jobs} processes at a time' if args.jobs > 1 else ''}.",
        "",
        f"**{ok} of {len(rows)} envs trained and evaluated.**",
        "",
        table(rows),
        "",
    ])  # fmt: skip
    stem = os.path.join(args.out, f"{device_label(dev)}-playground_suite" + (f"-{args.label}" if args.label else ""))
    provenance.write(stem, {"provenance": prov, "rows": rows, "passed": ok}, text, echo=True)
    return 0 if ok == len(rows) else 1


if __name__ == "__main__":
    raise SystemExit(main())
