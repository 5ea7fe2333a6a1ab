"""Table 4.1 with our code: A3C / A2C x ordinary / path reward on ``arm7``, through the command line.

    python -m benchmarks.a2c_arm7 --preset cpu --seeds 0
    python -m benchmarks.a2c_arm7 --preset thesis --rows a3c:path a2c:path --seeds 0 1 2

Each row is one ``python -m train.<algo> --env arm7 --reward <reward> --preset <preset>`` run
(``train.a2c.main`` in this process, run directories under ``--runs``), followed by the run's own
evaluation: success over 100 test episodes from fresh random starts and goals, and the mean extra
distance (path length minus straight-line distance, over the successful episodes). Recorded per
row: those two, wall time (compile, training, evaluation), env steps actually taken (lanes idle
after an early episode end within a round) and their rate after the first (compiling) chunk, the mean
gradient staleness, and the preset's hyper-parameters.

Results: ``benchmarks/results/<device>-a2c_arm7.json`` and ``.md``; rows are merged by
(algo, reward, preset, seed, extra flags), so runs can be added one at a time.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import platform
import statistics
from typing import Any

import jax

from benchmarks import provenance
from benchmarks import seeds as bench_seeds
from benchmarks.arguments import nonnegative
from jaxrl_robot.logging import read_csv
from train import a2c as a2c_cli

RESULTS = os.path.join(os.path.dirname(os.path.abspath(__file__)), "results")
THESIS = {("a3c", "ordinary"): 76, ("a3c", "path"): 84, ("a2c", "ordinary"): 79, ("a2c", "path"): 88}


def device_label() -> str:
    d = jax.devices()[0]
    kind = d.device_kind if d.platform != "cpu" else f"cpu-{os.cpu_count()}core"
    return f"{d.platform}-{kind}".replace(" ", "_").lower()


def record(run_dir: str, algo: str, reward: str, preset: str, seed: int, extra: list[str]) -> dict[str, Any]:
    """The row's record from its run directory (``eval.json``, ``config.json``, ``metrics.csv``).

    ``env_steps_per_s`` leaves out the first chunk, whose time includes compilation.
    """
    ev = json.load(open(os.path.join(run_dir, "eval.json")))
    cfg = json.load(open(os.path.join(run_dir, "config.json")))
    rows = read_csv(os.path.join(run_dir, "metrics.csv"))
    taken = [float(r["steps_taken"]) for r in rows]
    pushes = [(float(r["applied_gradients"]), float(r["staleness_mean"])) for r in rows]
    n_push = sum(n for n, _ in pushes)
    steady_s = ev["train_s"] - ev["compile_s"]
    return {
        "algo": algo,
        "reward": reward,
        "preset": preset,
        "seed": seed,
        "extra": extra,
        "success_rate": ev["success_rate"],
        "test_episodes": ev["episodes"],
        "mean_extra_distance": ev["mean_extra_distance"],
        "mean_length": ev["mean_length"],
        "env_step_slots": ev["env_steps"],
        "env_steps_taken": sum(taken),
        "train_s": ev["train_s"],
        "compile_s": ev["compile_s"],
        "eval_s": ev["eval_s"],
        "wall_s": ev["wall_s"],
        "env_steps_per_s": (sum(taken) - taken[0]) / steady_s if len(rows) > 1 and steady_s > 0 else float("nan"),
        "staleness_mean": sum(n * s for n, s in pushes) / max(n_push, 1.0),
        "episodes": sum(float(r["episodes"]) for r in rows),
        "config": cfg[algo],
        "env_config": cfg["args"]["env_config"],
        "run_dir": run_dir,
        "thesis_success": THESIS[(algo, reward)],
    }


def run_row(algo: str, reward: str, preset: str, seed: int, runs: str, extra: list[str]) -> dict[str, Any]:
    """Train and evaluate one row through the CLI; return its record."""
    before = set(os.listdir(runs)) if os.path.isdir(runs) else set()
    argv = ["--env", "arm7", "--reward", reward, "--preset", preset, "--seed", str(seed), "--out", runs, *extra]
    code = a2c_cli.main(argv, algo=algo)
    (run_dir,) = [os.path.join(runs, d) for d in set(os.listdir(runs)) - before]
    if code != 0:
        return {"algo": algo, "reward": reward, "preset": preset, "seed": seed, "extra": extra, "error": code,
                "run_dir": run_dir}  # fmt: skip
    return record(run_dir, algo, reward, preset, seed, extra)


def _key(r: dict[str, Any]) -> tuple:
    return (r["algo"], r["reward"], r["preset"], r["seed"], tuple(r.get("extra", ())))


def to_markdown(result: dict[str, Any]) -> str:
    lines = [
        f"# A3C / A2C on arm7 (Table 4.1) — {result['device']}",
        "",
        f"{result['note']}",
        "",
        "| algo | reward | preset | seed | flags | success /100 (thesis) | mean extra distance (m) | env steps taken "
        "| env-steps/s | train s | compile s | mean staleness |",
        "|---|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    rows = [r for r in result["rows"] if "error" not in r]
    groups: dict[tuple, list[dict[str, Any]]] = {}
    for r in rows:
        groups.setdefault((r["algo"], r["reward"], r["preset"], " ".join(r["extra"])), []).append(r)
    summary = [
        "",
        "Per setting, over seeds: success (mean, min–max of the seeds, median), mean extra distance of the seeds' "
        "means.",
        "",
        "| algo | reward | preset | flags | seeds | success % (thesis) | median % | extra distance (m) |",
        "|---|---|---|---|---|---|---|---|",
    ]
    for (algo, reward, preset, flags), rs in sorted(groups.items()):
        succ = [100 * r["success_rate"] for r in rs]
        median = statistics.median(succ)
        extra = [r["mean_extra_distance"] for r in rs if r["mean_extra_distance"] is not None]
        extra = [x for x in extra if not math.isnan(x)]
        extra_s = f"{sum(extra) / len(extra):.3f}" if extra else "n/a"
        summary.append(
            f"| {algo} | {reward} | {preset} | {flags} | {len(rs)} | {sum(succ) / len(succ):.1f} "
            f"({min(succ):.0f}–{max(succ):.0f}) ({THESIS[(algo, reward)]}) | {median:.1f} | {extra_s} |"
        )
    lines += summary + ["", "All runs:", ""] + lines[4:6]
    del lines[4:6]
    for r in sorted(result["rows"], key=_key):
        if "error" in r:
            lines.append(f"| {r['algo']} | {r['reward']} | {r['preset']} | {r['seed']} | {' '.join(r['extra'])} "
                         f"| failed (exit {r['error']}) | | | | | | |")  # fmt: skip
            continue
        extra = r["mean_extra_distance"]
        extra_s = "n/a" if extra is None or (isinstance(extra, float) and math.isnan(extra)) else f"{extra:.3f}"
        lines.append(
            f"| {r['algo']} | {r['reward']} | {r['preset']} | {r['seed']} | {' '.join(r['extra'])} "
            f"| {round(100 * r['success_rate'])} ({r['thesis_success']}) | {extra_s} | {r['env_steps_taken']:,.0f} "
            f"| {r['env_steps_per_s']:,.0f} | {r['train_s']:.0f} | {r['compile_s']:.0f} | {r['staleness_mean']:.2f} |"
        )
    findings = result.get("findings", [])
    if findings:
        lines += ["", "## Findings", ""] + [f"- {f}" for f in findings]
    return "\n".join(lines) + "\n"


def _write(stem: str, result: dict[str, Any]) -> None:
    """The results, with this invocation's provenance and that of the earlier ones whose rows remain."""
    mine = result["provenance"]["started"]
    earlier = {r["provenance"]["started"]: r["provenance"] for r in result["rows"] if "provenance" in r}
    earlier.pop(mine, None)
    kept = os.path.join("runs", os.path.basename(stem))
    result["provenance"]["run_directories"] = (
        f"`eval.json` and `config.json` of each row's run kept under `{kept}/` beside this file"
        if any(r.get("kept") for r in result["rows"]) else "not kept"
    )  # fmt: skip
    provenance.write(stem, result, to_markdown(result), earlier=list(earlier.values()))


