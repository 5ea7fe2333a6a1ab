"""The brax-tasks report: the algorithms and evaluation modes a record names, the markdown table of our side beside
brax's, and one learning-curve figure per task."""

from __future__ import annotations

import os
from typing import Any

import numpy as np

from benchmarks import stats
from jaxrl_robot import plots
from train.presets import BRAX_PPO, BRAX_SAC

ALGOS = {"ppo": ("PPO", "ppo", BRAX_PPO), "td3": ("TD3", "sac", BRAX_SAC), "ddpg": ("DDPG", "sac", BRAX_SAC),
         "sac": ("SAC", "sac", BRAX_SAC)}
"""``--algo``: (our algorithm's name, brax's peer, the table of tasks and settings)."""


PLAYGROUND = "playground:"
"""The prefix of a MuJoCo Playground task (``playground:CartpoleBalance``)."""


def is_playground(task: str) -> bool:
    """Whether ``task`` is a MuJoCo Playground env (``playground:<Name>``) rather than one of brax's."""
    return task.startswith(PLAYGROUND)


EVAL_MODES = ("stochastic", "deterministic")
"""How the final evaluation acts: the policy's sampled actions (brax's default) or its mean action."""


def default_eval_mode(algo: str) -> str:
    """``--eval-mode`` unless given: PPO's sampled actions (brax's default); for TD3 and DDPG, whose only
    policy is deterministic, the mean action on both sides (brax's SAC with ``deterministic_eval``)."""
    return "stochastic" if algo == "ppo" else "deterministic"


def eval_mode(side: dict[str, Any], name: str) -> str:
    """The evaluation mode of a side's record; records without one: ours deterministic, brax's sampled
    (brax's ``deterministic_eval=False`` default, which the peer kept until the mode was recorded)."""
    return side.get("eval_mode", "deterministic" if name == "ours" else "stochastic")


def our_returns(side: dict[str, Any], mode: str) -> list[float] | None:
    """Our returns per seed in evaluation ``mode``, or None where that mode was not measured."""
    if eval_mode(side, "ours") == mode:
        return side["returns"]
    return side.get("returns_deterministic") if mode == "deterministic" else None


def training_wall_per_seed(side: dict[str, Any]) -> float | None:
    """A side's training wall per seed with compilation apart: the seconds from its second evaluation to its
    last (every program compiled by then: training and the last evaluation), scaled to all its env steps and
    divided among the seeds of one program (``seeds_per_program``: ours vmapped, 1 for a seed alone), averaged
    over the programs that kept their times (``curve_wall_s``: per program the seconds since its start at each
    evaluation, None for a program whose times were not recorded). None where no program has times, there
    are fewer than three evaluations, or the run was cut short."""
    walls, steps = [w for w in side.get("curve_wall_s") or [] if w is not None], side.get("curve_steps") or []
    if not walls or len(steps) < 3 or side.get("cut") or any(len(w) != len(steps) for w in walls):
        return None
    scale = side["env_steps"] / (steps[-1] - steps[1])
    return float(np.mean([(w[-1] - w[1]) * scale for w in walls])) / side.get("seeds_per_program", 1)


def timed_seeds(side: dict[str, Any]) -> tuple[int, int]:
    """(seeds whose evaluation times were recorded, seeds) of a side: the seeds :func:`training_wall_per_seed`
    speaks for."""
    per = side.get("seeds_per_program", 1)
    timed = sum(w is not None for w in side.get("curve_wall_s") or []) * per
    return timed, len(side.get("returns") or [])


def brax_seed_words(result: dict[str, Any]) -> str:
    """How many seeds brax's side ran: the invocation's count, or the range over a merged report's rows."""
    counts = sorted({len(t["brax"]["returns"]) for t in result["tasks"] if "brax" in t and t["brax"].get("returns")
                     and not np.isnan(t["brax"]["returns"][0])})  # fmt: skip
    if not result.get("merged_from") or len(counts) < 2:
        return str(result["brax_seeds"])
    return f"{counts[0]}–{counts[-1]} (the row's comparison says how many)"


