"""The time-to-solve report: per (task, device count) the spread over seeds, the markdown table and the figure
of :mod:`benchmarks.time_to_solve`'s records."""

from __future__ import annotations

import math
import os
from collections.abc import Sequence
from typing import Any

from benchmarks import provenance
from benchmarks import seeds as bench_seeds

FIELDS = ("process_wall_s", "startup_s", "first_chunk_s", "train_to_target_s", "total_to_target_s",
          "env_steps_to_target")  # fmt: skip
"""The per-process figures summarised per (task, device count)."""


def spread(values: Sequence[float]) -> dict[str, Any]:
    """``{"n", "mean", "std", "values"}`` of ``values`` (None entries left out; ``std`` with n − 1, 0 for one
    value; mean and std None for none)."""
    vals = [float(v) for v in values if v is not None]
    n = len(vals)
    mean = sum(vals) / n if n else None
    std = math.sqrt(sum((v - mean) ** 2 for v in vals) / (n - 1)) if n > 1 else (0.0 if n else None)
    return {"n": n, "mean": mean, "std": std, "values": vals}


def summarise(records: Sequence[dict[str, Any]], devices: Sequence[int]) -> list[dict[str, Any]]:
    """Per device count: the seeds run and met, and :func:`spread` of each of :data:`FIELDS` (the ``to target``
    ones over the seeds that met the target), and of the final criterion."""
    out = []
    for n in devices:
        mine = [r for r in records if r["devices"] == n and "error" not in r]
        failed = sum(1 for r in records if r["devices"] == n and "error" in r)
        row: dict[str, Any] = {"devices": n, "seeds": len(mine), "failed": failed,
                               "reached": sum(1 for r in mine if r["reached"])}  # fmt: skip
        for field in FIELDS:
            row[field] = spread([r.get(field) for r in mine])
        row["final"] = spread([r.get("final") for r in mine])
        out.append(row)
    return out


def cell(s: dict[str, Any], digits: int = 1) -> str:
    """``mean ± std`` of a :func:`spread` (``—`` for none)."""
    if not s["n"]:
        return "—"
    return f"{s['mean']:.{digits}f} ± {s['std']:.{digits}f}" if s["n"] > 1 else f"{s['mean']:.{digits}f}"


def steps_words(steps: float) -> str:
    """``1.23 M`` from a million env steps on, else the count (``12,800``)."""
    return f"{steps / 1e6:.2f} M" if steps >= 1e6 else f"{steps:,.0f}"


