"""Every thesis table in one command: each row through its command line, over seeds, beside the thesis.

    python -m benchmarks.thesis                              # every table, 3 seeds, preset auto
    python -m benchmarks.thesis --tables 3.1 4.1 --seeds 1 --preset cpu
    python -m benchmarks.thesis --list                       # the rows and their commands
    python -m benchmarks.thesis --variant precise --tables 3.1 4.1 5.1   # the arm at a 1 cm goal

Each row of thesis Tables 3.1, 4.1, 4.3–4.5, 5.1, 5.4–5.7 and 6.2–6.3 is one command line of
``train/`` (``python -m train.<algo> ...``, run in this process) per seed, with ``--preset``,
``--seed`` and a run directory of its own under ``--runs``.  Its figures come from the run's own
evaluation (``eval.json``): success over 100 test episodes for the arm, the per-axis sum of
|error| over one test episode from ``t = 0`` for tracking, laps per road ending in success,
collision, off the track or stalled for racing (20 laps on each of the four roads).  Tables 7.1–7.3 (the thesis's
summaries) are drawn from those rows.  Rows whose algorithm or environment does not exist yet
are listed as **missing** with the reason.

Resumable: a seed whose run directory has ``eval.json`` is done and skipped; a run directory
without it (a killed run) continues with ``--resume``; rerunning the command finishes the rest
and rewrites the report.  The report is rewritten after every finished row, so a killed
invocation leaves the rows it finished.  Ctrl-C (or SIGTERM) stops a row's run after its current
chunk with a checkpoint, and the runner with it; the same command continues from there.

Report: ``<out>/thesis-<device>-<preset>.md`` (and ``.json``), one section per table — the
thesis's figure, ours as mean ± std over seeds with the per-seed values, met / not met against
the goal (arm: ≥ 95 % per row, with success at 2 and 1 cm beside it; tracking: ≤ ½ of the
thesis's best over its methods per axis; driving: ≥ 19 / 20 per road), wall time, commit,
device and the exact command — plus figures in ``<out>/thesis-<device>-<preset>-figures/``: per
table the learning curves of its rows (mean over seeds, min–max band) and, for tracking rows,
seed 0's reference-vs-path and per-axis error plots drawn by the run.

``--variant precise`` runs the arm rows (Tables 3.1, 4.1, 5.1) on ``arm7_precise`` (1 cm goal threshold
instead of 5 cm, ``envs_mjx.arm7.Arm7Precise``), where the methods separate: a row is met there at
≥ 95 % success within 2 cm and ≥ 90 % within 1 cm; its report and runs carry ``-precise`` in their names.

``--smoke`` shrinks every row's budget to seconds (checks the plumbing, not the numbers).
Seeds run one after another in this process (each a command-line run), or with ``--jobs N`` up to
``N`` seeds of a row at once, each a ``python -m train.<algo>`` process of its own (output in
``<runs>/<table>/<row>/seed<k>.log``; on a GPU each process gets 1/N of its memory): the compiles,
which take most of a short row's time, then overlap.  ``--together`` runs a row's seeds as one run
(the command line's ``--seeds N``: one program vmapped over the seeds on a GPU, one compiled program
looped over them on the CPU), its seeds in ``<runs>/<table>/<row>/seeds0-1-2/<run>/seed<k>/``.
``--parallel N`` runs up to ``N`` rows at once, each its seeds as one run (as ``--together``) in a process
of its own (output in ``<runs>/<table>/<row>/seeds0-1-2.log``; each process gets 1/N of the device's
memory), so that one row's compilation and small kernels overlap another's; ``--gpus 0 1 …`` spreads
those processes over GPUs, one GPU each.
"""

from __future__ import annotations

import argparse
import contextlib
import dataclasses
import glob
import importlib
import io
import json
import os
import queue
import re
import shutil
import subprocess
import sys
import time
from collections.abc import Sequence
from concurrent.futures import ThreadPoolExecutor, as_completed
from typing import Any

import numpy as np

from benchmarks import deviations, provenance
from benchmarks import seeds as bench_seeds
from benchmarks.arguments import nonnegative, positive
from benchmarks.tracking_report import GOAL, THESIS
from benchmarks.train_throughput import RESULTS, device_label
from jaxrl_robot import plots
from jaxrl_robot.logging import read_csv

ARM_GOAL = 95.0
PRECISE_GOAL = (95.0, 90.0)
"""``--variant precise``: success within 2 cm and within 1 cm, % (every arm row)."""
VARIANTS = ("standard", "precise", "faithful")
"""``faithful``: every row in the thesis's setting (:func:`faithful_row`, the ``thesis`` preset)."""
ROADS = ("train", "test1", "test2", "test3")
RACING_THESIS = {  # per road: (success, collision, out of track, overtakes) of 20 laps, Tables 6.2 and 6.3
    "ddpg": ((18, 2, 0, 2.65), (16, 2, 2, 2.55), (17, 2, 1, 2.6), (18, 1, 1, 2.85)),
    "td3": ((18, 2, 0, 2.6), (17, 2, 1, 2.65), (18, 1, 1, 2.9), (17, 2, 1, 2.7)),
}
"""Arm rows: success over 100 test episodes, % (every row)."""


@dataclasses.dataclass(frozen=True)
class Row:
    """One row of a thesis table.

    ``algo``: the ``train.<algo>`` command (None: missing); ``argv``: its flags beyond preset,
    seed and output; ``thesis``: the thesis's figure (success % for the arm, ``(x, y, θ or z)``
    sums for tracking); ``reference``: the tracking goal's key (``scara``, ``sine``, ``ellipse``).
    """

    table: str
    name: str
    label: str
    algo: str | None
    argv: tuple[str, ...]
    thesis: Any
    kind: str
    reference: str = ""
    missing: str = ""

    @property
    def id(self) -> str:
        return f"{self.table}/{self.name}"


ARM = ("--env", "arm7", "--env-config", "mode=kinematic")  # the thesis's arm runs in joint-position mode
UNICYCLE = {"sine": ("--env", "unicycle", "--env-config", "trajectory=sine"),
            "ellipse": ("--env", "unicycle", "--env-config", "trajectory=ellipse")}  # fmt: skip


def _tracking_rows() -> list[Row]:
    """Tables 4.3-4.5 (DDPG, distributed DDPG) and 5.4-5.7 (PPO, two-stage, PPO + LSTM)."""
    rows = []
    table = {"scara": "4.3", "sine": "4.4", "ellipse": "4.5"}
    for ref in ("scara", "sine", "ellipse"):
        env = ("--env", "scara") if ref == "scara" else UNICYCLE[ref]
        rows.append(Row(table[ref], f"{ref}-ddpg", f"DDPG + PER, {ref}", "ddpg", env, THESIS[(ref, "ddpg")],
                        "tracking", ref))  # fmt: skip
        rows.append(Row(table[ref], f"{ref}-distributed", f"Distributed DDPG, {ref}", "ddpg",
                        (*env, "--distributed"), THESIS[(ref, "distributed")], "tracking", ref))  # fmt: skip
    for ref in ("sine", "ellipse"):
        env = UNICYCLE[ref]
        rows += [
            Row("5.4-5.7", f"{ref}-ppo", f"Distributed PPO, {ref}", "ppo", env, THESIS[(ref, "mlp")], "tracking", ref),
            Row("5.4-5.7", f"{ref}-two-stage", f"Two-stage (action-search pre-training + PPO), {ref}", "ppo",
                (*env, "--pretrain", "action-search"), THESIS[(ref, "two-stage")], "tracking", ref),
            Row("5.4-5.7", f"{ref}-lstm", f"Distributed PPO + LSTM, {ref}", "ppo", (*env, "--policy", "lstm"),
                THESIS[(ref, "lstm")], "tracking", ref),
        ]  # fmt: skip
    return rows


