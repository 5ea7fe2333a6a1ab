"""Results files of :mod:`benchmarks.brax_tasks`: writing one, joining brax's seeds run apart, and merging the files
of several invocations into one report."""

from __future__ import annotations

import json
import os
from collections.abc import Sequence
from typing import Any

from benchmarks import provenance
from benchmarks.brax_tasks_report import ALGOS, eval_mode, figure, to_markdown


def missing(side: dict[str, Any]) -> dict[str, Any]:
    """A side that did not run: NaN returns, no curves, the other side's steps (for the table's columns)."""
    kept = {k: v for k, v in side.items() if k != "cut"}  # the other side's state is not this one's
    return {**kept, "returns": [float("nan")], "returns_deterministic": [float("nan")], "curves": [],
            "overrides": {}, "wall_s": float("nan"),
            "wall_per_seed_s": float("nan"), "env_steps_per_s": float("nan")}  # fmt: skip


def write(stem: str, result: dict[str, Any], earlier: list[dict[str, Any]] = (), echo: bool = False) -> str:
    """The figures of every task and ``stem.json`` / ``stem.md``; a side that did not run shows as NaN."""
    os.makedirs(result["figures"], exist_ok=True)
    shown = dict(result, tasks=[])
    for row in result["tasks"]:
        shown_row = dict(row)
        for side, other in (("ours", "brax"), ("brax", "ours")):
            if side not in row:
                shown_row[side] = missing(row[other])
        figure(shown_row, result["figures"])
        shown["tasks"].append(shown_row)
    return provenance.write(stem, result, to_markdown(shown), earlier=list(earlier), echo=echo)


def join_seeds(a: dict[str, Any], b: dict[str, Any]) -> dict[str, Any]:
    """brax's record of two invocations: the seeds of both when they are different seeds of one setting
    (``seed_ids`` disjoint, same evaluation mode and env steps), else ``b`` (the later file wins). A record
    without ``seed_ids`` ran seeds 0, 1, … (the only seeds before ``--brax-first-seed``). Evaluation times
    (``curve_wall_s``) stay with the seeds that have them: a seed of a file that kept none has None there, and
    the walls with compilation apart are over the timed seeds alone (:func:`timed_seeds` says how many)."""
    ids_a, ids_b = (r.get("seed_ids") or list(range(len(r["returns"]))) for r in (a, b))
    same = eval_mode(a, "brax") == eval_mode(b, "brax") and all(a[k] == b[k] for k in ("env_steps", "curve_steps"))
    if not (ids_a and ids_b and same and not set(ids_a) & set(ids_b)):
        return b
    wall, steps = a["wall_s"] + b["wall_s"], len(ids_a) * a["env_steps"] + len(ids_b) * b["env_steps"]
    asked = {"seeds_asked": a["seeds_asked"] + b["seeds_asked"]} if "seeds_asked" in a and "seeds_asked" in b else {}
    joined = {**b, **asked, "returns": a["returns"] + b["returns"], "curves": a["curves"] + b["curves"],
              "seed_ids": ids_a + ids_b, "wall_s": wall, "wall_per_seed_s": wall / (len(ids_a) + len(ids_b)),
              "env_steps_per_s": steps / wall}  # fmt: skip
    if "curve_wall_s" in a or "curve_wall_s" in b:  # one program a seed: None where a seed's times were not kept
        joined["curve_wall_s"] = [*(a.get("curve_wall_s") or [None] * len(ids_a)),
                                  *(b.get("curve_wall_s") or [None] * len(ids_b))]  # fmt: skip
    return joined


def stem_of(out: str, device: str, algo: str, label: str = "") -> str:
    """``<out>/<device>-brax_tasks[-<algo> unless ppo][-<label>]``: the results files' path without suffix."""
    return f"{out}/{device}-brax_tasks" + ("" if algo == "ppo" else f"-{algo}") + (f"-{label}" if label else "")


def _brax_side_only(part: dict[str, Any]) -> dict[str, Any]:
    """A results file's record with its tasks' brax side alone (``--brax-from``)."""
    tasks = [{"task": t["task"], "settings": t["settings"], "sides": ["brax"], "brax": t["brax"]}
             for t in part["tasks"] if "brax" in t]  # fmt: skip
    return {**part, "tasks": tasks}