def to_markdown(result: dict[str, Any]) -> str:
    """The results file's text: per task its command, target and table, per-process rows, figure."""
    dev = result["device"]
    where = ("fake CPU devices (XLA_FLAGS) on " if dev.get("fake_devices") else "") + provenance.device_words(
        {**dev, "count": 1})
    side = "; processes of a device count side by side on disjoint GPUs" if result["concurrent"] else ""
    stop = "; each stopped (SIGTERM) once an evaluation met the target" if result["stop_at_target"] else ""
    lines = [f"# Time to solve — {where}", "",
             "Each process is the task's command line as a user runs it (`--evals "
             f"{result['evals']}` evaluations of {result['eval_episodes']} episodes during training), a fresh process "
             f"per device count and seed ({bench_seeds.words(result['seeds'])}); compilation cache: "
             f"{result['compile_cache']}{side}{stop}. "
             "Process wall: start to exit; start-up: to the run's start; first chunk: its compilation included; to "
             "target: the first evaluation that met the target, on the training clock (evaluations apart) and from "
             "the process's start (evaluations before it apart). Mean ± std over the seeds that met it (met / run).",
             ""]  # fmt: skip
    for t in result["tasks"]:
        lines += [f"## {t['task']}: {t['words']}", "", f"`{t['command']}`", "",
                  "| devices | met / run | process wall s | start-up s | first chunk (compile) s | to target, training "
                  "clock s | to target, total s | env steps to target | final |",
                  "|---:|---|---:|---:|---:|---:|---:|---:|---:|"]  # fmt: skip
        for s in t["summary"]:
            steps = s["env_steps_to_target"]
            steps_cell = steps_words(steps["mean"]) if steps["n"] else "—"
            failed = f" ({s['failed']} failed)" if s["failed"] else ""
            lines.append(f"| {s['devices']} | {s['reached']} / {s['seeds']}{failed} | {cell(s['process_wall_s'])} | "
                         f"{cell(s['startup_s'])} | {cell(s['first_chunk_s'])} | {cell(s['train_to_target_s'])} | "
                         f"{cell(s['total_to_target_s'])} | {steps_cell} | {cell(s['final'], 3)} |")  # fmt: skip
        lines += ["", "| devices | seed | process wall s | start-up s | first chunk s | to target, training clock s | "
                  "to target, total s | final | env steps run | stopped at target | cache hits / programs |",
                  "|---:|---:|---:|---:|---:|---:|---:|---:|---:|---|---|"]  # fmt: skip
        for r in t["runs"]:
            if "error" in r:
                lines.append(f"| {r['devices']} | {r['seed']} | {r['process_wall_s']:.1f} | failed (exit "
                             f"{r['exit_code']}) | | | | | | | |")  # fmt: skip
                continue
            num = lambda v, d=1: "—" if v is None else f"{v:.{d}f}"  # noqa: E731
            hits = f"{r.get('cache_hits')} / {r.get('programs')}" if r.get("programs") is not None else "—"
            stopped = "yes" if r["stopped_at_target"] else "no"
            lines.append(f"| {r['devices']} | {r['seed']} | {r['process_wall_s']:.1f} | {num(r['startup_s'])} | "
                         f"{num(r['first_chunk_s'])} | {num(r['train_to_target_s'])} | {num(r['total_to_target_s'])} "
                         f"| {r['final']:.3f} | {steps_words(r['final_env_steps'])} | {stopped} | {hits} |")
        if t.get("figure"):
            lines += ["", f"![{t['task']}]({os.path.relpath(t['figure'], os.path.dirname(result['stem']))})"]
        lines.append("")
    return "\n".join(lines)


def figure(task: dict[str, Any], out_dir: str) -> str | None:
    """The criterion against the training clock, one colour per device count (a line per seed), the target
    dashed: ``<out_dir>/<task>.png`` (None: no evaluation yet)."""
    runs = [r for r in task["runs"] if r.get("curve")]
    if not runs:
        return None
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from benchmarks.time_to_solve import TASKS  # the task definitions' module imports this one

    tracking = TASKS[task["task"]].column == "tracking"
    fig, ax = plt.subplots(figsize=(6, 4))
    colours = {n: f"C{i}" for i, n in enumerate(sorted({r["devices"] for r in runs}))}
    labelled = set()
    for r in runs:
        n = r["devices"]
        label = None if n in labelled else f"{n} device{'s' if n > 1 else ''}"
        labelled.add(n)
        xs, ys = [c["train_wall_s"] for c in r["curve"]], [c["value"] for c in r["curve"]]
        ax.plot(xs, ys, marker=".", color=colours[n], alpha=0.8, label=label)
    ax.axhline(1.0 if tracking else task["target"], color="k", linestyle="--", linewidth=1, label="target")
    if tracking:
        ax.set_yscale("log")
    ax.set_xlabel("training clock, s (compilation in, evaluations out)")
    ax.set_ylabel("worst axis error / goal" if tracking else TASKS[task["task"]].column)
    ax.set_title(f"{task['task']}: {task['words']}", fontsize=9)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=8)
    os.makedirs(out_dir, exist_ok=True)
    path = os.path.join(out_dir, f"{task['task']}.png")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def write(result: dict[str, Any]) -> str:
    """Figures, ``stem.json`` and ``stem.md`` of ``result`` as it stands."""
    for t in result["tasks"]:
        t["summary"] = summarise(t["runs"], result["device_counts"])
        t["figure"] = figure(t, result["stem"] + "-figures")
    return provenance.write(result["stem"], result, to_markdown(result))