def main(argv: list[str] | None = None) -> dict[str, Any]:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--preset", default="cpu", help="thesis, cpu or fast")
    p.add_argument("--rows", nargs="+", default=["a3c:ordinary", "a3c:path", "a2c:ordinary", "a2c:path"])
    p.add_argument("--seeds", nargs="+", type=nonnegative, default=[0])
    p.add_argument("--runs", default="runs/bench-a2c", help="parent folder of the run directories")
    p.add_argument("--out", default=RESULTS)
    p.add_argument("--note", default="", help="free text recorded with the results (e.g. machine load)")
    p.add_argument("--extra", nargs=argparse.REMAINDER, default=[], help="further train.a2c flags for every row")
    p.add_argument("--rebuild", action="store_true", help="only re-derive the saved rows from their run directories")
    provenance.add_args(p)
    args = p.parse_args(argv)
    purposes = "/".join(sorted({bench_seeds.purpose_of(k) for k in args.seeds}))
    prov = provenance.record("benchmarks.a2c_arm7", argv, allow_dirty=args.allow_dirty,
                             seeds=bench_seeds.record(purposes, args.seeds, "train.a2c/a3c --seed k"),
                             **({"note": args.note} if args.note else {}))  # fmt: skip
    os.makedirs(args.runs, exist_ok=True)
    os.makedirs(args.out, exist_ok=True)
    stem = os.path.join(args.out, f"{device_label()}-a2c_arm7")
    result = {"device": device_label(), "host": platform.node(), "jax": jax.__version__, "rows": [],
              "note": "Each row: one CLI run; success over 100 test episodes of the final policy."}  # fmt: skip
    if os.path.exists(stem + ".json"):
        result = json.load(open(stem + ".json"))
    result["provenance"] = prov
    if args.rebuild:
        keep = ("algo", "reward", "preset", "seed", "extra")
        result["rows"] = [
            {**r, **record(r["run_dir"], *(r[k] for k in keep))} if "error" not in r else r for r in result["rows"]
        ]
        _write(stem, result)
        return result
    for seed in args.seeds:
        for row in args.rows:
            algo, reward = row.split(":")
            rec = run_row(algo, reward, args.preset, seed, args.runs, list(args.extra))
            if args.note:
                rec["note"] = args.note
            rec["provenance"] = dict(provenance.stamp(prov))
            rec["kept"] = provenance.keep_run(rec["run_dir"], stem)
            result["rows"] = [r for r in result["rows"] if _key(r) != _key(rec)] + [rec]
            _write(stem, result)
            print(to_markdown({**result, "rows": [rec]}), flush=True)
    return result


if __name__ == "__main__":
    main()