ROWS: tuple[Row, ...] = (
    Row("3.1", "sparse-final", "DDPG, sparse reward, HER final", "ddpg",
        (*ARM, "--reward", "sparse", "--her", "final"), 79, "arm"),
    Row("3.1", "sparse-future2", "DDPG, sparse reward, HER future k=2", "ddpg",
        (*ARM, "--reward", "sparse", "--her", "future", "--her-k", "2"), 78, "arm"),
    Row("3.1", "sparse-future4", "DDPG, sparse reward, HER future k=4", "ddpg",
        (*ARM, "--reward", "sparse", "--her", "future", "--her-k", "4"), 81, "arm"),
    Row("3.1", "shaped-random2", "DDPG, shaped reward, HER random k=2", "ddpg",
        (*ARM, "--reward", "shaped", "--her", "random", "--her-k", "2"), 87, "arm"),
    Row("3.1", "shaped-future2", "DDPG, shaped reward, HER future k=2", "ddpg",
        (*ARM, "--reward", "shaped", "--her", "future", "--her-k", "2"), 56, "arm"),
    Row("3.1", "shaped-per", "DDPG, shaped reward, no relabelling, PER (no goal in the observation)", "ddpg",
        ("--env", "arm7", "--env-config", "mode=kinematic", "obs=no_goal", "--reward", "shaped", "--her", "none",
         "--per"), 9, "arm"),
    Row("4.1", "a3c-ordinary", "A3C, ordinary reward", "a3c", (*ARM, "--reward", "ordinary"), 76, "arm"),
    Row("4.1", "a3c-path", "A3C, path reward", "a3c", (*ARM, "--reward", "path"), 84, "arm"),
    Row("4.1", "a2c-ordinary", "A2C, ordinary reward", "a2c", (*ARM, "--reward", "ordinary"), 79, "arm"),
    Row("4.1", "a2c-path", "A2C, path reward", "a2c", (*ARM, "--reward", "path"), 88, "arm"),
    *[r for r in _tracking_rows() if r.table in ("4.3", "4.4", "4.5")],
    Row("5.1", "ppo-ordinary", "Distributed PPO, ordinary reward", "ppo", (*ARM, "--reward", "ordinary"), 82, "arm"),
    Row("5.1", "ppo-path", "Distributed PPO, path reward", "ppo", (*ARM, "--reward", "path"), 91, "arm"),
    *[r for r in _tracking_rows() if r.table == "5.4-5.7"],
    *[Row("6.2-6.3", algo, f"{algo.upper()} after imitation of the expert, 20 laps per road", algo,
          ("--env", "racecar", "--eval-episodes", "20"), RACING_THESIS[algo], "driving")
      for algo in ("ddpg", "td3")],
)  # fmt: skip
"""Every row of the thesis's result tables (chapters 3-6)."""

TABLES = tuple(dict.fromkeys(r.table for r in ROWS))
TITLES = {
    "3.1": "Table 3.1 — DDPG with HER / PER on the arm (success over 100 test goals, %)",
    "4.1": "Table 4.1 — A3C and A2C on the arm (success, %)",
    "4.3": "Table 4.3 — SCARA tracking, DDPG and distributed DDPG (sum of |error|: x, y, z in m)",
    "4.4": "Table 4.4 — unicycle sine, DDPG and distributed DDPG (sum of |error|: x, y m; θ rad)",
    "4.5": "Table 4.5 — unicycle ellipse, DDPG and distributed DDPG (sum of |error|)",
    "5.1": "Table 5.1 — distributed PPO on the arm (success, %)",
    "5.4-5.7": "Tables 5.4–5.7 — unicycle, PPO, two-stage and PPO + LSTM (sum of |error|)",
    "6.2-6.3": "Tables 6.2–6.3 — racing with opponents, 20 laps per road (success / collision / out / overtakes)",
}

SMOKE = {  # budgets of seconds: the plumbing, not the numbers
    ("ddpg", "arm"): ("--epochs", "1", "--cycles-per-epoch", "2", "--num-envs", "4", "--updates-per-cycle", "2",
                      "--batch-size", "16", "--actor-hidden", "16", "--critic-hidden", "16", "--eval-episodes", "4"),
    ("ddpg", "tracking"): ("--total-steps", "256", "--learning-starts", "64", "--batch-size", "16",
                           "--actor-hidden", "16", "--critic-hidden", "16", "--chunks", "2"),
    ("a2c", "arm"): ("--total-steps", "256", "--chunks", "2", "--eval-episodes", "4"),
    ("ppo", "arm"): ("--total-steps", "1024", "--chunks", "2", "--eval-episodes", "4"),
    ("ppo", "tracking"): ("--total-steps", "1024", "--chunks", "2"),
    ("ddpg", "driving"): ("--total-steps", "256", "--pretrain-steps", "128", "--num-envs", "4", "--unroll-length",
                          "4", "--learning-starts", "32", "--batch-size", "16", "--actor-hidden", "16",
                          "--critic-hidden", "16", "--imitation-batch", "16", "--imitation-updates", "1",
                          "--chunks", "2", "--eval-episodes", "1", "--env-config", "n_opponents=2", "max_steps=100"),
}  # fmt: skip


def precise_row(row: Row) -> Row:
    """``row`` on ``arm7_precise`` (arm rows; any other row unchanged)."""
    if row.kind != "arm":
        return row
    argv = tuple("arm7_precise" if a == "arm7" and i and row.argv[i - 1] == "--env" else a
                 for i, a in enumerate(row.argv))  # fmt: skip
    return dataclasses.replace(row, argv=argv)


def faithful_row(row: Row) -> Row:
    """``row`` in the thesis's plant: the unicycle rows in ``kinematic`` mode (the thesis's Euler update of
    Eq. 3.18; the arm rows already run ``kinematic``); with the ``thesis`` preset (Tables 3.2, 3.3, 4.2,
    5.2, 5.3 and Eq. 3.21–3.23) the thesis's setting."""
    if "unicycle" not in row.argv:
        return row
    argv = tuple(x for a in row.argv for x in ((a, "mode=kinematic") if a.startswith("trajectory=") else (a,)))
    return dataclasses.replace(row, argv=argv)


def is_precise(row: Row | dict) -> bool:
    argv = row.argv if isinstance(row, Row) else row["argv"]
    return "arm7_precise" in argv


def smoke_args(row: Row) -> tuple[str, ...]:
    algo = {"a3c": "a2c", "td3": "ddpg"}.get(row.algo, row.algo)
    return SMOKE[(algo, row.kind)]


