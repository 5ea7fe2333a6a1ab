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
import dataclasses
import glob
import json
import os
import queue
import sys
import time
from collections.abc import Sequence
from concurrent.futures import ThreadPoolExecutor, as_completed
from typing import Any

from benchmarks import deviations, provenance
from benchmarks import seeds as bench_seeds
from benchmarks.arguments import nonnegative, positive
from benchmarks.thesis_report import (  # noqa: F401  (read here by the tests)
    header,
    load_faithful,
    regenerate,
    report,
    row_figure,
    runs_wall,
    table_markdown,
)
from benchmarks.thesis_rows import (  # noqa: F401  (read here by the tests)
    ROADS,
    ROWS,
    TABLES,
    VARIANTS,
    Row,
    command,
    faithful_row,
    is_precise,
    precise_row,
)
from benchmarks.thesis_runs import (  # noqa: F401  (read here by the tests)
    mark_ran,
    row_process_env,
    row_provenance,
    run_in_process,
    run_row_process,
    run_seed,
    run_seeds_apart,
    run_seeds_together,
)
from benchmarks.train_throughput import RESULTS, device_label


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
