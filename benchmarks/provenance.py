"""Where a results file came from: the command as run, the commit (and whether the tree was clean),
the device, the seeds, the wall time and the date — one record, written into the ``.json`` and the
``.md`` of every benchmark (:func:`write`).

    prov = provenance.record("benchmarks.racing", argv, seeds="3 keys split from PRNGKey(0)",
                             commit=args.commit)
    ...  # the run
    provenance.write(stem, {"provenance": prov, **result}, markdown)

A run from a tree with uncommitted edits is recorded as such (``dirty: true`` and the edited
files, ``diff_sha1`` of ``git diff HEAD``): its figures come from code no commit holds.  Where the
benchmark ran without a git checkout (a copy of the working tree on another machine) the commit
is the one given with ``--commit`` and the tree's state is ``null``: unknown, and said so.

The run directories behind a results file (their small ``eval.json`` and ``config.json``) are kept
under ``<results>/runs/<results file>/`` by :func:`keep_run`.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import platform
import shlex
import shutil
import subprocess
import sys
import time
from collections.abc import Sequence
from typing import Any

REPO = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
RUN_FILES = ("eval.json", "config.json")
"""The files of a run directory that :func:`keep_run` copies beside the results."""
MAX_KEPT_BYTES = 100_000


def add_args(p: argparse.ArgumentParser) -> None:
    """``--commit``: the commit to record where the benchmark runs without a git checkout."""
    p.add_argument("--commit", default="", help="commit to record when no git checkout is at hand (default: HEAD)")


def command(module: str, argv: Sequence[str] | None = None) -> str:
    """The command line as run: ``python -m <module> <argv>`` (``argv`` default ``sys.argv[1:]``), quoted."""
    return " ".join(["python -m", module, shlex.join(sys.argv[1:] if argv is None else list(argv))]).strip()


def _git(*args: str, cwd: str) -> str | None:
    try:
        out = subprocess.run(["git", *args], cwd=cwd, capture_output=True, text=True, timeout=30)
    except (OSError, subprocess.TimeoutExpired):
        return None
    return out.stdout if out.returncode == 0 else None


def git_state(cwd: str | None = None, commit: str = "") -> dict[str, Any]:
    """``commit`` (full hash), ``dirty`` (True, False, or None: unknown), ``dirty_files`` (``git status
    --porcelain`` lines, at most 20), ``dirty_count`` (all of them), ``diff_sha1`` (of ``git diff HEAD``)
    and ``commit_source`` of the checkout at ``cwd`` (default :data:`REPO`, the checkout this code is in).

    ``commit`` (given by the caller, e.g. ``--commit``): recorded as given; the tree's state is read
    from ``cwd`` only where its HEAD is that commit, else it is unknown."""
    cwd = cwd or REPO
    head = (_git("rev-parse", "HEAD", cwd=cwd) or "").strip()
    if commit and not head.startswith(commit):
        return {"commit": commit, "dirty": None, "dirty_files": [], "diff_sha1": None,
                "commit_source": "given with --commit; the tree it ran from was not checked"}  # fmt: skip
    if not head:
        return {"commit": "unknown", "dirty": None, "dirty_files": [], "diff_sha1": None,
                "commit_source": "no git checkout where it ran and no --commit"}  # fmt: skip
    status = [line for line in (_git("status", "--porcelain", cwd=cwd) or "").splitlines() if line.strip()]
    diff = _git("diff", "HEAD", cwd=cwd) or ""
    return {"commit": head, "dirty": bool(status), "dirty_files": status[:20], "dirty_count": len(status),
            "diff_sha1": hashlib.sha1(diff.encode()).hexdigest() if status else None,
            "commit_source": "git rev-parse HEAD"}  # fmt: skip


def device() -> dict[str, Any]:
    """The accelerator jax sees: ``{"name", "platform", "count", "cpu_cores"}`` (``name``: the device kind)."""
    import jax

    d = jax.devices()[0]
    return {"name": d.device_kind, "platform": d.platform, "count": jax.device_count(), "cpu_cores": os.cpu_count()}


def record(
    module: str,
    argv: Sequence[str] | None = None,
    *,
    seeds: Any = None,
    commit: str = "",
    device_info: dict[str, Any] | None = None,
    **extra: Any,
) -> dict[str, Any]:
    """The provenance of a run starting now (call it before the run: the wall time counts from here).

    ``module``: ``benchmarks.<name>``; ``argv``: its arguments (default ``sys.argv[1:]``); ``seeds``:
    the seeds (a list, or words saying how the keys are made); ``commit``: see :func:`git_state`;
    ``device_info``: the device where jax is not to be asked here (default :func:`device`);
    ``extra``: further fields (``note``; ``run_directories``: where the runs' files are, in words)."""
    import jax

    return {
        "command": command(module, argv),
        **git_state(commit=commit),
        "device": device() if device_info is None else device_info,
        "host": platform.node(),
        "seeds": seeds,
        "jax": jax.__version__,
        "python": platform.python_version(),
        "started": time.strftime("%Y-%m-%d %H:%M:%S %z"),
        "start_time": time.time(),
        "wall_s": 0.0,
        **extra,
    }


def stamp(prov: dict[str, Any]) -> dict[str, Any]:
    """Set ``wall_s`` (since :func:`record`) and ``written`` (now); returns ``prov``."""
    prov["wall_s"] = round(time.time() - prov["start_time"], 1)
    prov["written"] = time.strftime("%Y-%m-%d %H:%M:%S %z")
    return prov


def tree_words(prov: dict[str, Any]) -> str:
    """``clean tree``, ``DIRTY tree: uncommitted edits in …`` or ``tree state unknown (…)``."""
    if prov.get("dirty") is None:
        return f"tree state unknown ({prov.get('commit_source', 'not recorded')})"
    if not prov["dirty"]:
        return "clean tree"
    listed = prov.get("dirty_files", [])
    more = prov.get("dirty_count", len(listed)) - 8
    files = ", ".join(line[3:] for line in listed[:8]) + (f" and {more} more" if more > 0 else "")
    return (f"**DIRTY tree: uncommitted edits** in {files} (diff sha1 {prov.get('diff_sha1')}): the figures come "
            "from code that this commit alone does not hold")  # fmt: skip


def device_words(dev: Any) -> str:
    if not isinstance(dev, dict):
        return str(dev)
    count = f"{dev['count']} x " if dev.get("count", 1) != 1 else ""
    cores = f", {dev['cpu_cores']} CPU cores" if dev.get("cpu_cores") else ""
    return f"{count}{dev['name']} ({dev['platform']}{cores})"


def markdown(*provs: dict[str, Any]) -> str:
    """The ``## Provenance`` section of a results file (one list per record, oldest first)."""
    lines = ["## Provenance", ""]
    for i, p in enumerate(provs):
        if len(provs) > 1:
            lines += [f"Invocation {i + 1} of {len(provs)}:", ""]
        seeds = p.get("seeds")
        lines += [
            f"- Command: `{p['command']}`",
            f"- Commit: {p['commit']} ({tree_words(p)})",
            f"- Device: {device_words(p['device'])}; host {p.get('host', '?')}",
            f"- Seeds: {'none (not a seeded experiment)' if seeds is None else seeds}",
            f"- Wall time: {p['wall_s']:.0f} s from the command's start to this write (started {p['started']}, "
            f"written {p.get('written', '?')})",
            f"- jax {p.get('jax', '?')}, Python {p.get('python', '?')}",
        ]
        lines += [f"- Run directories: {p['run_directories']}"] if p.get("run_directories") else []
        lines += [f"- Note: {p['note']}"] if p.get("note") else []
        lines.append("")
    return "\n".join(lines)


RECOVERED_FIELDS = (
    ("results_commits", "Results committed in"),
    ("command", "Command"),
    ("code_commit", "Code commit"),
    ("device", "Device"),
    ("seeds", "Seeds"),
    ("wall_time", "Wall time"),
    ("selection", "Selection"),
    ("run_directories", "Run directories"),
    ("not_recorded", "Not recorded"),
)
"""The fields of a ``provenance_recovered`` record and their labels, in the order written."""


def recovered_markdown(rec: dict[str, Any]) -> str:
    """The ``## Provenance (recovered from git history)`` section of a results file that was written
    before its benchmark recorded provenance: what the file and its commits' messages say, and what
    they do not (``not_recorded``)."""
    lines = ["## Provenance (recovered from git history)", "", rec.get("intro", ""), ""]
    for key, label in RECOVERED_FIELDS:
        value = rec.get(key)
        if isinstance(value, list) and len(value) > 1:
            lines += [f"- {label}:", *(f"  - {v}" for v in value)]
        elif value:
            lines.append(f"- {label}: " + (value[0] if isinstance(value, list) else str(value)))
    return "\n".join(lines) + "\n"


def _plain(x: Any) -> Any:
    """What ``json`` cannot write as it is: numbers (numpy scalars) as floats, anything else as text."""
    try:
        return float(x)
    except (TypeError, ValueError):
        return str(x)


def write(
    stem: str,
    result: dict[str, Any],
    text: str | None,
    earlier: Sequence[dict[str, Any]] = (),
    echo: bool = False,
) -> str:
    """Write ``stem.json`` (``result``, its ``"provenance"`` stamped with the wall time so far) and, unless
    ``text`` is None, ``stem.md``: ``text``, then :func:`markdown` of ``earlier`` records (rows merged from
    earlier invocations) and of this one.  ``echo`` prints the markdown.  Returns the markdown written."""
    stamp(result["provenance"])
    os.makedirs(os.path.dirname(stem) or ".", exist_ok=True)
    with open(stem + ".json", "w") as f:
        json.dump(result, f, indent=1, default=_plain)
    if text is None:
        return ""
    md = text.rstrip("\n") + "\n\n"
    if result.get("provenance_recovered"):  # rows merged from before provenance was recorded
        md += recovered_markdown(result["provenance_recovered"]) + "\n"
    md += markdown(*earlier, result["provenance"])
    with open(stem + ".md", "w") as f:
        f.write(md)
    if echo:
        print(md)
    return md


def keep_run(run_dir: str, stem: str, name: str | None = None) -> str | None:
    """Copy ``run_dir``'s :data:`RUN_FILES` (each under 100 kB) to ``<dir of stem>/runs/<name of
    stem>/<name>/`` (``name`` default: the name of ``run_dir``, which holds its start time to the second;
    runs that may start in the same second need names of their own); returns that folder (None if none
    was copied)."""
    name = name or os.path.basename(run_dir.rstrip("/"))
    dest = os.path.join(os.path.dirname(stem), "runs", os.path.basename(stem), name)
    copied = 0
    for name in RUN_FILES:
        src = os.path.join(run_dir, name)
        if os.path.isfile(src) and os.path.getsize(src) < MAX_KEPT_BYTES:
            os.makedirs(dest, exist_ok=True)
            shutil.copyfile(src, os.path.join(dest, name))
            copied += 1
    return dest if copied else None