def command(row: Row, preset: str, seed: int, smoke: bool) -> list[str]:
    """The row's ``train.<algo>`` arguments for one seed (output directory apart)."""
    return [*row.argv, "--preset", preset, "--seed", str(seed), *(smoke_args(row) if smoke else ())]


def latest_run(out: str) -> str | None:
    """The newest run directory under ``out`` (None before the first start)."""
    found = sorted(glob.glob(os.path.join(out, "*", "config.json")))
    return os.path.dirname(found[-1]) if found else None


def run_dir_of(runs: str, row: Row, seed: int) -> str | None:
    """The run directory of ``row`` and ``seed`` under ``runs`` (None before its first start)."""
    return latest_run(os.path.join(runs, row.table, row.name, f"seed{seed}"))


def seed_start(row: Row, seed: int, args: argparse.Namespace) -> tuple[dict[str, Any] | None, list[str], str]:
    """How one seed of ``row`` starts: ``(record, argv, out)`` — the record of a finished seed (skipped)
    or None, the command line that starts it (or continues a killed run) and its parent folder."""
    out = os.path.join(args.runs, row.table, row.name, f"seed{seed}")
    existing = run_dir_of(args.runs, row, seed)
    if existing and os.path.exists(os.path.join(existing, "eval.json")):
        return finished_record(os.path.join(existing, "eval.json")), [], out
    argv = ["--resume", existing] if existing else [*command(row, args.preset, seed, args.smoke), "--out", out]
    return None, argv, out


def seed_result(row: Row, seed: int, args: argparse.Namespace, code: Any, wall: float, where: str = "") -> dict:
    """The record of a seed's run that ended with exit ``code``: its evaluation, or the error."""
    return run_record(run_dir_of(args.runs, row, seed), code, wall, where)


RAN_AT = "provenance.json"
"""Written into a seed's run directory when it finishes: the commit and tree it ran from."""


def mark_ran(run_dir: str, prov: dict[str, Any]) -> dict[str, Any]:
    """Record in ``run_dir`` (``provenance.json``) that its run finished under ``prov`` (this invocation's
    provenance): commit, dirty flag, tree and diff SHA-1, command; returns that record."""
    keep = ("commit", "dirty", "dirty_count", "diff_sha1", "tree_sha1", "commit_source", "command")
    ran = {k: prov.get(k) for k in keep}
    with open(os.path.join(run_dir, RAN_AT), "w") as f:
        json.dump(ran, f, indent=1)
    return ran


def ran_at(run_dir: str) -> dict[str, Any] | None:
    """The ``provenance.json`` of a finished run (None where the run wrote none: before it was recorded)."""
    try:
        with open(os.path.join(run_dir, RAN_AT)) as f:
            return json.load(f)
    except (OSError, ValueError):
        return None


def finished_record(eval_json: str) -> dict[str, Any]:
    """The record of a seed found finished (``eval.json``), skipped: its evaluation, folder and provenance."""
    run_dir = os.path.dirname(eval_json)
    with open(eval_json) as f:
        done = {**json.load(f), "run_dir": run_dir, "skipped": True}
    ran = ran_at(run_dir)
    return {**done, "provenance": ran} if ran else done


def row_provenance(seeds: list[dict]) -> dict[str, Any]:
    """A row's provenance from its seeds' records: the commits they ran at, whether every one's tree was clean,
    and how many finished seeds recorded none."""
    done = [s for s in seeds if "error" not in s]
    ran = [s["provenance"] for s in done if s.get("provenance")]
    return {"commits": sorted({r["commit"] for r in ran}), "clean": all(r.get("dirty") is False for r in ran),
            "missing": len(done) - len(ran)}  # fmt: skip


def run_record(run_dir: str | None, code: Any, wall: float, where: str = "") -> dict:
    """The record of the run in ``run_dir`` (a seed's folder) that ended with exit ``code``: its
    ``eval.json``, or the error."""
    if code != 0 or run_dir is None or not os.path.exists(os.path.join(run_dir, "eval.json")):
        return {"error": f"exit code {code}{where}", "run_dir": run_dir, "wall_s": wall}
    return {**json.load(open(os.path.join(run_dir, "eval.json"))), "run_dir": run_dir, "process_s": wall}


def run_in_process(row: Row, argv: list[str], quiet: bool) -> tuple[Any, float]:
    """``python -m train.<algo> argv`` of ``row`` in this process: ``(exit code, wall s)``."""
    main = importlib.import_module(f"train.{row.algo}").main
    t0 = time.perf_counter()
    with contextlib.redirect_stdout(io.StringIO()) if quiet else contextlib.nullcontext():
        try:
            code = main(argv)
        except SystemExit as e:  # a command line that does not parse
            code = e.code
    from train.run import STOP_SIGNALS

    if code in [128 + s for s in STOP_SIGNALS]:  # Ctrl-C / SIGTERM: the run saved a checkpoint and stopped
        raise SystemExit(f"interrupted: {row.id} stopped with a checkpoint; the same command continues it")
    return code, time.perf_counter() - t0


def run_seed(row: Row, seed: int, args: argparse.Namespace) -> dict[str, Any]:
    """Run (or continue, or skip) one seed of ``row`` in this process; its evaluation and wall time."""
    done, argv, _ = seed_start(row, seed, args)
    if done is not None:
        return done
    code, wall = run_in_process(row, argv, args.quiet)
    return seed_result(row, seed, args, code, wall)


def run_seeds_apart(row: Row, seeds: Sequence[int], args: argparse.Namespace) -> list[dict[str, Any]]:
    """Run (or continue, or skip) the ``seeds`` of ``row`` at once, each in a process of its own;
    the same records as :func:`run_seed`, in the order of ``seeds``."""
    procs, results = {}, {}
    for seed in seeds:
        done, argv, out = seed_start(row, seed, args)
        if done is not None:
            results[seed] = done
            continue
        os.makedirs(out, exist_ok=True)
        env = {**os.environ, "XLA_PYTHON_CLIENT_MEM_FRACTION": f"{0.9 / len(seeds):.3f}"}
        log = open(out + ".log", "w")
        procs[seed] = (subprocess.Popen([sys.executable, "-m", f"train.{row.algo}", *argv], stdout=log,
                                        stderr=subprocess.STDOUT, env=env), log, time.perf_counter())  # fmt: skip
    for seed, (proc, log, t0) in procs.items():
        code = proc.wait()
        log.close()
        results[seed] = seed_result(row, seed, args, code, time.perf_counter() - t0, f" (log: {log.name})")
    return [results[s] for s in seeds]


def together_start(
    row: Row, seeds: Sequence[int], args: argparse.Namespace
) -> tuple[list[dict] | None, list[str], str]:
    """How the ``seeds`` of ``row`` start as one run: ``(records, argv, out)`` — the records of a finished
    run (skipped) or None, the command line that starts it (or continues a killed run) and its parent
    folder ``<runs>/<table>/<row>/seeds<0-1-…>``."""
    out = os.path.join(args.runs, row.table, row.name, "seeds" + "-".join(map(str, seeds)))
    run = latest_run(out)
    evals = [os.path.join(seed_folder(run, seeds, k), "eval.json") for k in seeds] if run else []
    if run and all(os.path.exists(e) for e in evals):
        return [finished_record(e) for e in evals], [], out
    if run:
        return None, ["--resume", run], out
    return None, [*command(row, args.preset, seeds[0], args.smoke), "--seeds", str(len(seeds)), "--out", out], out


