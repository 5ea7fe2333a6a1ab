"""Rewrite results files' markdown from their ``.json`` with the code at hand (nothing runs, nothing is measured).

    python -m benchmarks.regenerate benchmarks/results/gpu-nvidia_h200-brax_tasks-5M-segments.json ...
    python -m benchmarks.regenerate --all          # every file of benchmarks/results/ this can rewrite

A report generator that gains a column (the seeds' confidence intervals of ``brax_tasks``, the deviations
and per-step errors of ``thesis`` and the tracking benchmarks) applies it to the files written before. The
``.json`` is left as it is (its provenance records keep their wall times); figures are not redrawn. Files
of a shape the generators do not write (sweeps assembled by hand, several reports in one file) are skipped
and named.
"""

from __future__ import annotations

import argparse
import glob
import json
import os
from collections.abc import Sequence
from typing import Any

from benchmarks import provenance
from benchmarks.train_throughput import RESULTS


def kind(result: dict[str, Any]) -> str | None:
    """Which generator wrote ``result``: ``brax_tasks``, ``thesis``, ``ppo_tracking``, ``ddpg_tracking``, or
    None (a shape none of them writes)."""
    if "provenance" not in result:
        return None
    if result.get("benchmark") == "brax_tasks" and "tasks" in result:
        return "brax_tasks"
    if "meta" in result and "rows" in result and "variant" in result["meta"]:
        return "thesis"
    if result.get("benchmark") in ("ppo_tracking", "ddpg_tracking") and "runs" in result:
        return result["benchmark"]
    return None


def brax_tasks_markdown(result: dict[str, Any]) -> str:
    """``brax_tasks``' table of a saved ``result`` (sides that did not run shown as such, as its writer does)."""
    from benchmarks import brax_tasks

    shown = dict(result, tasks=[])
    for row in result["tasks"]:
        shown_row = dict(row)
        for side, other in (("ours", "brax"), ("brax", "ours")):
            if side not in row:
                shown_row[side] = brax_tasks.missing(row[other])
        shown["tasks"].append(shown_row)
    return brax_tasks.to_markdown(shown)


def rewrite(path: str, results: str = RESULTS) -> str | None:
    """Rewrite ``path``'s markdown (``.json`` -> ``.md``); returns the kind rewritten, None where skipped."""
    with open(path) as f:
        result = json.load(f)
    what = kind(result) if isinstance(result, dict) else None
    stem = path[: -len(".json")]
    if what == "brax_tasks":
        provenance.rewrite_markdown(stem, result, brax_tasks_markdown(result), earlier=result.get("sources", []))
    elif what == "thesis":
        from benchmarks import thesis

        thesis.regenerate(path, results=results)
    elif what in ("ppo_tracking", "ddpg_tracking"):
        from benchmarks import ddpg_tracking, ppo_tracking

        module = ppo_tracking if what == "ppo_tracking" else ddpg_tracking
        provenance.rewrite_markdown(stem, result, module.to_markdown(result))
    return what


def main(argv: Sequence[str] | None = None) -> int:
    p = argparse.ArgumentParser(prog="python -m benchmarks.regenerate", description=__doc__.split("\n")[0])
    p.add_argument("paths", nargs="*", metavar="JSON")
    p.add_argument("--all", action="store_true", help=f"every .json of {RESULTS}")
    args = p.parse_args(argv)
    paths = sorted(glob.glob(os.path.join(RESULTS, "*.json"))) if args.all else args.paths
    if not paths:
        p.error("give results files (.json) or --all")
    for path in paths:
        what = rewrite(path)
        print(f"{'rewrote' if what else 'skipped'} {os.path.basename(path)}" + (f" ({what})" if what else ""))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
