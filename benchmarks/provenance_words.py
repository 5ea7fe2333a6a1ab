"""How a provenance record reads in a report: the tree, the device, the seeds, and the markdown of several."""

from __future__ import annotations

from typing import Any


def tree_words(prov: dict[str, Any]) -> str:
    """``clean tree``, ``DIRTY tree: uncommitted edits in …`` or ``tree state unknown (…)``."""
    if prov.get("dirty") is None:
        return f"tree state unknown ({prov.get('commit_source', 'not recorded')})"
    if not prov["dirty"]:
        return "clean tree"
    listed = prov.get("dirty_files", [])
    more = prov.get("dirty_count", len(listed)) - 8
    files = ", ".join(line[3:] for line in listed[:8]) + (f" and {more} more" if more > 0 else "")
    kept = "; the diff is in the .json" if prov.get("diff") else ""
    return (f"**DIRTY tree: uncommitted edits** in {files} (diff sha1 {prov.get('diff_sha1')}{kept}): the figures "
            "come from code that this commit alone does not hold")  # fmt: skip


def device_words(dev: Any) -> str:
    if not isinstance(dev, dict):
        return str(dev)
    count = f"{dev['count']} x " if dev.get("count", 1) != 1 else ""
    cores = f", {dev['cpu_cores']} CPU cores" if dev.get("cpu_cores") else ""
    return f"{count}{dev['name']} ({dev['platform']}{cores})"


def seed_words(entry: Any) -> str:
    """A record's ``seeds`` in words (:func:`benchmarks.seeds.words`)."""
    from benchmarks.seeds import words

    return words(entry)


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
            *([f"- Tree: code SHA-1 {p['tree_sha1']}, read from {p['commit_source']}"] if p.get("tree_sha1") else []),
            f"- Device: {device_words(p['device'])}; host {p.get('host', '?')}",
            f"- Seeds: {'none (not a seeded experiment)' if seeds is None else seed_words(seeds)}",
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