def together_records(out: str, seeds: Sequence[int], code: Any, wall: float, where: str = "") -> list[dict]:
    """The records of the seeds of the run under ``out`` that ended with exit ``code``."""
    run = latest_run(out)
    return [run_record(seed_folder(run, seeds, k) if run else None, code, wall, where) for k in seeds]


def seed_folder(run: str, seeds: Sequence[int], seed: int) -> str:
    """Where seed ``seed`` of a run of ``seeds`` writes: ``<run>/seed<k>/``, or the run itself for one seed."""
    return os.path.join(run, f"seed{seed}") if len(seeds) > 1 else run


def run_seeds_together(row: Row, seeds: Sequence[int], args: argparse.Namespace) -> list[dict[str, Any]]:
    """Run (or continue, or skip) the ``seeds`` of ``row`` as one run in this process, ``--seeds N`` of the
    algorithm's command line (one program vmapped over the seeds on a GPU, the same compiled program once
    per seed on the CPU; ``train.seeds.SeedProgram``); the same records as :func:`run_seed`, in the order
    of ``seeds``, each with its ``run_dir`` the seed's folder ``<run>/seed<k>/``."""
    done, argv, out = together_start(row, seeds, args)
    if done is not None:
        return done
    code, wall = run_in_process(row, argv, args.quiet)
    return together_records(out, seeds, code, wall)


def row_process_env(slot: int, args: argparse.Namespace) -> dict[str, str]:
    """The environment of the row process in ``slot`` (0 … ``--parallel`` − 1): pinned to GPU
    ``gpus[slot % len(gpus)]`` with ``--gpus``, and given its share of that device's memory (1/k of 90 %
    for the k slots that share it)."""
    env = dict(os.environ)
    sharing = args.parallel
    if args.gpus:
        env["CUDA_VISIBLE_DEVICES"] = str(args.gpus[slot % len(args.gpus)])
        sharing = len(range(slot % len(args.gpus), args.parallel, len(args.gpus)))
    env["XLA_PYTHON_CLIENT_MEM_FRACTION"] = f"{0.9 / sharing:.3f}"
    return env


def run_row_process(row: Row, seeds: Sequence[int], args: argparse.Namespace, slots: queue.Queue) -> list[dict]:
    """Run (or continue, or skip) the ``seeds`` of ``row`` as one run (as :func:`run_seeds_together`) in a
    process of its own, in a free slot of ``slots`` (output in ``<out>.log``)."""
    done, argv, out = together_start(row, seeds, args)
    if done is not None:
        return done
    slot = slots.get()
    try:
        os.makedirs(out, exist_ok=True)
        t0 = time.perf_counter()
        with open(out + ".log", "w") as log:
            code = subprocess.run([sys.executable, "-m", f"train.{row.algo}", *argv], stdout=log,
                                  stderr=subprocess.STDOUT, env=row_process_env(slot, args)).returncode  # fmt: skip
        return together_records(out, seeds, code, time.perf_counter() - t0, f" (log: {out}.log)")
    finally:
        slots.put(slot)


def axis_keys(ev: dict) -> tuple[str, str, str]:
    return ("x", "y", "z") if "z" in ev else ("x", "y", "theta")


def row_figure(row: Row, seeds: list[dict]) -> dict[str, Any]:
    """Mean ± std over the seeds that finished, the per-seed values, and met / not met."""
    done = [s for s in seeds if "error" not in s]
    out: dict[str, Any] = {"seeds_done": len(done), "seeds": len(seeds)}
    if not done:
        return out
    if row.kind == "driving":  # successes per road; met: ≥ 19 of 20 (95 %) and ≤ 1 collision (5 %) on every seed
        laps = float(done[0]["laps_per_road"])
        vals = np.array([[s[f"{road}/success"] for road in ROADS] for s in done], float)
        crashes = np.array([[s[f"{road}/collision"] for road in ROADS] for s in done], float)
        goal = np.full(len(ROADS), 0.95 * laps)
        met = (vals >= goal).all(0) & (crashes <= 0.05 * laps).all(0)
        out.update(laps=laps, collisions=crashes.mean(0).tolist(),
                   overtakes=[float(np.mean([s[f"{road}/overtakes"] for s in done])) for road in ROADS],
                   speed_kmh=[float(np.mean([s[f"{road}/speed_kmh"] for s in done])) for road in ROADS])  # fmt: skip
    elif row.kind == "arm" and is_precise(row):  # within 2 cm and within 1 cm, every seed's figures
        vals = np.array([[100.0 * s["success_2cm"], 100.0 * s["success_1cm"]] for s in done])
        goal = np.array(PRECISE_GOAL)
        met = vals.mean(0) >= goal
        out["precision"] = [100.0 * float(np.mean([s["success_5cm"] for s in done]))]
    elif row.kind == "arm":
        vals = np.array([[100.0 * s["success_rate"]] for s in done])
        goal = np.array([ARM_GOAL])
        met = vals.mean(0) >= goal
        if all("success_1cm" in s for s in done):  # success at 2 and 1 cm (mean over seeds, %)
            out["precision"] = [100.0 * float(np.mean([s[k] for s in done])) for k in ("success_2cm", "success_1cm")]
    else:
        vals = np.array([[s[k] for k in axis_keys(s)] for s in done])
        goal = np.array(GOAL[row.reference])
        met = vals.mean(0) <= goal
        if all("steps" in s for s in done):  # the test episode's steps and the mean |error| per step
            steps = np.array([float(s["steps"]) for s in done])
            out.update(steps=steps.tolist(), per_step=(vals / steps[:, None]).mean(0).tolist())
    out.update(values=vals.tolist(), mean=vals.mean(0).tolist(), std=vals.std(0).tolist(), goal=goal.tolist(),
               met=met.tolist(), wall_s=runs_wall(done))  # fmt: skip
    return out


def runs_wall(seeds: list[dict]) -> float:
    """Wall seconds of the runs behind ``seeds``: a run of several seeds together (its seeds' folders
    ``<run>/seed<k>/`` share ``<run>``, and each seed's ``eval.json`` gives the whole run's wall) counts
    once; a seed run on its own counts its own."""
    walls: dict[str, float] = {}
    for i, s in enumerate(seeds):
        run_dir = s.get("run_dir") or f"#{i}"
        together = re.fullmatch(r"seed\d+", os.path.basename(run_dir)) is not None
        key = os.path.dirname(run_dir) if together else run_dir
        walls[key] = max(walls.get(key, 0.0), float(s.get("wall_s", s.get("process_s", 0.0))))
    return float(sum(walls.values()))


def _cell(mean: float, std: float, met: bool, digits: int) -> str:
    text = f"{mean:.{digits}f} ± {std:.{digits}f}"
    return f"**{text}**" if met else text


