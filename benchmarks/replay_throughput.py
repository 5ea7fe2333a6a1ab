"""Replay throughput: our uniform and prioritised buffers beside flashbax's prioritised buffer, and DDPG+HER.

    python -m benchmarks.replay_throughput                       # capacity 10^6, batches 128 and 256
    python -m benchmarks.replay_throughput --no-ddpg --batches 128

Every buffer holds arm7's HER transition (obs 9, action 3, reward, next obs 9, termination: 23
floats) at capacity ``--capacity`` (10^6), filled with ``--fill`` transitions with random
priorities.  Each operation runs ``--inner`` times inside one jitted ``lax.scan`` (the way a
training loop calls it, the buffer carried on the device) and is timed as the median of
``--repeats`` calls after a compiling call (compile time reported apart); the table gives the
cost of one operation:

* ``add``: store one batch (new priorities = the maximum, as in PER);
* ``sample``: draw one mini-batch with its data (and, for PER, probabilities and IS weights);
* ``update``: write back the priorities of a fixed batch of slots (β annealed);
* ``sample+update``: the sum of the two columns before, each timed in its own scan;
* ``step``: one learning step's replay work fused in one scan body, as DDPG runs it: sample,
  stand-in TD errors computed from the sampled data (and IS weights), priorities written back
  (uniform: the same without the write-back).

Ratios: ``PER sample+update / uniform sample`` (the issue's goal, unfused) and ``PER step /
uniform step`` (fused, like for like).
Peers in the same run: our uniform ring buffer, our prioritised replay with the sum-tree branching
factors of ``--branchings`` (2 = the binary tree of Fig. 3.2; 16 = the default), and flashbax's
``make_prioritised_item_buffer`` (an optional dependency: ``pip install -e .[bench]``).
Goals (issue 5): prioritised sample + update ≤ 1.5 × uniform sample; ≥ 2 × faster than flashbax.

With ``--ddpg``: DDPG + HER (future, k = 4, PER) on arm7, one cycle per timed call: the thesis's
16 lanes × 100 steps with 40 updates of 128, and a many-lane cycle; env steps/s counts every
lane step of the cycle, updates/s the gradient updates of the same cycle.

Results: ``benchmarks/results/<device>-replay_throughput.json`` and ``.md`` (``<device>``:
``cpu-<n>core`` or ``gpu-<device kind>``, e.g. ``gpu-nvidia_h200``); ``--out DIR`` writes them elsewhere.
"""

from __future__ import annotations

import argparse
import os
import platform
import statistics
import time
from collections.abc import Callable
from typing import Any

import jax
import jax.numpy as jnp

import envs_mjx  # noqa: F401  (configures XLA:CPU for MJX before the first computation)
from benchmarks import provenance
from benchmarks.arguments import at_least, nonnegative, positive
from benchmarks.timing import compile_and_time
from jaxrl_robot.replay import Transition, make_prioritized_replay, make_uniform_replay

RESULTS = os.path.join(os.path.dirname(os.path.abspath(__file__)), "results")


def device_label() -> str:
    """``cpu-<n>core`` on the CPU, else ``<backend>-<device kind>`` (``gpu-nvidia_h200``)."""
    d = jax.devices()[0]
    if d.platform == "cpu":
        return f"cpu-{os.cpu_count()}core"
    backend = "gpu" if d.platform in ("gpu", "cuda", "rocm") else d.platform
    return f"{backend}-{d.device_kind}".replace(" ", "_").lower()


def transitions(key: jax.Array, n: int) -> Transition:
    """``n`` random arm7-HER-shaped transitions."""
    k = jax.random.split(key, 4)
    return Transition(
        obs=jax.random.normal(k[0], (n, 9)),
        action=jax.random.uniform(k[1], (n, 3), minval=-1, maxval=1),
        reward=-jnp.ones((n,)),
        next_obs=jax.random.normal(k[2], (n, 9)),
        termination=jnp.zeros((n,)),
    )


