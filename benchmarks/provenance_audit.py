"""The audit of results files: which ones' provenance does not verify the code they ran
(``python -m benchmarks.provenance audit``)."""

from __future__ import annotations

import glob
import json
import os
from typing import Any

from benchmarks import provenance


def record_problem(p: dict[str, Any]) -> str | None:
    """Why a provenance record does not verify the code it ran (None: a commit read by the tool from a clean
    tree)."""
    if not isinstance(p, dict) or not p.get("commit") or p["commit"] == "unknown":
        return "names no commit"
    if "--commit" in str(p.get("commit_source", "")):
        return "commit typed by hand (--commit); the tree it ran from was not checked"
    if p.get("assembled_by_hand"):
        return "assembled by hand from the runs' files: no tool took the commit the runs ran from"
    if p.get("dirty") is True:
        return "ran from a tree with uncommitted edits"
    if p.get("dirty") is not False:
        return "the tree's state was not recorded"
    return None


def _in_history(commit: str, cwd: str) -> bool:
    return provenance._git("cat-file", "-e", f"{commit}^{{commit}}", cwd=cwd) is not None


def audit_result(result: dict[str, Any], history: bool = False, cwd: str | None = None) -> list[str]:
    """The reasons a results file's figures are not verified by its provenance ([] where they are):
    no record or a record that does not verify (:func:`record_problem`), merged invocations that do not,
    thesis rows taken from earlier invocations with no record of their own, and with ``history`` a commit
    that this repository does not hold."""
    if "invocations" in result and "provenance" not in result:  # a file of several reports, each with its own
        parts = list(result["invocations"].values())
        records = [part.get("provenance") for part in parts]
        rows = [row for part in parts for row in part.get("rows", [])]
    else:
        records, rows = [result.get("provenance")], result.get("rows", [])
        records += list(result.get("sources", []))
    if records == [None]:
        return ["written before the benchmark recorded its provenance (commit and tree from git history, "
                "where at all)" if "provenance_recovered" in result else "names no commit"]  # fmt: skip
    reasons = []
    problems = [problem for problem in map(record_problem, records) if problem]
    if problems:
        what = "; ".join(dict.fromkeys(problems))
        reasons.append(what if len(records) == 1 else f"{len(problems)} of its {len(records)} invocations: {what}")
    rows = [r for r in rows if isinstance(r, dict)]
    earlier = [r for r in rows if any(isinstance(s, dict) and s.get("skipped") for s in r.get("seeds", []))
               and (r.get("provenance") or {}).get("missing", 1)]  # fmt: skip
    if earlier:
        reasons.append(f"{len(earlier)} of its {len(rows)} rows were run by an earlier invocation whose commit the "
                       "file does not record")  # fmt: skip
    unclean = [r for r in rows if r.get("provenance") and not r["provenance"].get("clean", True)]
    if unclean:
        reasons.append(f"{len(unclean)} of its {len(rows)} rows ran from a tree with uncommitted edits")
    if history:
        missing = [r["commit"] for r in records if isinstance(r, dict) and r.get("commit") not in (None, "", "unknown")
                   and not _in_history(r["commit"], cwd or provenance.REPO)]  # fmt: skip
        if missing:
            reasons.append(f"commit {', '.join(dict.fromkeys(missing))} is not in this repository's history")
    return reasons


def audit(results: str, history: bool = False) -> dict[str, list[str]]:
    """``{results file name without .json: reasons}`` for every ``.json`` in ``results`` that does not verify
    (:func:`audit_result`); a file that does not read as JSON is listed as such."""
    out = {}
    for path in sorted(glob.glob(os.path.join(results, "*.json"))):
        if os.path.basename(path) in provenance.NOT_RESULTS:
            continue
        try:
            with open(path) as f:
                result = json.load(f)
        except ValueError as e:
            out[os.path.basename(path)[:-5]] = [f"not readable as JSON ({e})"]
            continue
        reasons = audit_result(result, history) if isinstance(result, dict) else ["not a results record"]
        if reasons:
            out[os.path.basename(path)[:-5]] = reasons
    return out