def _faithful_cell(fig: dict | None, kind: str, i: int = 0) -> str:
    """The faithful column's cell: ``fig``'s mean ± std (tracking: x / y / θ-z means; driving: road ``i``'s
    successes), ``not run`` without one."""
    if not fig or not fig.get("seeds_done"):
        return "not run"
    if kind == "tracking":
        return " / ".join(f"{m:.2f}" for m in fig["mean"]) + f" ({fig['seeds_done']} seeds)"
    return f"{fig['mean'][i]:.1f} ± {fig['std'][i]:.1f} ({fig['seeds_done']} seeds)"


def deviations_markdown(rows: list[dict], faithful: dict[str, dict]) -> list[str]:
    """Under a table: each row's deviations from the thesis's setting (:mod:`benchmarks.deviations`), and the
    faithful column's where it has rows."""
    listed = [r for r in rows if r.get("deviations")]
    if not listed:
        return []
    lines = ["", "Deviations from the thesis's setting (the thesis's value → ours; the `thesis` preset and the "
             "thesis's plant are the reference, `benchmarks/deviations.py`):", ""]  # fmt: skip
    for r in listed:
        lines.append(f"- {r['row']['label']}: {r['deviations']['text']}")
    sources = dict.fromkeys(r["deviations"]["source"] for r in listed)
    lines += ["", "Read from " + "; ".join(sources) + "."]
    kept = [(r, faithful[r["row"]["name"]]) for r in rows if r["row"]["name"] in faithful]
    if kept:
        lines += ["", "The faithful column's own deviations:", ""]
        lines += [f"- {r['row']['label']}: {f['deviations']['text'] if f.get('deviations') else 'not recorded'}"
                  for r, f in kept]  # fmt: skip
    return lines


TABLE_COLUMNS = {
    "precise": "row; thesis (5 cm):; ours within 2 cm:; ours within 1 cm:; seeds (2 cm / 1 cm); met (≥ 95 / ≥ 90); "
               "within 5 cm:; wall s:; command",
    "arm": "row; thesis:; faithful (thesis's setting):; ours (mean ± std):; seeds; met (≥ 95); at 2 cm / 1 cm:; "
           "wall s:; command",
    "tracking": "row; thesis x / y / θ-z; faithful x / y / θ-z; ours x:; ours y:; ours θ-z:; "
                "ours per step x / y / θ-z; test steps:; seeds (x / y / θ-z); goal; met; wall s:; command",
    "driving": "row; road; thesis success / collision / out / overtakes; faithful success:; ours success:; "
               "collisions:; overtakes:; km/h:; seeds; met; wall s:; command",
}  # fmt: skip
"""The columns of a thesis table's section by the kind of its rows (``precise``: an arm table at a 1 cm goal),
``;``-separated; a trailing ``:`` aligns the column to the right."""


def table_header(kind: str) -> list[str]:
    """The header and alignment rows of a section of ``kind`` (:data:`TABLE_COLUMNS`; another kind: row, thesis,
    ours, status)."""
    columns = [c.strip() for c in TABLE_COLUMNS.get(kind, "row; thesis; ours; status").split(";")]
    names = [c.removesuffix(":") for c in columns]
    align = ["---:" if c.endswith(":") else "---" for c in columns]
    return ["| " + " | ".join(names) + " |", "|" + "|".join(align) + "|"]


def table_markdown(table: str, results: list[dict], fig_dir: str, rel: str,
                   faithful: dict[str, dict] | None = None) -> list[str]:  # fmt: skip
    """The section of one table: rows, thesis figures, goals, per-seed values, the faithful column (``faithful``:
    row name -> its result in the thesis's setting; :func:`faithful_row`), its figures and each row's
    deviations from the thesis's setting."""
    faithful = faithful or {}
    lines = [f"## {TITLES[table]}", ""]
    rows = [r for r in results if r["row"]["table"] == table]
    kind = rows[0]["row"]["kind"]
    precise = kind == "arm" and is_precise(rows[0]["row"])
    lines += table_header("precise" if precise else kind)
    columns = lines[-2].count("|") - 1
    curves: dict[str, list] = {}
    for r in rows:
        row, fig = r["row"], r["figure"]
        kept = faithful.get(row["name"], {}).get("figure")
        cmd = f"`python -m train.{row['algo']} {' '.join(r['command'])}`" if row["algo"] else ""
        if row["missing"]:
            lines.append(f"| {row['label']} | {row['thesis']} | **missing** | {row['missing']} |")
            continue
        if not fig.get("seeds_done"):
            errors = "; ".join(s.get("error", "") for s in r["seeds"])
            lines.append(f"| {row['label']} | {row['thesis']} | **not run** ({errors or 'no seed finished'}) |"
                         + " |" * (columns - 3))  # fmt: skip
            continue
        per_seed = "; ".join(" / ".join(f"{v:.2f}" if kind == "tracking" else f"{v:.0f}" for v in s)
                             for s in fig["values"])  # fmt: skip
        seeds = f"{per_seed} ({fig['seeds_done']}/{fig['seeds']})"
        if kind == "driving":
            for i, road in enumerate(ROADS):
                thesis = " / ".join(f"{v:g}" for v in row["thesis"][i])
                cell = _cell(fig["mean"][i], fig["std"][i], fig["met"][i], 1)
                each = ", ".join(f"{v[i]:.0f}" for v in fig["values"])
                lines.append(f"| {row['label'] if i == 0 else ''} | {road} | {thesis} "
                             f"| {_faithful_cell(kept, kind, i)} | {cell} of {fig['laps']:.0f} | "
                             f"{fig['collisions'][i]:.1f} | {fig['overtakes'][i]:.2f} | {fig['speed_kmh'][i]:.0f} | "
                             f"{each} ({fig['seeds_done']}/{fig['seeds']}) | {'yes' if fig['met'][i] else 'no'} | "
                             f"{fig['wall_s']:.0f} | {cmd if i == 0 else ''} |")  # fmt: skip
        elif precise:
            cells = " | ".join(_cell(m, s, ok, 1) for m, s, ok in zip(fig["mean"], fig["std"], fig["met"], strict=True))
            met = "yes" if all(fig["met"]) else "no"
            lines.append(f"| {row['label']} | {row['thesis']} | {cells} | {seeds} | {met} "
                         f"| {fig['precision'][0]:.1f} | {fig['wall_s']:.0f} | {cmd} |")  # fmt: skip
        elif kind == "arm":
            cell = _cell(fig["mean"][0], fig["std"][0], fig["met"][0], 1)
            at = " / ".join(f"{v:.1f}" for v in fig.get("precision", ())) or "—"
            lines.append(f"| {row['label']} | {row['thesis']} | {_faithful_cell(kept, kind)} | {cell} | {seeds} "
                         f"| {'yes' if fig['met'][0] else 'no'} | {at} | {fig['wall_s']:.0f} | {cmd} |")  # fmt: skip
        else:
            cells = " | ".join(_cell(m, s, ok, 2) for m, s, ok in zip(fig["mean"], fig["std"], fig["met"], strict=True))
            goal = " / ".join(f"{g:.2f}" for g in fig["goal"])
            met = f"{sum(fig['met'])}/3"
            thesis = " / ".join(str(t) for t in row["thesis"])
            per_step = " / ".join(f"{v:.4f}" for v in fig["per_step"]) if "per_step" in fig else "not recorded"
            steps = "/".join(f"{v:.0f}" for v in dict.fromkeys(fig["steps"])) if "steps" in fig else "not recorded"
            lines.append(f"| {row['label']} | {thesis} | {_faithful_cell(kept, kind)} | {cells} | {per_step} | {steps} "
                         f"| {seeds} | {goal} | {met} | {fig['wall_s']:.0f} | {cmd} |")  # fmt: skip
        csvs = [os.path.join(s["run_dir"], "metrics.csv") for s in r["seeds"] if "error" not in s]
        curves[row["name"]] = [read_csv(c) for c in csvs if os.path.exists(c)]
        if kind == "tracking" and r["seeds"] and "error" not in r["seeds"][0]:
            for name in ("tracking_path.png", "tracking_errors.png"):
                src, dst = os.path.join(r["seeds"][0]["run_dir"], name), f"{table}-{row['name']}-{name}"
                if os.path.exists(src):
                    shutil.copy(src, os.path.join(fig_dir, dst))
                if os.path.exists(os.path.join(fig_dir, dst)):  # copied now, or by the invocation that ran the row
                    lines.append(f"| ![{row['label']}: {name[:-4]}, seed 0]({rel}/{dst}) |" + " |" * (columns - 1))
    key = "success" if kind == "arm" else "episode_return"
    name = f"table-{table}-curves.png"
    if any(curves.values()):
        plots.plot_seed_bands(curves, key, fig_dir, name, TITLES[table].split(" — ")[0])
    if os.path.exists(os.path.join(fig_dir, name)):
        lines += ["", f"![learning curves, {TITLES[table].split(' — ')[0]}]({rel}/{name})"]
    lines += deviations_markdown(rows, faithful if not precise else {})
    lines.append("")
    return lines


