"""The greedy straight-to-goal controller on the arm, with its results file: how often a controller that knows
the goal reaches it, per physics mode, on ``arm7`` (5 cm goal) or ``arm7_precise`` (1 cm).

    python -m benchmarks.arm7_greedy                          # arm7, kinematic and pd, 256 episodes each
    python -m benchmarks.arm7_greedy --env arm7_precise --purpose report

One episode on each of ``--lanes`` lanes per mode (:func:`envs_mjx.demo.make_rollout`: the largest step C allows
along the straight line to the goal), after a compiling first batch on other keys; success, the extra distance
of the successful episodes (path length − straight start-goal distance), steps per episode and control
steps/s. Results: ``benchmarks/results/<device>-<env>_greedy.{json,md}`` with the provenance of
:mod:`benchmarks.provenance` (a tree with uncommitted edits is refused unless ``--allow-dirty``).
"""

from __future__ import annotations

import argparse
import os
from collections.abc import Sequence
from typing import Any

from benchmarks import provenance
from benchmarks import seeds as bench_seeds
from benchmarks.arguments import positive
from benchmarks.train_throughput import RESULTS, device_label

ENVS = ("arm7", "arm7_precise")
MODES = ("kinematic", "pd")


def run(env_name: str, mode: str, lanes: int, seed: int) -> dict[str, float]:
    """The greedy controller's first episode on ``lanes`` lanes of ``env_name`` in ``mode``
    (:func:`envs_mjx.demo.run`)."""
    from envs_mjx import demo

    return demo.run(mode, lanes, seed, env_name)


def to_markdown(result: dict[str, Any]) -> str:
    """The results file's table."""
    lines = [f"# {result['env']}: greedy straight-to-goal controller — {result['device']}", "",
             f"`{result['command']}` at commit {result['commit']} ({provenance.tree_words(result['provenance'])}); "
             f"one episode on each of {result['lanes']} lanes per mode, keys from seed {result['seed']} "
             f"({result['purpose']} range). The action is the largest step C allows along the straight line to the "
             "goal; extra distance = path length − straight start-goal distance (successful episodes); steps/s "
             "after compilation.", "",
             "| mode | episodes reaching the goal | success | extra distance (m) | steps per episode | control steps/s "
             "| compile s |", "|---|---:|---:|---:|---:|---:|---:|"]  # fmt: skip
    for r in result["rows"]:
        lines.append(f"| {r['mode']} | {r['successes']} of {r['episodes']} | {r['success']:.1%} | {r['extra']:.4f} "
                     f"| {r['length']:.1f} | {r['steps_per_s']:,.0f} | {r['compile_s']:.1f} |")  # fmt: skip
    return "\n".join(lines) + "\n"


def main(argv: Sequence[str] | None = None) -> dict[str, Any]:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--env", default="arm7", choices=ENVS)
    p.add_argument("--modes", nargs="+", default=list(MODES), choices=MODES)
    p.add_argument("--lanes", type=positive, default=256, help="episodes per mode")
    p.add_argument("--purpose", default="tune", choices=bench_seeds.PURPOSES,
                   help="the seed's range (benchmarks.seeds): tune (seed 0) or report (the report range's first)")
    p.add_argument("--out", default=RESULTS)
    provenance.add_args(p)
    args = p.parse_args(None if argv is None else list(argv))
    (seed,) = bench_seeds.seed_ids(args.purpose, 1)
    prov = provenance.record("benchmarks.arm7_greedy", argv, allow_dirty=args.allow_dirty,
                             seeds=bench_seeds.record(args.purpose, [seed], "PRNGKey(seed): starts and goals"))
    result = {"benchmark": "arm7_greedy", "provenance": prov, "env": args.env, "device": device_label(),
              "lanes": args.lanes, "seed": seed, "purpose": args.purpose, "command": prov["command"],
              "commit": prov["commit"], "rows": []}  # fmt: skip
    for mode in args.modes:
        result["rows"].append({"mode": mode, **run(args.env, mode, args.lanes, seed)})
    provenance.write(os.path.join(args.out, f"{device_label()}-{args.env}_greedy"), result, to_markdown(result),
                     echo=True)  # fmt: skip
    return result


if __name__ == "__main__":
    main()
