"""Where a results file came from: the command as run, the commit and whether the tree held edits no
commit holds, the device, the seeds, the wall time and the date — one record, written into the
``.json`` and the ``.md`` of every benchmark (:func:`write`).

    prov = provenance.record("benchmarks.racing", argv, seeds=..., allow_dirty=args.allow_dirty)
    ...  # the run
    provenance.write(stem, {"provenance": prov, **result}, markdown)

The tool takes the tree's state itself, never from the command line (:func:`git_state`):

* a stamp, ``.provenance.json`` at the repository's root, written by ``python -m benchmarks.provenance
  stamp`` in the git checkout before the tree is copied to another machine (a copy whose ``.git`` may be
  stale); it holds the commit, the dirty flag, the diff and the SHA-1 of every file of the tree. It is
  used where it is present and every file of the tree still hashes as it says (ignored by git: carry it
  with the copy);
* else git (``git rev-parse HEAD``, ``git status``, ``git diff HEAD``) in the checkout this code is in.

Files the benchmarks write (``benchmarks/results/``) are outputs, not code: they count neither for the
dirty flag nor for the tree's hashes. A run from a tree with uncommitted edits, or whose state cannot be
read, is refused (:func:`require_clean`) unless ``--allow-dirty`` is given; then its record holds the
edited files, ``diff_sha1`` and the diff itself (``git diff HEAD`` and the new files, up to
:data:`MAX_DIFF_CHARS`).

``python -m benchmarks.provenance check`` prints what a run would record now; ``audit`` lists the results
files whose provenance does not verify (:func:`benchmarks.provenance_audit.audit`).

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

from benchmarks.provenance_words import (  # noqa: F401  (the benchmarks call these as provenance.*)
    RECOVERED_FIELDS,
    device_words,
    markdown,
    recovered_markdown,
    seed_words,
    tree_words,
)

REPO = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
RUN_FILES = ("eval.json", "config.json", "provenance.json")
"""The files of a run directory that :func:`keep_run` copies beside the results."""
MAX_KEPT_BYTES = 100_000
STAMP_NAME = ".provenance.json"
"""The stamp's file name at the repository's root (ignored by git)."""
OUTPUTS = ("benchmarks/results/",)
"""Path prefixes the benchmarks write: outputs, not code (not in the dirty flag, the diff or the tree's hashes)."""
MAX_DIFF_CHARS = 200_000
NOT_RESULTS = ("claims.json",)
"""Files of the results folder that are not results (the index of the figures the READMEs quote)."""
"""The most characters of a dirty tree's diff kept in a record (its SHA-1 is of the whole)."""


def add_args(p: argparse.ArgumentParser) -> None:
    """``--allow-dirty``: run from a tree with uncommitted edits (or of unknown state), recording its diff."""
    p.add_argument("--allow-dirty", action="store_true",
                   help="run although the tree has uncommitted edits or its state cannot be read; the record "
                   "then holds the edited files and the diff (refused otherwise)")  # fmt: skip


def command(module: str, argv: Sequence[str] | None = None) -> str:
    """The command line as run: ``python -m <module> <argv>`` (``argv`` default ``sys.argv[1:]``), quoted."""
    return " ".join(["python -m", module, shlex.join(sys.argv[1:] if argv is None else list(argv))]).strip()


def _git(*args: str, cwd: str) -> str | None:
    try:
        out = subprocess.run(["git", *args], cwd=cwd, capture_output=True, text=True, timeout=30)
    except (OSError, subprocess.TimeoutExpired):
        return None
    return out.stdout if out.returncode == 0 else None


def _is_output(path: str) -> bool:
    return path == STAMP_NAME or any(path.startswith(o) for o in OUTPUTS)


def _code_pathspec() -> list[str]:
    return ["--", ".", *(f":(exclude){o.rstrip('/')}" for o in OUTPUTS), f":(exclude){STAMP_NAME}"]


def tree_files(cwd: str) -> list[str] | None:
    """The code's files at ``cwd``: git's tracked and not-ignored untracked files that exist, outputs
    (:data:`OUTPUTS`) apart, sorted; None where git cannot list them."""
    out = _git("ls-files", "-z", "--cached", "--others", "--exclude-standard", cwd=cwd)
    if out is None:
        return None
    names = {n for n in out.split("\0") if n and not _is_output(n)}
    return sorted(n for n in names if os.path.isfile(os.path.join(cwd, n)))


def file_hashes(cwd: str, names: Sequence[str]) -> dict[str, str]:
    """``{path: SHA-1 of its bytes}`` of ``names`` under ``cwd`` (``"missing"`` for a file not there)."""
    out = {}
    for name in names:
        try:
            with open(os.path.join(cwd, name), "rb") as f:
                out[name] = hashlib.sha1(f.read()).hexdigest()
        except OSError:
            out[name] = "missing"
    return out


def tree_sha1(hashes: dict[str, str]) -> str:
    """One SHA-1 of a tree's ``{path: file SHA-1}`` (order-free)."""
    return hashlib.sha1("".join(f"{k}\0{v}\n" for k, v in sorted(hashes.items())).encode()).hexdigest()


def _untracked_diff(cwd: str) -> str:
    """The new (untracked, not ignored) code files as a diff of their whole text."""
    out = []
    listed = _git("ls-files", "-z", "--others", "--exclude-standard", *_code_pathspec(), cwd=cwd) or ""
    for name in listed.split("\0"):
        if name and os.path.isfile(os.path.join(cwd, name)):
            with open(os.path.join(cwd, name), "rb") as f:
                text = f.read().decode("utf-8", "replace")
            out.append(f"--- /dev/null\n+++ b/{name}\n" + "".join(f"+{line}\n" for line in text.splitlines()))
    return "".join(out)


def from_git(cwd: str) -> dict[str, Any]:
    """The tree's state from git at ``cwd``: ``commit`` (full hash, ``"unknown"`` without a checkout),
    ``dirty`` (True, False, or None: unknown), ``dirty_files`` (``git status --porcelain`` lines of code,
    at most 20), ``dirty_count``, ``diff_sha1`` and ``diff`` (of the code's edits and new files; None when
    clean), ``commit_source``."""
    head = (_git("rev-parse", "HEAD", cwd=cwd) or "").strip()
    if not head:
        return {"commit": "unknown", "dirty": None, "dirty_files": [], "dirty_count": 0, "diff_sha1": None,
                "diff": None, "commit_source": "no git checkout where it ran and no matching stamp"}  # fmt: skip
    status = (_git("status", "--porcelain", *_code_pathspec(), cwd=cwd) or "").splitlines()
    status = [line for line in status if line.strip()]
    diff = ((_git("diff", "HEAD", *_code_pathspec(), cwd=cwd) or "") + _untracked_diff(cwd)) if status else ""
    return {"commit": head, "dirty": bool(status), "dirty_files": status[:20], "dirty_count": len(status),
            "diff_sha1": hashlib.sha1(diff.encode()).hexdigest() if status else None,
            "diff": diff or None, "commit_source": "git rev-parse HEAD"}  # fmt: skip


def read_stamp(cwd: str) -> dict[str, Any] | None:
    """The stamp at ``cwd`` (None where there is none, or it does not read as one)."""
    try:
        with open(os.path.join(cwd, STAMP_NAME)) as f:
            stamp = json.load(f)
    except (OSError, ValueError):
        return None
    return stamp if isinstance(stamp, dict) and isinstance(stamp.get("files"), dict) else None


def stamp_differences(stamp: dict[str, Any], cwd: str) -> list[str]:
    """The files whose bytes differ from ``stamp``'s (added, removed or changed since), sorted; [] when
    the tree is the stamped one. Where git cannot list the tree, the stamp's own files are compared."""
    names = tree_files(cwd)
    listed = set(stamp["files"]) | set(names if names is not None else ())
    now = file_hashes(cwd, sorted(listed))
    return sorted(n for n in listed if now[n] != stamp["files"].get(n, "missing"))


def write_stamp(cwd: str | None = None) -> dict[str, Any]:
    """Write the stamp of the checkout at ``cwd`` (default :data:`REPO`) from git: its state
    (:func:`from_git`), the SHA-1 of every file of the code and the time; returns it."""
    cwd = cwd or REPO
    state = from_git(cwd)
    names = tree_files(cwd)
    if state["commit"] == "unknown" or names is None:
        raise SystemExit(f"error: {cwd} is not a git checkout; stamp the tree where its .git is")
    hashes = file_hashes(cwd, names)
    stamp = {**state, "commit_source": "git rev-parse HEAD where the tree was stamped", "tree_sha1": tree_sha1(hashes),
             "stamped": time.strftime("%Y-%m-%d %H:%M:%S %z"), "host": platform.node(), "files": hashes}  # fmt: skip
    with open(os.path.join(cwd, STAMP_NAME), "w") as f:
        json.dump(stamp, f, indent=1)
    return stamp


def git_state(cwd: str | None = None) -> dict[str, Any]:
    """The state of the tree at ``cwd`` (default :data:`REPO`): from its stamp where every file still
    matches it, else from git (:func:`from_git`); ``tree_sha1`` of the code's files either way (None
    where git cannot list them). A stamp that no longer matches is named in ``stamp_note``."""
    cwd = cwd or REPO
    stamp = read_stamp(cwd)
    differ = stamp_differences(stamp, cwd) if stamp else []
    if stamp and not differ:
        keep = ("commit", "dirty", "dirty_files", "dirty_count", "diff_sha1", "diff", "tree_sha1")
        return {**{k: stamp.get(k) for k in keep},
                "commit_source": f"stamp {STAMP_NAME} of {stamp.get('stamped', '?')} (every file matches it)"}
    state = from_git(cwd)
    names = tree_files(cwd)
    state["tree_sha1"] = tree_sha1(file_hashes(cwd, names)) if names is not None else None
    if stamp:
        more = f" and {len(differ) - 3} more" if len(differ) > 3 else ""
        state["stamp_note"] = f"{STAMP_NAME} does not match the tree ({', '.join(differ[:3])}{more} differ): not used"
    return state


def require_clean(state: dict[str, Any], allow_dirty: bool) -> None:
    """Refuse (``SystemExit`` with one line) a tree with uncommitted edits or of unknown state, unless
    ``allow_dirty``."""
    if allow_dirty or state["dirty"] is False:
        return
    if state["dirty"] is None:
        note = f"; {state['stamp_note']}" if state.get("stamp_note") else ""
        raise SystemExit(f"error: the tree's state cannot be read ({state['commit_source']}{note}); run `python -m "
                         "benchmarks.provenance stamp` in the checkout and copy .provenance.json with the tree, "
                         "or pass --allow-dirty to record the run as unverified")  # fmt: skip
    files = ", ".join(line[3:] for line in state["dirty_files"][:5])
    more = state.get("dirty_count", 0) - 5
    raise SystemExit(f"error: the tree has uncommitted edits ({files}{f' and {more} more' if more > 0 else ''}); "
                     "commit them, or pass --allow-dirty to record the run with its diff")  # fmt: skip


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
    allow_dirty: bool = False,
    device_info: dict[str, Any] | None = None,
    cwd: str | None = None,
    **extra: Any,
) -> dict[str, Any]:
    """The provenance of a run starting now (call it before the run: the wall time counts from here).

    ``module``: ``benchmarks.<name>``; ``argv``: its arguments (default ``sys.argv[1:]``); ``seeds``:
    the seeds (a list, or words saying how the keys are made; :func:`benchmarks.seeds.record`);
    ``allow_dirty``: record a tree with edits or of unknown state instead of refusing it
    (:func:`require_clean`); ``device_info``: the device where jax is not to be asked here (default
    :func:`device`); ``cwd``: the checkout (default :data:`REPO`); ``extra``: further fields (``note``;
    ``run_directories``: where the runs' files are, in words).

    Raises:
      SystemExit: the tree has uncommitted edits or its state cannot be read, and not ``allow_dirty``.
    """
    import jax

    state = git_state(cwd)
    require_clean(state, allow_dirty)
    diff = state.pop("diff", None)
    if diff:
        state["diff"] = diff[:MAX_DIFF_CHARS]
        state["diff_truncated"] = len(diff) > MAX_DIFF_CHARS
    return {
        "command": command(module, argv),
        **state,
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


def rewrite_markdown(stem: str, result: dict[str, Any], text: str, earlier: Sequence[dict[str, Any]] = ()) -> str:
    """Write ``stem.md`` anew from a results file's ``result`` (as read from ``stem.json``, left as it is):
    ``text``, then its provenance sections as :func:`write` writes them (the records unchanged, the wall
    times those they hold). Returns the markdown."""
    md = text.rstrip("\n") + "\n\n"
    if result.get("provenance_recovered"):
        md += recovered_markdown(result["provenance_recovered"]) + "\n"
    md += markdown(*earlier, result["provenance"])
    with open(stem + ".md", "w") as f:
        f.write(md)
    return md


def main(argv: Sequence[str] | None = None) -> int:
    """``python -m benchmarks.provenance stamp|check|audit``."""
    p = argparse.ArgumentParser(prog="python -m benchmarks.provenance", description=__doc__.split("\n")[0])
    sub = p.add_subparsers(dest="what", required=True)
    sub.add_parser("stamp", help=f"write {STAMP_NAME}: the commit, dirty flag, diff and file hashes of this tree")
    sub.add_parser("check", help="print the state a benchmark run would record now, and whether it would run")
    a = sub.add_parser("audit", help="list the results files whose provenance does not verify")
    a.add_argument("--results", default=os.path.join(REPO, "benchmarks", "results"))
    a.add_argument("--history", action="store_true", help="also check that each commit is in this repository")
    args = p.parse_args(argv)
    if args.what == "stamp":
        s = write_stamp()
        print(f"{STAMP_NAME}: commit {s['commit']}, {tree_words(s)}, {len(s['files'])} files (tree {s['tree_sha1']})")
    elif args.what == "check":
        s = git_state()
        print(f"commit {s['commit']} ({tree_words(s)}); read from {s['commit_source']}; tree {s['tree_sha1']}")
        if s.get("stamp_note"):
            print(s["stamp_note"])
        print("a run would be refused without --allow-dirty" if s["dirty"] is not False else "a run would go ahead")
    else:
        from benchmarks.provenance_audit import audit  # it reads this module's settings

        for name, reasons in audit(args.results, args.history).items():
            print(f"{name}: {'; '.join(reasons)}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