def summary_markdown(results: list[dict]) -> list[str]:
    """Tables 7.1-7.3 (the thesis's summaries): the best of ours per arm method and per tracking axis."""
    lines = ["## Tables 7.1–7.3 — summaries", "", "| summary | thesis best | ours best (row) | goal | met |",
             "|---|---:|---:|---:|---|"]  # fmt: skip
    arm = [r for r in results if r["row"]["kind"] == "arm" and r["figure"].get("seeds_done")]
    if arm:
        best = max(arm, key=lambda r: r["figure"]["mean"][0])
        worst = min(arm, key=lambda r: r["figure"]["mean"][0])
        thesis = max(r["row"]["thesis"] for r in results if r["row"]["kind"] == "arm")
        within = " (within 2 cm)" if is_precise(best["row"]) else ""
        goal = f"≥ {PRECISE_GOAL[0]:.0f} within 2 cm" if within else f"≥ {ARM_GOAL:.0f}"
        lines.append(f"| 7.1 arm, best row{within} | {thesis} "
                     f"| {best['figure']['mean'][0]:.1f} ({best['row']['label']}) "
                     f"| {goal} every row | lowest row {worst['figure']['mean'][0]:.1f} |")  # fmt: skip
    for ref in ("scara", "sine", "ellipse"):
        rs = [r for r in results if r["row"]["reference"] == ref]
        if not rs:
            continue
        done = [r for r in rs if r["figure"].get("seeds_done")]
        for axis in range(3):
            thesis = min(r["row"]["thesis"][axis] for r in rs)
            if not done:
                lines.append(f"| 7.2-7.3 {ref} axis {axis + 1} | {thesis} | not run | {GOAL[ref][axis]} | |")
                continue
            best = min(done, key=lambda r: r["figure"]["mean"][axis])
            value = best["figure"]["mean"][axis]
            lines.append(f"| 7.2-7.3 {ref}, {'xyz'[axis] if ref == 'scara' else ('x', 'y', 'θ')[axis]} | {thesis} "
                         f"| {value:.2f} ({best['row']['label']}) | {GOAL[ref][axis]} "
                         f"| {'yes' if value <= GOAL[ref][axis] else 'no'} |")  # fmt: skip
    return [*lines, ""]


def faithful_paths(faithful: str | Sequence[str] | None) -> list[str]:
    """The faithful reports a report names (one path in reports written before several could be named)."""
    return [] if not faithful else [faithful] if isinstance(faithful, str) else list(faithful)


def load_faithful(faithful: str | Sequence[str] | None) -> dict[str, dict]:
    """The rows of faithful reports (``--variant faithful``'s ``.json``, one or several, each holding other rows)
    by row name; {} without one.  A path that does not exist is passed over."""
    rows: dict[str, dict] = {}
    for path in faithful_paths(faithful):
        if os.path.exists(path):
            with open(path) as f:
                rows.update({r["row"]["name"]: r for r in json.load(f).get("rows", [])})
    return rows


def header(meta: dict[str, Any]) -> list[str]:
    """The report's title and its first paragraph (command, commit, seeds, wall time, what bold means)."""
    variant = meta.get("variant")
    title = {"precise": ", the arm at a 1 cm goal (`arm7_precise`)",
             "faithful": ", every row in the thesis's setting (`--variant faithful`)"}.get(variant, "")  # fmt: skip
    purpose = meta.get("purpose")
    seeds = (f"{meta['seeds']} seed(s) per row ({seed_words(meta)})" if purpose else f"{meta['seeds']} seed(s) per row")
    faithful = ", ".join(f"`{os.path.basename(p)}`" for p in faithful_paths(meta.get("faithful")))
    return [
        f"# The thesis's tables with jaxrl-robot — {meta['device']}, `{meta['preset']}` preset{title}",
        "",
        f"`{meta['command']}` at commit {meta['commit']} (jax {meta['jax']}, {meta['date']}); {seeds}, "
        + ("a row's seeds one command-line run (`--seeds`)" if meta.get("together") else "each one command-line run")
        + (f", {meta['parallel']} rows at once" if meta.get("parallel", 1) > 1 else "")
        + f"; the rows' runs took {meta['runs_wall_s']:.0f} s in all "
        f"(this invocation {meta['wall_s']:.0f} s)"
        + (" (smoke budgets: not results)" if meta["smoke"] else "") + ". Bold: at the goal (arm ≥ 95 % per row"
        + ("; precise variant: ≥ 95 % within 2 cm and ≥ 90 % within 1 cm" if variant == "precise" else "")
        + "; "
        "tracking ≤ ½ of the thesis's best over all its methods, per axis; racing ≥ 19 of 20 laps per road with "
        "at most 1 collision, every seed). Tracking: the sum of |error| over one test episode from t = 0, its "
        "steps and the mean per step beside. The faithful column: the same row in the thesis's setting ("
        + (faithful or "not run yet: `python -m benchmarks.thesis --variant "
           "faithful --purpose report`") + "); each row's deviations from that setting are listed under its table.",
        "",
        *([meta["note"], ""] if meta.get("note") else []),
    ]  # fmt: skip


def seed_words(meta: dict[str, Any]) -> str:
    """``the report range: seeds 1000000..1000002`` or ``the tuning range: seeds 0..2``."""
    ids = meta.get("seed_ids") or []
    span = f"{ids[0]}..{ids[-1]}" if ids else "?"
    return ("the report range, never used to choose a setting" if meta["purpose"] == "report"
            else "the tuning range") + f": seeds {span}"  # fmt: skip