def _time(fn: Callable, state: Any, repeats: int) -> tuple[float, float, Any]:
    """(compile_s, median seconds per call, state); ``fn(state) -> state`` jitted with donation."""
    compile_s, times, state = compile_and_time(lambda s: (fn(s), None), state, repeats, donate=True)
    return compile_s, statistics.median(times), state


def _scan(op: Callable, inner: int) -> Callable:
    """``state -> state`` running ``op(state, i)`` ``inner`` times under ``lax.scan``."""

    def run(carry):
        def body(c, i):
            return op(c, i), None

        return jax.lax.scan(body, carry, jnp.arange(inner))[0]

    return run


def _checksum(x: Any) -> jax.Array:
    return sum(jnp.sum(leaf.astype(jnp.float32)) for leaf in jax.tree.leaves(x))


def fake_td(experience: Transition, weights: jax.Array | None = None) -> jax.Array:
    """``[B]`` stand-in TD errors computed from the sampled data (and IS weights), so nothing is skipped."""
    td = experience.reward + 0.1 * experience.obs[:, 0] - 0.1 * experience.next_obs[:, 0] + experience.action[:, 0]
    return td if weights is None else td * weights


def _run_ops(ops: dict[str, Callable], carry: Any, inner: int, repeats: int) -> dict[str, Any]:
    """Time each ``op(carry, i) -> carry`` in its own jitted scan; adds the unfused ``sample+update`` sum."""
    out: dict[str, Any] = {}
    for name, op in ops.items():
        compile_s, sec, carry = _time(_scan(op, inner), carry, repeats)
        out[name] = {"us": sec / inner * 1e6, "compile_s": compile_s}
    if "update" in out:
        out["sample+update"] = {"us": out["sample"]["us"] + out["update"]["us"]}
    return out


def bench_ours(kind: str, capacity: int, batch: int, fill: int, inner: int, repeats: int) -> dict[str, Any]:
    """Per-operation µs of our uniform ('uniform') or prioritised buffer: 'per<branching>' (sum tree,
    e.g. 'per16'), 'block' (block tree, default backend) or 'block-<backend>' ('block-xla')."""
    if kind == "uniform":
        buf = make_uniform_replay(capacity, batch)
    elif kind.startswith("block"):  # 'block' (auto backend) or 'block-<backend>'
        backend = kind.split("-", 1)[1] if "-" in kind else "auto"
        buf = make_prioritized_replay(capacity, batch, tree="block", backend=backend)
    else:
        buf = make_prioritized_replay(capacity, batch, tree="sum", branching=int(kind[3:]))
    items = transitions(jax.random.PRNGKey(0), batch)
    state = buf.init(jax.tree.map(lambda x: x[0], items))
    state = jax.jit(buf.add)(state, transitions(jax.random.PRNGKey(1), fill))
    if kind != "uniform":
        state = jax.jit(buf.update_priorities)(
            state, jnp.arange(fill), jax.random.exponential(jax.random.PRNGKey(2), (fill,))
        )
    key = jax.random.PRNGKey(3)
    ops: dict[str, Callable] = {"add": lambda c, i: (buf.add(c[0], items), c[1])}

    def sample(c, i):
        s = buf.sample(jax.random.fold_in(key, i), c[0])
        return c[0], c[1] + _checksum(s)

    ops["sample"] = sample
    if kind == "uniform":

        def step(c, i):
            s = buf.sample(jax.random.fold_in(key, i), c[0])
            return c[0], c[1] + jnp.sum(fake_td(s.experience))

    else:
        td = jax.random.normal(jax.random.PRNGKey(4), (batch,))
        idx = jax.random.randint(jax.random.PRNGKey(5), (batch,), 0, fill)

        def update(c, i):
            return buf.update_priorities(c[0], idx, td + i), c[1]

        def step(c, i):
            s = buf.sample(jax.random.fold_in(key, i), c[0])
            err = fake_td(s.experience, s.weights)
            return buf.update_priorities(c[0], s.indices, err), c[1] + jnp.sum(err)

        ops["update"] = update
    ops["step"] = step
    return _run_ops(ops, (state, jnp.zeros(())), inner, repeats)


