"""What the tracking-error benchmarks (``ppo_tracking``, ``ddpg_tracking``) share.

Each case trains several seeds of one method on one reference and runs every agent's test
episode from ``t = 0`` (``envs_mjx.tracking.rollout``).  The metric is the thesis's: per axis
the sum over the test episode of |reference − real| (x, y in m; θ in rad or z in m).  A case
becomes one dict (:func:`summarise`), a run of cases one results file (:func:`to_markdown`,
written after every case by :func:`run_cases` so that a cut-short run keeps its rows).
"""

from __future__ import annotations

import argparse
import os
import sys
import time
from collections.abc import Callable, Sequence
from typing import Any

import jax
import numpy as np

from benchmarks import provenance
from benchmarks import seeds as bench_seeds
from benchmarks.arguments import nonnegative
from benchmarks.train_throughput import RESULTS, device_label
from train.envs import parse_value

THESIS = {  # (reference, method) -> (x, y, θ or z) sums over the test episode (Tables 4.3-4.5, 5.4-5.7)
    ("scara", "ddpg"): (2.585, 4.210, 5.389),  # Table 4.3
    ("scara", "distributed"): (0.988, 3.944, 2.081),
    ("sine", "ddpg"): (6.578, 3.495, 1.471),  # Table 4.4
    ("sine", "distributed"): (2.592, 2.915, 1.242),
    ("ellipse", "ddpg"): (4.267, 2.533, 5.265),  # Table 4.5
    ("ellipse", "distributed"): (2.837, 2.919, 3.802),
    ("sine", "mlp"): (2.998, 2.961, 1.495),  # Tables 5.4-5.7: distributed PPO, two-stage, PPO + LSTM
    ("sine", "two-stage"): (3.276, 2.293, 1.147),
    ("sine", "lstm"): (3.002, 1.717, 0.942),
    ("ellipse", "mlp"): (3.906, 3.683, 4.451),
    ("ellipse", "two-stage"): (1.857, 3.213, 3.643),
    ("ellipse", "lstm"): (2.374, 2.636, 3.360),
}
"""The thesis's tracking errors; DDPG-family methods are ``ddpg``/``distributed``, PPO ones
``mlp``/``two-stage``/``lstm`` (the thesis ran TD3 only on the racing car)."""

GOAL = {  # half of the thesis's best over all its methods, per axis (Tables 4.3-4.5, 5.4-5.7)
    "scara": (0.49, 1.97, 1.04),
    "sine": (1.30, 0.86, 0.47),
    "ellipse": (0.93, 1.27, 1.68),
}


def pairs(items: Sequence[str]) -> dict[str, Any]:
    """``["KEY=VALUE", ...]`` -> ``{key: value}`` (values parsed as the command lines do; ``-`` in keys -> ``_``)."""
    out = {}
    for item in items:
        if "=" not in item:
            raise SystemExit(f"error: {item!r}: expected KEY=VALUE")
        key, value = item.split("=", 1)
        out[key.strip().replace("-", "_")] = parse_value(value.strip())
    return out


def add_common_args(p: argparse.ArgumentParser) -> None:
    """The options every tracking benchmark has: seeds (:func:`benchmarks.seeds.add_args`), preset, budget,
    overrides, label, ``--allow-dirty``, out."""
    bench_seeds.add_args(p)
    p.add_argument("--preset", default="auto")
    p.add_argument("--total-steps", type=nonnegative, default=0, help="override the preset's budget (0: keep it)")
    p.add_argument("--set", nargs="*", default=[], help="trainer config fields FIELD=VALUE")
    p.add_argument("--env-config", nargs="*", default=[], help="env settings KEY=VALUE")
    p.add_argument("--label", default="", help="names the variant (results file suffix)")
    provenance.add_args(p)
    p.add_argument("--out", default=RESULTS)


def train_seeds(train: Callable, test: Callable, keys: jax.Array, vmapped: bool) -> tuple[Any, Any, float, float]:
    """Compile and run ``train(key) -> (state, metrics)`` for every key, then ``test(state)``.

    ``vmapped``: all keys in one program; otherwise one compiled program run per key.
    Returns ``(test results [S, ...], metrics [S, ...], compile s, train s)`` (host arrays).
    """
    fn = jax.jit(jax.vmap(train) if vmapped else train)
    t0 = time.perf_counter()
    compiled = fn.lower(keys if vmapped else keys[0]).compile()
    compile_s = time.perf_counter() - t0
    t0 = time.perf_counter()
    if vmapped:
        states, metrics = jax.block_until_ready(compiled(keys))
        train_s = time.perf_counter() - t0
        return jax.device_get(jax.jit(jax.vmap(test))(states)), jax.device_get(metrics), compile_s, train_s
    runs = [jax.block_until_ready(compiled(k)) for k in keys]
    train_s = time.perf_counter() - t0
    test = jax.jit(test)
    stack = lambda trees: jax.tree.map(lambda *xs: np.stack(xs), *trees)  # noqa: E731
    return stack([jax.device_get(test(s)) for s, _ in runs]), stack([m for _, m in runs]), compile_s, train_s