def report(results: list[dict], meta: dict[str, Any], stem: str, rewrite: bool = False) -> str:
    """Write ``stem.md`` / ``stem.json`` with ``meta["provenance"]`` (figures in ``stem-figures/``); returns the
    markdown. ``rewrite``: the markdown alone, anew from a saved report (its ``.json`` left as it is)."""
    fig_dir = stem + "-figures"
    os.makedirs(fig_dir, exist_ok=True)
    rel = os.path.basename(fig_dir)
    faithful = load_faithful(meta.get("faithful"))
    lines = header(meta)
    for table in dict.fromkeys(r["row"]["table"] for r in results):
        lines += table_markdown(table, results, fig_dir, rel, faithful)
    lines += summary_markdown(results)
    text = "\n".join(lines)
    saved = {"provenance": meta["provenance"], "meta": meta, "rows": results}
    if rewrite:
        return provenance.rewrite_markdown(stem, saved, text)
    return provenance.write(stem, saved, text)


def regenerate(path: str, faithful: Sequence[str] | None = None, results: str = RESULTS) -> str:
    """Rewrite the markdown of the saved report ``path`` (``.json``) with this code: figures and deviations
    from its rows (each row's ``config.json`` kept under ``<results>/runs/``), the faithful column from
    the reports ``faithful`` (default: those the report names; given, they are named in its ``.json`` from then on).
    Returns the markdown."""
    with open(path) as f:
        saved = json.load(f)
    stem = path[: -len(".json")]
    if faithful:  # kept in the report's .json, so that a later rewrite (benchmarks.regenerate) reads the same
        saved["meta"]["faithful"] = list(faithful)
        with open(path, "w") as f:
            json.dump(saved, f, indent=1)
    meta = {**saved["meta"], "provenance": saved["provenance"]}
    for r in saved["rows"]:
        r["figure"] = row_figure(Row(**r["row"]), r["seeds"])
        if r["figure"].get("seeds_done") and r["row"]["algo"] and not meta.get("smoke"):
            config = deviations.kept_config(results, stem, r["row"]["table"], r["row"]["name"])
            r["deviations"] = deviations.row_deviations(r["row"]["algo"], r["row"]["argv"], r["row"]["kind"], config,
                                                        meta["preset"])  # fmt: skip
    return report(saved["rows"], meta, stem, rewrite=True)


def select(tables: Sequence[str] | None, names: Sequence[str] | None, variant: str = "standard") -> list[Row]:
    """The rows of ``tables`` (default all), narrowed to ``names`` (row ids ``table/name`` or names);
    ``variant='precise'``: the arm rows on ``arm7_precise``; ``'faithful'``: every row in the thesis's plant
    (:func:`faithful_row`)."""
    change = {"precise": precise_row, "faithful": faithful_row}.get(variant, lambda r: r)
    rows = [change(r) for r in ROWS if not tables or r.table in tables]
    if names:
        rows = [r for r in rows if r.id in names or r.name in names]
    return rows