def bench_flashbax(capacity: int, batch: int, fill: int, inner: int, repeats: int) -> dict[str, Any]:
    """The same operations on flashbax's prioritised item buffer (α = 0.6)."""
    import flashbax as fbx

    device = "gpu" if jax.default_backend() == "gpu" else ("tpu" if jax.default_backend() == "tpu" else "cpu")
    buf = fbx.make_prioritised_item_buffer(
        max_length=capacity, min_length=batch, sample_batch_size=batch, add_batches=True, priority_exponent=0.6,
        device=device,
    )  # fmt: skip
    items = transitions(jax.random.PRNGKey(0), batch)
    state = buf.init(jax.tree.map(lambda x: x[0], items))
    add = jax.jit(buf.add, donate_argnums=0)
    fill_items = transitions(jax.random.PRNGKey(1), fill)
    t0 = time.perf_counter()
    state = jax.block_until_ready(add(state, fill_items))
    fill_s = time.perf_counter() - t0
    state = jax.jit(buf.set_priorities)(state, jnp.arange(fill), jax.random.exponential(jax.random.PRNGKey(2), (fill,)))
    key = jax.random.PRNGKey(3)

    def sample(c, i):
        s = buf.sample(c[0], jax.random.fold_in(key, i))
        return c[0], c[1] + _checksum(s.experience)

    td = jax.random.normal(jax.random.PRNGKey(4), (batch,))
    idx = jax.random.randint(jax.random.PRNGKey(5), (batch,), 0, fill)

    def update(c, i):
        return buf.set_priorities(c[0], idx, jnp.abs(td + i) + 1e-6), c[1]

    def step(c, i):  # flashbax returns probabilities, not IS weights: weight them by 1 / P
        s = buf.sample(c[0], jax.random.fold_in(key, i))
        err = fake_td(s.experience, 1.0 / (s.probabilities + 1e-6))
        return buf.set_priorities(c[0], s.indices, jnp.abs(err) + 1e-6), c[1] + jnp.sum(err)

    ops = {"add": lambda c, i: (buf.add(c[0], items), c[1]), "sample": sample, "update": update, "step": step}
    return {"fill_s": fill_s, **_run_ops(ops, (state, jnp.zeros(())), inner, repeats)}


def bench_ddpg(lanes: int, updates: int, batch: int, mode: str, repeats: int) -> dict[str, Any]:
    """One DDPG+HER (future k=4, PER) cycle on arm7: env steps/s and updates/s of the same cycle."""
    from jaxrl_robot.agents.ddpg import DDPGConfig, make_trainer

    env = envs_mjx.make("arm7", reward="sparse", mode=mode)
    cfg = DDPGConfig(epochs=1, cycles_per_epoch=1, num_envs=lanes, updates_per_cycle=updates, batch_size=batch,
                     buffer_size=1_000_000, her="future", her_k=4, per=True, target_clip=(-10.0, 0.0),
                     failure_value=-10.0)  # fmt: skip
    trainer = make_trainer(cfg, env, iterations_per_update=1)
    state = jax.block_until_ready(jax.jit(trainer.init)(jax.random.PRNGKey(0)))
    compile_s, times, _ = compile_and_time(trainer.update, state, repeats, donate=True)
    med = statistics.median(times)
    steps = trainer.env_steps_per_update
    return {"lanes": lanes, "updates_per_cycle": updates, "batch": batch, "mode": mode, "compile_s": compile_s,
            "cycle_s": med, "env_steps_per_s": steps / med, "updates_per_s": updates / med,
            "transitions_per_cycle_max": steps * 5}  # fmt: skip


COLUMNS = ("add", "sample", "update", "sample+update", "step")