def summarise(result: dict, metrics: dict, reward_key: str, **fields: Any) -> dict[str, Any]:
    """One case's dict: ``fields`` plus the per-seed sums ``[S, 3]``, their mean, std and median, test steps,
    the mean |error| per step (mean over seeds of each seed's sums over its steps) and the last chunk's
    ``metrics[reward_key]`` per seed."""
    sums = np.asarray(result["sum_abs_error"])
    steps = np.asarray(result["steps"], float).reshape(len(sums))
    return {
        **fields,
        "sums": sums.tolist(),
        "steps": steps.tolist(),
        "per_step": (sums / steps[:, None]).mean(axis=0).tolist(),
        "mean": sums.mean(axis=0).tolist(),
        "std": sums.std(axis=0).tolist(),
        "median": np.median(sums, axis=0).tolist(),
        "final_reward": np.asarray(metrics[reward_key])[:, -1].tolist(),
    }


THESIS_ROWS = {("scara", "ddpg"): ("ddpg", ("--env", "scara")),
               ("scara", "distributed"): ("ddpg", ("--env", "scara", "--distributed")),
               ("scara", "td3"): ("td3", ("--env", "scara")),
               ("scara", "distributed-td3"): ("td3", ("--env", "scara", "--distributed"))}
"""(reference, method) -> (``train.<algo>``, the row's flags) for :func:`case_deviations`; the unicycle's cases
follow from the reference (:func:`thesis_command`)."""


def thesis_command(reference: str, method: str) -> tuple[str, tuple[str, ...]]:
    """The ``train.<algo>`` and flags of a case's row of the thesis (TD3: the DDPG row with TD3's update)."""
    if (reference, method) in THESIS_ROWS:
        return THESIS_ROWS[(reference, method)]
    env = ("--env", "unicycle", "--env-config", f"trajectory={reference}")
    extra = {"distributed": ("--distributed",), "distributed-td3": ("--distributed",),
             "two-stage": ("--pretrain", "action-search"), "lstm": ("--policy", "lstm")}.get(method, ())  # fmt: skip
    algo = {"mlp": "ppo", "two-stage": "ppo", "lstm": "ppo", "td3": "td3", "distributed-td3": "td3"}.get(method, "ddpg")
    return algo, (*env, *extra)


def case_deviations(r: dict[str, Any]) -> str:
    """A case's deviations from the thesis's setting in words (:mod:`benchmarks.deviations`): its recorded
    ``algo_config`` and ``env_config`` against the thesis's; ``not recorded`` for a case that kept neither."""
    from benchmarks import deviations

    if "algo_config" not in r or "env_config" not in r:
        return "not recorded (the case kept only part of its config)"
    algo, argv = thesis_command(r["reference"], r["method"])
    thesis_algo, thesis_env = deviations.thesis_setting(algo, argv, "tracking")
    env = deviations.differences(r["env_config"], thesis_env, deviations.IGNORED | deviations.ROW_FIELDS)
    return deviations.words(env, deviations.differences(r["algo_config"], thesis_algo))