def main(argv: list[str] | None = None) -> dict[str, Any]:
    import jax
    from rich.console import Console

    from train.presets import resolve_preset

    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--tables", nargs="+", default=None, choices=TABLES,
                   help="default: every table; rows run in this order (the report keeps the thesis's)")
    p.add_argument("--rows", nargs="+", default=None, help="only these rows (table/name or name; see --list)")
    bench_seeds.add_args(p)
    p.add_argument("--preset", default="auto", choices=["auto", "thesis", "cpu", "fast"])
    p.add_argument("--variant", default="standard", choices=VARIANTS,
                   help="precise: the arm rows on arm7_precise (1 cm goal; met at >= 95 %% within 2 cm and >= 90 %% "
                   "within 1 cm); faithful: every row in the thesis's setting (the thesis preset, the unicycle's "
                   "kinematic plant)")
    p.add_argument("--faithful", nargs="+", default=None, metavar="JSON",
                   help="--variant faithful reports whose rows fill the faithful column (default: every "
                   "<out>/thesis-<device>-thesis-faithful*.json)")
    p.add_argument("--regenerate", nargs="+", default=None, metavar="JSON",
                   help="rewrite the markdown of these saved reports with this code (deviations, per-step errors, "
                   "the faithful column); runs nothing")
    p.add_argument("--runs", default=None, help="run directories (default runs/thesis-<preset>[-precise])")
    p.add_argument("--out", default=RESULTS, help="where the report goes")
    p.add_argument("--smoke", action="store_true", help="tiny budgets: checks the plumbing, not the numbers")
    p.add_argument("--quiet", action="store_true", help="hide the runs' own output")
    p.add_argument("--jobs", type=positive, default=1,
                   help="seeds of a row run at once, each in its own process (default 1: one after another, "
                   "in this process)")  # fmt: skip
    p.add_argument("--together", action="store_true",
                   help="a row's seeds as one run (--seeds N of its command line: vmapped on a GPU, one compiled "
                   "program looped over the seeds on the CPU)")  # fmt: skip
    p.add_argument("--parallel", type=positive, default=1,
                   help="rows run at once, each its seeds as one run (as --together) in a process of its own "
                   "(default 1: one row after another)")  # fmt: skip
    p.add_argument("--gpus", type=nonnegative, nargs="+", default=None,
                   help="with --parallel: GPU indices the row processes are spread over, one GPU each (default: "
                   "every process sees every visible device)")  # fmt: skip
    p.add_argument("--list", action="store_true", help="print the rows and their commands, run nothing")
    provenance.add_args(p)
    argv = sys.argv[1:] if argv is None else list(argv)
    args = p.parse_args(argv)
    if args.regenerate:
        for path in args.regenerate:
            regenerate(path, args.faithful, args.out)
            print(f"rewrote {path[: -len('.json')]}.md")
        return {}
    if args.variant == "faithful":
        if args.preset not in ("auto", "thesis"):
            p.error(f"--variant faithful runs the thesis preset; --preset {args.preset} contradicts it")
        args.preset = "thesis"
    args.preset = resolve_preset(args.preset)
    try:
        seed_list = bench_seeds.seed_ids(args.purpose, args.seeds, args.first_seed)
    except ValueError as e:
        p.error(f"--seeds/--first-seed: {e}")
    suffix = {"precise": "-precise", "faithful": "-faithful"}.get(args.variant, "")
    args.runs = args.runs or os.path.join("runs", f"thesis-{args.preset}{suffix}")
    rows = select(args.tables, args.rows, args.variant)
    if not rows:
        raise SystemExit(f"error: --rows {args.rows} matches no row of tables {args.tables or 'all'}; see --list")
    if args.parallel < 1:
        raise SystemExit(f"error: --parallel {args.parallel} is out of range; allowed >= 1")
    if args.parallel > 1 and args.jobs > 1:
        raise SystemExit("error: --parallel and --jobs exclude each other; --parallel runs each row's seeds as one run")
    if args.gpus and args.parallel == 1:
        raise SystemExit("error: --gpus needs --parallel > 1")
    if args.parallel > 1 or args.jobs > 1:  # the runs are other processes: this one keeps the device's memory free
        os.environ.setdefault("XLA_PYTHON_CLIENT_PREALLOCATE", "false")
    args.together = args.together or args.parallel > 1
    console = Console(stderr=True)
    if args.list:
        for r in rows:
            flags = " ".join(command(r, args.preset, seed_list[0], args.smoke))
            cmd = f"python -m train.{r.algo} {flags}" if r.algo else f"missing: {r.missing}"
            print(f"{r.id:24s} {r.label}: {cmd}")
        return {}
    prov = provenance.record("benchmarks.thesis", argv, seeds=bench_seeds.record(args.purpose, seed_list,
                             "each row's train.<algo> --seed k"), allow_dirty=args.allow_dirty,
                             run_directories=f"{args.runs}; each seed's eval.json, config.json and provenance.json "
                             "kept under runs/")  # fmt: skip
    faithful = args.faithful or sorted(p for p in glob.glob(os.path.join(args.out, f"thesis-{device_label()}-thesis-"
                                                                          "faithful*.json")) if "-smoke" not in p)
    meta = {"device": device_label(), "preset": args.preset, "variant": args.variant, "seeds": args.seeds,
            "purpose": args.purpose, "seed_ids": seed_list,
            "smoke": args.smoke, "together": args.together, "parallel": args.parallel,
            "command": "python -m benchmarks.thesis " + " ".join(argv), "jax": jax.__version__,
            "commit": prov["commit"][:12], "date": time.strftime("%Y-%m-%d %H:%M"), "provenance": prov,
            **({"faithful": faithful} if args.variant != "faithful" and load_faithful(faithful) else {})}  # fmt: skip
    stem = os.path.join(args.out, f"thesis-{device_label()}-{args.preset}{suffix}" + ("-smoke" if args.smoke else ""))
    if args.jobs < 1:
        raise SystemExit(f"error: --jobs {args.jobs} is out of range; allowed >= 1")
    seeds = seed_list
    size = len(seeds) if args.together else args.jobs
    # rows run in the order of --tables; the report keeps the thesis's order
    order = {t: k for k, t in enumerate(args.tables or [])}
    runnable = sorted((r for r in rows if r.algo), key=lambda r: order.get(r.table, 0))
    jobs = [(r, seeds[i : i + size]) for r in runnable for i in range(0, len(seeds), size)]
    t_start, ran, spent = time.perf_counter(), 0, 0.0
    by_row: dict[str, list[dict]] = {r.id: [] for r in rows}

    def finished(i: int, row: Row, group: list[int], got_all: list[dict]) -> None:
        """Keep a finished job's records and runs; the report so far once its row is done."""
        for seed, got in zip(group, got_all, strict=True):
            if "error" in got:
                console.print(f"  [red]{row.id} seed {seed}: {got['error']}[/red]")
            elif not got.get("skipped"):  # ran now: its commit and tree are this invocation's
                got["provenance"] = mark_ran(got["run_dir"], prov)
            by_row[row.id].append(got)
            if got.get("run_dir") and not args.smoke:
                provenance.keep_run(got["run_dir"], stem, os.path.relpath(got["run_dir"], args.runs))
        if len(by_row[row.id]) == args.seeds and i + 1 < len(jobs):
            report(collect(rows, by_row, args, meta, t_start), meta, stem)

    if args.parallel > 1:
        slots: queue.Queue = queue.Queue()
        for k in range(args.parallel):
            slots.put(k)
        console.print(f"{len(jobs)} rows, {args.parallel} at once" + (f" over GPUs {args.gpus}" if args.gpus else ""))
        with ThreadPoolExecutor(args.parallel) as pool:
            futures = {pool.submit(run_row_process, row, group, args, slots): (row, group) for row, group in jobs}
            for i, future in enumerate(as_completed(futures)):
                row, group = futures[future]
                got_all = future.result()
                ran += not all(got.get("skipped") for got in got_all)  # rows found finished take no time
                took, left = time.perf_counter() - t_start, len(jobs) - i - 1
                eta = f", ETA {took / ran * left / 60:.0f} min" if left and ran else ""
                console.print(f"[bold][{i + 1}/{len(jobs)}][/bold] {row.id} done — {row.label} "
                              f"({took / 60:.1f} min in{eta})")  # fmt: skip
                finished(i, row, group, got_all)
    else:
        for i, (row, group) in enumerate(jobs):
            eta = f", ETA {spent / ran * (len(jobs) - i) / 60:.0f} min" if ran else ""
            which = f"seed {group[0]}" if len(group) == 1 else f"seeds {group[0]}-{group[-1]}"
            console.print(f"[bold][{i + 1}/{len(jobs)}][/bold] {row.id} {which} — {row.label}{eta}")
            t0 = time.perf_counter()
            if args.together:
                got_all = run_seeds_together(row, group, args)
            else:
                got_all = run_seeds_apart(row, group, args) if args.jobs > 1 else [run_seed(row, group[0], args)]
            if not all(got.get("skipped") for got in got_all):
                ran, spent = ran + 1, spent + time.perf_counter() - t0
            finished(i, row, group, got_all)
    results = collect(rows, by_row, args, meta, t_start)
    report(results, meta, stem)
    console.print(f"report: {stem}.md")
    return {"meta": meta, "rows": results, "stem": stem}


_DEVIATIONS: dict[tuple[str, str], dict[str, Any]] = {}
"""Deviations per (row id, run directory) computed so far in this process (a report is rewritten after every row)."""


def row_deviations(row: Row, seeds: list[dict], preset: str) -> dict[str, Any] | None:
    """The row's deviations from the thesis's setting (:func:`benchmarks.deviations.row_deviations`) from the
    ``config.json`` of its first finished seed; None before one finished."""
    done = [s for s in seeds if "error" not in s and s.get("run_dir")]
    if not done or not row.algo:
        return None
    key = (row.id, done[0]["run_dir"])
    if key not in _DEVIATIONS:
        path = os.path.join(done[0]["run_dir"], "config.json")
        config = json.load(open(path)) if os.path.exists(path) else None
        _DEVIATIONS[key] = deviations.row_deviations(row.algo, row.argv, row.kind, config, preset)
    return _DEVIATIONS[key]


def collect(rows: list[Row], by_row: dict[str, list[dict]], args: argparse.Namespace, meta: dict,
            t_start: float) -> list[dict]:  # fmt: skip
    """Every row's seeds so far, its figure, provenance (:func:`row_provenance`) and deviations from the thesis's
    setting (not for ``--smoke``); sets ``meta``'s wall times."""
    meta["wall_s"] = time.perf_counter() - t_start
    first = meta["seed_ids"][0]
    results = [{"row": dataclasses.asdict(r), "command": command(r, args.preset, first, args.smoke) if r.algo else [],
                "seeds": by_row[r.id], "figure": row_figure(r, by_row[r.id]),
                "provenance": row_provenance(by_row[r.id]),
                "deviations": None if args.smoke else row_deviations(r, by_row[r.id], args.preset)}
               for r in rows]  # fmt: skip
    meta["runs_wall_s"] = float(sum(r["figure"].get("wall_s", 0.0) for r in results))
    return results


if __name__ == "__main__":
    main()
