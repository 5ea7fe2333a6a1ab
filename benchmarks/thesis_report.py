"""The report of :mod:`benchmarks.thesis`: each row's figure over seeds beside the thesis's, the tables with their
deviations from the thesis's setting and the faithful column, the summary tables, and the report rewritten from its
JSON (``--regenerate``)."""

from __future__ import annotations

import json
import os
import re
import shutil
from collections.abc import Sequence
from typing import Any

import numpy as np

from benchmarks import deviations, provenance
from benchmarks.thesis_rows import (
    ARM_GOAL,
    PRECISE_GOAL,
    ROADS,
    TITLES,
    Row,
    is_precise,
)
from benchmarks.tracking_report import GOAL
from benchmarks.train_throughput import RESULTS
from jaxrl_robot import plots
from jaxrl_robot.logging import read_csv


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
        shown = " / ".join(f"{v:g}" for v in row["thesis"]) if kind == "tracking" and row["thesis"] else row["thesis"]
        if row["missing"]:
            lines.append(f"| {row['label']} | {shown} | **missing** | {row['missing']} |")
            continue
        if not fig.get("seeds_done"):
            errors = "; ".join(dict.fromkeys(s.get("error", "") for s in r["seeds"]))  # one line for a row's run
            lines.append(f"| {row['label']} | {shown} | **not run** ({errors or 'no seed finished'}) |"
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