def to_markdown(result: dict[str, Any], title: str, intro: str, third: str = "θ") -> str:
    """The results file: ``title``, ``intro``, then per case its row (mean ± std, each seed, the test episode's
    steps and the mean |error| per step) and the thesis's row for the method where the thesis has one
    (``r["thesis"]`` None: no row), then each case's deviations from the thesis's setting; ``third`` names the
    third axis."""
    seeds = (bench_seeds.words(result["provenance"]["seeds"]) if "purpose" in result
             else f"keys split from seed {result['seed']}")  # fmt: skip
    lines = [
        f"# {title} — {result['device']}",
        "",
        f"`{result['command']}` at commit {result['commit']} ({provenance.tree_words(result['provenance'])}; "
        f"jax {result['jax']}, {result['date']}). {intro} "
        f"Seeds: {seeds}; per axis the sum over the test episode from t = 0 of "
        "|error| (x, y m; θ rad or z m), mean ± std over seeds (median), each seed beside, the test episode's "
        "steps and the mean |error| per step; goal: ½ of the thesis's best over all its methods. Bold: at or below "
        "the goal.",
        "",
        f"| reference | method | variant | x | y | {third} | per step x / y / {third} | test steps "
        f"| seeds (x / y / {third}) | env steps | train s (compile s) |",
        "|---|---|---|---:|---:|---:|---|---:|---|---:|---:|",
    ]
    for r in result["runs"]:
        cells = []
        for axis in range(3):
            mean, std = r["mean"][axis], r["std"][axis]
            text = f"{mean:.2f} ± {std:.2f}"
            median = f" ({r['median'][axis]:.2f})" if "median" in r else ""
            cells.append((f"**{text}**" if mean <= r["goal"][axis] else text) + median)
        per_seed = "; ".join(" / ".join(f"{v:.2f}" for v in s) for s in r["sums"])
        steps = np.asarray(r.get("steps", []), float).ravel()
        per_step = r.get("per_step")
        if per_step is None and steps.size == len(r["sums"]):  # written before per_step was kept
            per_step = (np.asarray(r["sums"]) / steps[:, None]).mean(axis=0).tolist()
        step_cell = " / ".join(f"{v:.4f}" for v in per_step) if per_step else "not recorded"
        steps_cell = "/".join(f"{v:.0f}" for v in dict.fromkeys(steps.tolist())) if steps.size else "not recorded"
        lines.append(
            f"| {r['reference']} | {r['method']} | {r['label'] or '-'} | {' | '.join(cells)} | {step_cell} "
            f"| {steps_cell} | {per_seed} | {r['env_steps'] / 1e6:.3g} M | {r['train_s']:.0f} ({r['compile_s']:.0f}) |"
        )
        if r.get("thesis"):
            t = r["thesis"]
            lines.append(f"| {r['reference']} | thesis {r['method']} | | {t[0]} | {t[1]} | {t[2]} | | | | | |")
    lines += ["", "Deviations from the thesis's setting (the thesis's value → ours; the `thesis` preset and the "
              "thesis's plant are the reference, `benchmarks/deviations.py`):", ""]  # fmt: skip
    lines += [f"- {r['reference']} {r['method']}{' ' + r['label'] if r['label'] else ''}: {case_deviations(r)}"
              for r in result["runs"]]  # fmt: skip
    lines.append("")
    return "\n".join(lines)


def run_cases(
    name: str,
    args: argparse.Namespace,
    argv: Sequence[str],
    cases: Sequence[tuple[str, str]],
    run_case: Callable[[str, str, argparse.Namespace], dict],
    markdown: Callable[[dict], str],
) -> dict[str, Any]:
    """Run ``run_case(reference, method, args)`` for every case; write ``<device>-<name>[-label]``
    (json and markdown) under ``args.out`` after each.  Returns the whole result."""
    args.seed_ids = bench_seeds.seed_ids(args.purpose, args.seeds, args.first_seed)
    seeds = bench_seeds.record(args.purpose, args.seed_ids)
    prov = provenance.record(f"benchmarks.{name}", argv, seeds=seeds, allow_dirty=args.allow_dirty)
    result = {
        "benchmark": name,
        "provenance": prov,
        "device": device_label(),
        "preset": args.preset,
        "purpose": args.purpose,
        "seed_ids": args.seed_ids,
        "command": prov["command"],
        "commit": prov["commit"],
        "jax": jax.__version__,
        "date": time.strftime("%Y-%m-%d"),
        "runs": [],
    }
    stem = os.path.join(args.out, f"{device_label()}-{name}" + (f"-{args.label}" if args.label else ""))
    for reference, method in cases:
        result["runs"].append(run_case(reference, method, args))
        provenance.write(stem, result, markdown(result), echo=True)
    return result


def cli(
    name: str,
    doc: str,
    references: tuple[str, Sequence[str]],
    methods: tuple[Sequence[str], Sequence[str]],
    run_case: Callable[[str, str, argparse.Namespace], dict],
    markdown: Callable[[dict], str],
    argv: Sequence[str] | None = None,
    extra_args: Callable[[argparse.ArgumentParser], None] | None = None,
) -> dict[str, Any]:
    """The command line of a tracking benchmark: ``--<references[0]>`` (choices ``references[1]``,
    all by default), ``--methods`` (choices ``methods[1]``, default ``methods[0]``),
    :func:`add_common_args` and the benchmark's own ``extra_args(parser)``; runs every (reference,
    method) case with :func:`run_cases`."""
    from train.presets import resolve_preset

    flag, choices = references
    p = argparse.ArgumentParser(description=doc.split("\n")[0])
    p.add_argument(f"--{flag}", nargs="+", default=list(choices), choices=list(choices))
    p.add_argument("--methods", nargs="+", default=list(methods[0]), choices=list(methods[1]))
    add_common_args(p)
    if extra_args is not None:
        extra_args(p)
    argv = list(sys.argv[1:] if argv is None else argv)
    args = p.parse_args(argv)
    args.preset = resolve_preset(args.preset)
    try:
        bench_seeds.seed_ids(args.purpose, args.seeds, args.first_seed)
    except ValueError as e:
        p.error(f"--seeds/--first-seed: {e}")
    cases = [(r, m) for r in getattr(args, flag) for m in args.methods]
    return run_cases(name, args, argv, cases, run_case, markdown)
