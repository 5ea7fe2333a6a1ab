"""Prioritised replay's two sum-trees inside a DDPG program: compile time and time per chunk.

    python -m benchmarks.per_trees                   # the arm's PER row of Table 3.1, preset auto
    python -m benchmarks.per_trees --trees sum block -- --env unicycle --preset fast

Builds the trainer of ``python -m train.ddpg <ddpg args> --per --per-tree <tree>`` for each tree
(``sum``: the 16-ary :mod:`jaxrl_robot.replay.sum_tree`; ``block``: the two-level
:mod:`jaxrl_robot.replay.block_tree`, Pallas kernels on a GPU) and times, in this process, the
compile of one chunk (``trainer.update``), then the median of ``--repeats`` chunks after a warm-up
chunk (:func:`benchmarks.timing.compile_and_time`).  The tree on its own is timed by
``python -m benchmarks.replay_throughput``; this measures what a user of the trainer waits for.

Results: ``benchmarks/results/<device>-per_trees.json`` and ``.md``.
"""

from __future__ import annotations

import argparse
import statistics
import time
from typing import Any

import jax

from benchmarks import provenance
from benchmarks.arguments import positive
from benchmarks.timing import compile_and_time
from benchmarks.train_throughput import RESULTS, device_label

DEFAULT_DDPG = ("--env", "arm7_precise", "--env-config", "mode=kinematic", "obs=no_goal", "--reward", "shaped",
                "--her", "none")  # fmt: skip
"""Table 3.1's PER row (shaped reward, no relabelling, no goal in the observation) on the 1 cm arm."""


def bench(tree: str, ddpg_argv: list[str], repeats: int) -> dict[str, Any]:
    """Compile and chunk times of the DDPG trainer of ``ddpg_argv`` with ``--per --per-tree tree``."""
    import train.ddpg

    args = train.ddpg.CLI.parse([*ddpg_argv, "--per", "--per-tree", tree])
    _, trainer, config = train.ddpg.CLI.build(args)
    t0 = time.perf_counter()
    state = jax.block_until_ready(jax.jit(trainer.init)(jax.random.PRNGKey(0)))
    init_s = time.perf_counter() - t0
    compile_s, times, _ = compile_and_time(trainer.update, state, repeats, donate=True)
    chunk_s = statistics.median(times)
    sizes = {k: config["ddpg"][k] for k in ("num_envs", "batch_size", "buffer_size", "updates_per_cycle")}
    steps = trainer.env_steps_per_update
    return dict(tree=tree, init_s=init_s, compile_s=compile_s, chunk_s=chunk_s, chunk_s_all=times,
                env_steps_per_chunk=steps, env_steps_per_s=steps / chunk_s, ddpg=sizes)  # fmt: skip


HEADER = """# Prioritised replay's trees inside DDPG — {device}

`python -m train.ddpg {argv} --per --per-tree <tree>`; one chunk is `trainer.update`; median of {repeats}
chunks after a warm-up chunk, compile apart (init: the jitted `trainer.init` including its compile).
Lower is better.

| tree | init s | compile s (one chunk) | s per chunk | env steps/s | × sum (chunk time) |
|---|---:|---:|---:|---:|---:|
"""


def to_markdown(result: dict[str, Any]) -> str:
    text = HEADER.format(device=result["device"], argv=" ".join(result["ddpg_argv"]), repeats=result["repeats"])
    base = {r["tree"]: r for r in result["runs"]}.get("sum")
    for r in result["runs"]:
        ratio = f"{r['chunk_s'] / base['chunk_s']:.2f}" if base else "—"
        text += (f"| {r['tree']} | {r['init_s']:.1f} | {r['compile_s']:.1f} | {r['chunk_s']:.3f} "
                 f"| {r['env_steps_per_s']:,.0f} | {ratio} |\n")  # fmt: skip
    return text


def main(argv: list[str] | None = None) -> dict[str, Any]:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--trees", nargs="+", default=["sum", "block"], choices=["sum", "block"])
    p.add_argument("--repeats", type=positive, default=3)
    p.add_argument("--out", default=RESULTS)
    p.add_argument("ddpg", nargs="*", help="train.ddpg arguments after --, without --per (default: Table 3.1's "
                   "PER row on arm7_precise)")  # fmt: skip
    provenance.add_args(p)
    args = p.parse_args(argv)
    ddpg_argv = list(args.ddpg or DEFAULT_DDPG)
    prov = provenance.record("benchmarks.per_trees", argv, seeds="PRNGKey(0) (fixed in the code)",
                             allow_dirty=args.allow_dirty)
    result = {"benchmark": "per_trees", "provenance": prov, "device": device_label(), "ddpg_argv": ddpg_argv,
              "repeats": args.repeats, "runs": []}  # fmt: skip
    stem = f"{args.out}/{device_label()}-per_trees"
    for tree in args.trees:
        row = bench(tree, ddpg_argv, args.repeats)
        result["runs"].append(row)
        print(f"{tree}: compile {row['compile_s']:.1f} s, chunk {row['chunk_s']:.3f} s", flush=True)
        provenance.write(stem, result, to_markdown(result), echo=tree == args.trees[-1])
    return result


if __name__ == "__main__":
    main()