def apart_cell(side: dict[str, Any]) -> str:
    """A side's wall per seed with compilation apart for the table: "—" without evaluation times, and how many
    seeds it is over where not all of them kept theirs."""
    wall = training_wall_per_seed(side)
    if wall is None:
        return "—"
    timed, seeds = timed_seeds(side)
    return f"{wall:.0f}" + (f" ({timed} of {seeds} seeds)" if timed < seeds else "")


def return_ratio(ours: float, brax: float) -> float:
    """Ours over brax's mean, or brax's over ours where brax's is negative (a cost): above 1 where our mean is
    higher. A ratio of means says nothing of the seeds' spread: whether ours is ahead beyond it is
    :func:`benchmarks.stats.compare`'s verdict, which the report gives beside."""
    if not brax or not ours:
        return float("nan")
    return ours / brax if brax > 0 else brax / ours


def to_markdown(result: dict[str, Any]) -> str:
    name, peer, _ = ALGOS[result.get("algo", "ppo")]
    table = "BRAX_PPO`, ours with the task's fields of `train.presets.BRAX_PPO_TUNED` unless `--ours tuned=false" \
        if peer == "ppo" else "BRAX_SAC"
    source = f"`train.presets.{table}`"
    pg = [t["task"] for t in result["tasks"] if is_playground(t["task"])]
    if pg:
        source += ("; on MuJoCo Playground's tasks its own `brax_" + ("ppo" if peer == "ppo" else "sac")
                   + "_config` (`train.presets.playground_row`; ours through the same conversion), brax's side on "
                   "the env wrapped by Playground's `wrapper.wrap_for_brax_training` as its training scripts do, "
                   f"Playground config_overrides {result.get('playground_config', {})}")  # fmt: skip
    where = "MuJoCo Playground's tasks" if len(pg) == len(result["tasks"]) else "brax's tasks"
    out = [f"# Our {name} beside brax's {peer.upper()} on {where} — {result['device']}", "",
           f"Backend `{result['backend']}`; {result['seeds']} seeds of ours ({result['seed_map']}), "
           f"{brax_seed_words(result)} of brax's (one after another); the same env steps and settings "
           f"({source}). Return: each side's final evaluation on fresh episodes (ours: "
           f"{result['eval_episodes']} episodes; brax: 128) in the mode its column names — sampled actions "
           "(brax's default) or the mean action; ours also with the mean action; ± the std over seeds. Wall: "
           "compilation included; compile apart: from a side's second evaluation to its last, scaled to all its env "
           "steps, per seed (`training_wall_per_seed`; — where the record has no evaluation times; over the seeds "
           "that have them where a merge joined seeds run before times were recorded). "
           "Ours against brax's: the difference of the means with its 95 % confidence "
           "interval (Welch's t) and Mann–Whitney's two-sided p, seeds per side; **ahead** / behind only where the "
           "interval excludes 0, else level (`benchmarks/stats.py`). Bold: ahead in the same mode; our wall per "
           "seed ≤ brax's."
           + (f" Merged from {len(result['sources'])} invocations (`--merge`; each one's provenance below)."
              if result.get("merged_from") else ""), "",
           "| task | env steps | brax return | our return, same mode | our return, mean action "
           "| ours − brax, same mode (95 % CI; Welch), Mann–Whitney p, seeds ours vs brax "
           "| brax wall per seed s | our wall per seed s | compile apart, brax / ours s | brax env steps/s "
           "| our env steps/s | ratio of the means |",
           "|---|---:|---:|---:|---:|---|---:|---:|---:|---:|---:|---:|"]  # fmt: skip
    words = {"stochastic": "sampled", "deterministic": "mean action"}
    for t in result["tasks"]:
        b, o = t["brax"], t["ours"]
        mode = eval_mode(b, "brax")
        same, mean = our_returns(o, mode), our_returns(o, "deterministic")
        rb, ro = np.mean(b["returns"]), np.mean(same) if same else float("nan")
        whole = not (b.get("cut") or o.get("cut"))  # a side cut short is not compared
        versus = stats.compare(same or [], b["returns"]) if whole else None
        won, fast = whole and versus["verdict"] == "ahead", whole and o["wall_per_seed_s"] <= b["wall_per_seed_s"]
        verdict = stats.words(versus) if versus else "not compared (a side cut short)"
        verdict = verdict.replace("ahead:", "**ahead**:", 1)
        cell = f"{ro:.1f} ± {np.std(same):.1f}" if same else "not measured"
        cut = f" (cut at {o['env_steps']:,} steps)" if o.get("cut") else ""
        cell += cut
        mean_cell = f"{np.mean(mean):.1f} ± {np.std(mean):.1f}{cut}" if mean else "not measured"
        wall = f"{o['wall_per_seed_s']:.0f}"
        asked = b.get("seeds_asked", result["brax_seeds"])  # merged: the seeds its invocations asked for
        short = len(b["returns"]) < asked and not np.isnan(rb)  # a killed run: the seeds it finished
        seeds_done = f" ({len(b['returns'])} of {asked} seeds)" if short else ""
        seeds_done += f" (cut at {b['env_steps']:,} steps)" if b.get("cut") else ""
        mode_word = "" if np.isnan(rb) else f" ({words[mode]})"
        apart = " / ".join(apart_cell(side) for side in (b, o))
        out.append(f"| {t['task']} | {o['env_steps']:,} | {rb:.1f} ± {np.std(b['returns']):.1f}{mode_word}"
                   f"{seeds_done} | {'**' + cell + '**' if won else cell} | {mean_cell} | {verdict} "
                   f"| {b['wall_per_seed_s']:.0f} | {'**' + wall + '**' if fast else wall} | {apart} "
                   f"| {b['env_steps_per_s']:,.0f} | {o['env_steps_per_s']:,.0f} "
                   f"| {return_ratio(ro, rb):.2f} |")  # fmt: skip
    out.append("")
    if result.get("note"):
        out += [result["note"], ""]
    for t in result["tasks"]:
        if t["ours"].get("overrides"):
            given = " ".join(f"{k}={v}" for k, v in t["ours"]["overrides"].items())
            out += [f"Ours on {t['task']} with `--ours {given}` over the preset.", ""]
        if t["ours"].get("devices", 1) > 1:
            out += [f"Ours on {t['task']}: each seed's lanes spread over {t['ours']['devices']} devices.", ""]
    for t in result["tasks"]:
        out.append(f"![{t['task']}]({os.path.basename(result['figures'])}/{t['task'].replace(':', '-')}.png)")
    return "\n".join(out) + "\n"


def figure(task: dict[str, Any], out_dir: str) -> str | None:
    """Each side's evaluations (our records from before evaluations along training: the mean return of
    the training episodes that ended in each chunk), labelled with the mode they were measured in."""
    words = {"stochastic": "sampled actions", "deterministic": "mean action"}
    labels = {"ours": f"ours: evaluations, {words[eval_mode(task['ours'], 'ours')]}"
              if task["ours"].get("curve_kind") == "evaluation" else "ours: training episodes, sampled actions",
              "brax": f"brax: evaluations, {words[eval_mode(task['brax'], 'brax')]}"}  # fmt: skip
    curves = {
        labels[name]: [[{"env_steps": x, "episode_return": y}
                        for x, y in zip(task[name]["curve_steps"], seed, strict=True)]
                       for seed in task[name]["curves"]]
        for name in ("ours", "brax") if task.get(name, {}).get("curves")
    }  # fmt: skip
    name = task["task"].replace(":", "-")  # playground:<Name> → a file name every file system and copy takes
    return plots.plot_seed_bands(curves, "episode_return", out_dir, f"{name}.png", task["task"])