def merge(paths: list[str], out: str, argv: list[str] | None = None, label: str = "", note: str = "",
          brax_from: Sequence[str] = ()) -> dict[str, Any]:  # fmt: skip
    """One report of several results files of one algorithm: per task (in the order first seen), our side
    from the last file that ran ours, brax's joined over files of different seeds (:func:`join_seeds`);
    named after the device of the last file that ran ours (each invocation's device is in its provenance);
    their provenance records (a merged file's own sources first) come first in the new file's, then the
    merge's own. ``note``: a paragraph under the table (a part's note is not carried over). ``brax_from``:
    files whose brax side alone is taken (first), e.g. brax's SAC run beside another of our algorithms; their
    brax peer must be the one of ``paths``' algorithm."""
    parts = []
    for path in [*brax_from, *paths]:
        with open(path) as f:
            parts.append(json.load(f))
    algos = {part.get("algo", "ppo") for part in parts[len(brax_from):]}
    if len(algos) != 1:
        raise SystemExit(f"--merge: the files are of different algorithms ({', '.join(sorted(algos))}); give one's")
    peer = ALGOS[next(iter(algos))][1]
    for path, part in zip(brax_from, parts, strict=False):
        if ALGOS[part.get("algo", "ppo")][1] != peer:
            raise SystemExit(f"--brax-from {path}: its brax side is brax's {ALGOS[part.get('algo', 'ppo')][1].upper()}"
                             f", not the {peer.upper()} beside --merge's {next(iter(algos))}")  # fmt: skip
    parts[: len(brax_from)] = [_brax_side_only(part) for part in parts[: len(brax_from)]]
    paths = [*brax_from, *paths]
    first = parts[len(brax_from)]
    tasks: dict[str, dict[str, Any]] = {}
    for part in parts:
        for row in part["tasks"]:
            if "brax" in row:  # the seeds its invocation asked for: fewer returns mean a run cut short
                row["brax"].setdefault("seeds_asked", part["brax_seeds"])
            merged = tasks.setdefault(row["task"], {"task": row["task"], "settings": row["settings"], "sides": []})
            # the sides a row holds (files from before a killed side was listed: the records present)
            for side in row.get("sides") or [name for name in ("ours", "brax") if name in row]:
                joins = side == "brax" and side in merged
                merged[side] = join_seeds(merged[side], row[side]) if joins else row[side]
                merged["sides"] = sorted(set(merged["sides"]) | {side}, reverse=True)
    for part, path in zip(parts, paths, strict=True):
        part["provenance"].setdefault("note", f"merged from {os.path.basename(path)}")
    ran_ours, ran_brax = ([p for p in parts if any(side in (r.get("sides") or r) for r in p["tasks"])]
                          for side in ("ours", "brax"))  # a file's seeds count for the sides it ran
    named = (ran_ours or parts)[-1]  # the file is named after the device our side last ran on
    stem = stem_of(out, named["device"], first.get("algo", "ppo"), label)
    prov = provenance.record("benchmarks.brax_tasks", argv, device_info=named["provenance"]["device"],
                             seeds="as in the invocations above", allow_dirty=True,  # merges figures, measures none
                             note="this file merges the results files of the invocations above")  # fmt: skip
    first = {**{k: v for k, v in first.items() if k != "note"}, "seed_map": (ran_ours or parts)[0]["seed_map"],
             "device": named["device"]}
    sources = [source for p in parts for source in [*p.get("sources", []), p["provenance"]]]
    result = {**first, "tasks": list(tasks.values()), "figures": stem + "-figures", "merged_from": paths,
              "seeds": max(p["seeds"] for p in ran_ours or parts),
              "brax_seeds": max([p["brax_seeds"] for p in ran_brax]
                                + [len(t["brax"]["returns"]) for t in tasks.values() if "brax" in t] or [0]),
              "provenance": prov, "sources": sources, **({"note": note} if note else {})}  # fmt: skip
    write(stem, result, earlier=result["sources"], echo=True)
    return result