def ratios_for(rows: dict[str, Any]) -> dict[str, float]:
    """The goal ratios of one batch size: PER vs uniform (unfused and fused) and flashbax vs PER."""
    uni = rows["uniform"]
    fbx = rows.get("flashbax", {})
    out = {}
    for kind, ops in rows.items():
        if not kind.startswith(("per", "block")) or "error" in ops:
            continue
        out[f"{kind} sample+update / uniform sample"] = ops["sample+update"]["us"] / uni["sample"]["us"]
        out[f"{kind} step / uniform step"] = ops["step"]["us"] / uni["step"]["us"]
        if "step" in fbx:
            out[f"flashbax / {kind} (sample+update)"] = fbx["sample+update"]["us"] / ops["sample+update"]["us"]
            out[f"flashbax / {kind} (step)"] = fbx["step"]["us"] / ops["step"]["us"]
            out[f"flashbax / {kind} (add)"] = fbx["add"]["us"] / ops["add"]["us"]
    return out


def to_markdown(result: dict[str, Any]) -> str:
    lines = [f"# Replay throughput on {result['device']} ({result['device_kind']})", "",
             f"capacity {result['capacity']:,}, filled {result['fill']:,}; µs per operation (median of "
             f"{result['repeats']} × {result['inner']} in one jitted scan); jax {result['jax']}.", "",
             "`sample+update` = the `sample` and `update` columns added (each timed in its own scan); "
             "`step` = sample → stand-in TD errors → priority write-back fused in one scan body, as DDPG "
             "runs it (uniform: the same without the write-back).", ""]  # fmt: skip
    if "empty_scan_us" in result:
        lines += [f"An empty scan iteration (a counter, no replay work) costs {result['empty_scan_us']:.2f} µs: "
                  "every figure includes it once.", ""]  # fmt: skip
    for batch, rows in result["ops"].items():
        header = "| buffer | " + " | ".join(COLUMNS) + " |"
        lines += [f"## batch {batch}", "", header, "|---" * (len(COLUMNS) + 1) + "|"]
        for impl, ops in rows.items():
            if "error" in ops:
                lines.append(f"| {impl} | {ops['error']} |" + " |" * (len(COLUMNS) - 1))
                continue
            cells = [f"{ops[o]['us']:.1f}" if o in ops else "—" for o in COLUMNS]
            lines.append(f"| {impl} | " + " | ".join(cells) + " |")
        ratios = result["ratios"].get(batch, {})
        lines += ["", *(f"- {k}: **{v:.2f}**" for k, v in ratios.items()), ""]
    if result.get("ddpg"):
        lines += ["## DDPG + HER (future k=4, PER) on arm7, one cycle", "",
                  "| mode | lanes | updates × batch | cycle s | env steps/s | updates/s | compile s |",
                  "|---|---|---|---|---|---|---|"]  # fmt: skip
        for r in result["ddpg"]:
            if "error" in r:
                lines.append(f"| {r.get('mode')} | {r.get('lanes')} | error: {r['error']} | | | | |")
                continue
            lines.append(f"| {r['mode']} | {r['lanes']} | {r['updates_per_cycle']} × {r['batch']} | {r['cycle_s']:.3f} "
                         f"| {r['env_steps_per_s']:,.0f} | {r['updates_per_s']:,.0f} | {r['compile_s']:.1f} |")
        lines.append("")
    lines += ["## Run", "",
              f"- Load average (1 min) at start / end: {result['load_start']} / {result.get('load_end', '—')} "
              f"on {os.cpu_count()} CPU cores (other jobs on a shared host make CPU figures noisy)."]  # fmt: skip
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> dict[str, Any]:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--capacity", type=positive, default=1_000_000)
    p.add_argument("--fill", type=nonnegative, default=1_000_000)
    p.add_argument("--batches", type=positive, nargs="+", default=[128, 256])
    p.add_argument("--inner", type=positive, default=100)
    p.add_argument("--repeats", type=positive, default=5)
    p.add_argument("--replay", action=argparse.BooleanOptionalAction, default=True, help="the buffer operations")
    p.add_argument("--ddpg", action=argparse.BooleanOptionalAction, default=True)
    p.add_argument("--ddpg-lanes", type=positive, nargs="+", default=None)
    p.add_argument("--mode", default=None, help="arm7 physics of the DDPG cycle (default: pd on GPU, else kinematic)")
    p.add_argument("--branchings", type=at_least(2), nargs="+", default=[2, 8, 16, 32],
                   help="sum-tree branching factors")  # fmt: skip
    p.add_argument("--blocks", nargs="*", default=["block"],
                   help="block-tree variants: 'block' (default backend), 'block-xla', 'block-pallas'")  # fmt: skip
    p.add_argument("--out", default=RESULTS)
    provenance.add_args(p)
    args = p.parse_args(argv)
    on_gpu = jax.default_backend() != "cpu"
    seeds = "fixed in the code: PRNGKey(0)-PRNGKey(5) for the items, priorities, keys and TD errors"
    result: dict[str, Any] = {
        "provenance": provenance.record("benchmarks.replay_throughput", argv, seeds=seeds,
                                        allow_dirty=args.allow_dirty),
        "device": device_label(), "device_kind": jax.devices()[0].device_kind, "jax": jax.__version__,
        "host": platform.node(), "capacity": args.capacity, "fill": args.fill, "inner": args.inner,
        "repeats": args.repeats, "ops": {}, "ratios": {},
        "load_start": round(os.getloadavg()[0], 2),
    }  # fmt: skip
    if args.replay:  # the floor under every figure: one scan iteration that does no replay work
        _, sec, _ = _time(_scan(lambda c, i: c + i.astype(jnp.float32), args.inner), jnp.zeros(()), args.repeats)
        result["empty_scan_us"] = sec / args.inner * 1e6
        print("empty scan iteration", round(result["empty_scan_us"], 2), "µs", flush=True)
    for batch in args.batches if args.replay else []:
        rows: dict[str, Any] = {}
        kinds = ["uniform", *(f"per{b}" for b in args.branchings), *args.blocks]
        for kind in kinds:
            rows[kind] = bench_ours(kind, args.capacity, batch, args.fill, args.inner, args.repeats)
            print(batch, kind, {k: round(v["us"], 1) for k, v in rows[kind].items()}, f"load {os.getloadavg()[0]:.1f}",
                  flush=True)
        try:
            rows["flashbax"] = bench_flashbax(args.capacity, batch, args.fill, args.inner, args.repeats)
            print(batch, "flashbax", {k: round(v["us"], 1) for k, v in rows["flashbax"].items() if k != "fill_s"},
                  flush=True)
        except Exception as e:  # an optional peer: record why it is missing
            rows["flashbax"] = {"error": f"{type(e).__name__}: {e}"[:200]}
            print(batch, "flashbax failed:", rows["flashbax"]["error"], flush=True)
        result["ops"][str(batch)] = rows
        result["ratios"][str(batch)] = ratios_for(rows)
        save(result, args.out)  # partial results survive a time limit
    if args.ddpg:
        mode = args.mode or ("pd" if on_gpu else "kinematic")
        lanes = args.ddpg_lanes or ([16, 1024] if on_gpu else [16, 128])
        result["ddpg"] = []
        for n in lanes:
            updates, batch = (40, 128) if n == 16 else (max(40, n // 4), 1024)
            try:
                r = bench_ddpg(n, updates, batch, mode, args.repeats)
            except Exception as e:
                r = {"lanes": n, "mode": mode, "error": f"{type(e).__name__}: {e}"[:200]}
            result["ddpg"].append(r)
            print("ddpg", r, flush=True)
            save(result, args.out)
    result["load_end"] = round(os.getloadavg()[0], 2)
    md = save(result, args.out)
    print(md)
    return result


def save(result: dict[str, Any], out: str) -> str:
    """Write (or rewrite) the ``.json`` and ``.md`` results; returns the markdown."""
    os.makedirs(out, exist_ok=True)
    return provenance.write(os.path.join(out, f"{result['device']}-replay_throughput"), result, to_markdown(result))


if __name__ == "__main__":
    main()
