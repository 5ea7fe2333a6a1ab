"""How :mod:`benchmarks.thesis` runs a row's seeds: in this process, as processes of their own, as one run of
several seeds, or a row per process; a seed's run directory, its record and where it ran from."""

from __future__ import annotations

import argparse
import contextlib
import glob
import importlib
import io
import json
import os
import queue
import subprocess
import sys
import time
from collections.abc import Sequence
from typing import Any

from benchmarks.thesis_rows import (
    Row,
    command,
)


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
