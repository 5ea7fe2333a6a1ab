"""The cost of one all-reduce between devices as the trainers issue it: the floor under every multi-device iteration.

    python -m benchmarks.collectives                          # 1, 2, 4, ... devices; 256 / 64 k / 1 M floats
    python -m benchmarks.collectives --sizes 256 --steps 2000 --label nccl-ll   # e.g. under NCCL_PROTO=LL

For every device count D = 1, 2, 4, ... up to the devices visible, and every ``--sizes`` entry S: one jitted
``fori_loop`` of ``--steps`` steps, each ``x = pmean(0.5 * x + 1)`` of this device's ``[S]`` float32 slice of
a ``[D * S]`` array split over a D-device lane mesh (``parallel.shard_lanes``, so the all-reduce is the one
PPO's gradients and DDPG's synchronous workers go through). Compile apart, one warm-up call, the median of
``--repeats`` timed calls; microseconds per step. D > 1 runs under both lane-map implementations (``vmap``,
the default on several devices, and ``shard_map``). D = 1 runs the same loop with no collective (``pmean``
over one device is the identity), so ``D's µs - 1's µs`` is what one all-reduce adds to a loop step.

A PPO iteration makes one all-reduce per mini-batch update (4 actor + 4 critic updates per epoch in
the presets) and DDPG's synchronous workers one per update, so each iteration on several devices pays
that many times the figure measured here, however few lanes each device holds.

Results: ``benchmarks/results/<device>x<count>-collectives[-label].json`` and ``.md``; environment
variables that shape the collectives (``NCCL_*``, ``XLA_FLAGS``) are recorded with them.
"""

from __future__ import annotations

import argparse
import os
import statistics
import sys
import time
from typing import Any

import jax
import jax.numpy as jnp

from benchmarks import provenance
from benchmarks.arguments import positive
from benchmarks.train_throughput import RESULTS, device_label
from jaxrl_robot import parallel

P = parallel.P


def device_counts(available: int) -> list[int]:
    """1, 2, 4, ... up to ``available``, and ``available`` itself when it is not a power of two."""
    counts, d = [], 1
    while d <= available:
        counts.append(d)
        d *= 2
    return counts + ([available] if counts[-1] != available else [])


def loop(devices: int, size: int, steps: int, impl: str | None = None):
    """``x [devices * size] -> x`` after ``steps`` steps of ``x = pmean(0.5 x + 1)`` per device slice
    (``impl``: the lane map's, default :func:`jaxrl_robot.parallel.lane_map_impl`'s)."""
    mesh = parallel.lane_mesh(devices)

    def body(x: jax.Array) -> jax.Array:
        return jax.lax.fori_loop(0, steps, lambda _, v: parallel.pmean(0.5 * v + 1.0), x)

    return jax.jit(parallel.shard_lanes(body, mesh, (P(parallel.LANES),), P(parallel.LANES), impl=impl)), mesh


def time_loop(devices: int, size: int, steps: int, repeats: int, impl: str | None = None) -> dict[str, Any]:
    """One row: compile seconds, µs per step (median of ``repeats`` calls) and the final value, which must
    be ``2 - 2 * 0.5 ** (steps * (repeats + 1))`` (the loop's fixed point is 2; a wrong collective misses it)."""
    fn, mesh = loop(devices, size, steps, impl)
    x = jax.device_put(jnp.zeros((devices * size,), jnp.float32), parallel.lane_sharding(mesh))
    t0 = time.perf_counter()
    compiled = fn.lower(x).compile()
    compile_s = time.perf_counter() - t0
    out = jax.block_until_ready(compiled(x))
    times = []
    for _ in range(repeats):
        t = time.perf_counter()
        out = jax.block_until_ready(compiled(out))
        times.append(time.perf_counter() - t)
    value = float(out[0])
    return {
        "devices": devices, "size": size, "impl": parallel.lane_map_impl(mesh, impl), "steps": steps,
        "us_per_step": 1e6 * statistics.median(times) / steps, "compile_s": compile_s, "value": value,
    }  # fmt: skip


def table(rows: list[dict[str, Any]]) -> str:
    """Markdown rows; ``added`` is the step's time over the one-device loop of the same size."""
    floor = {r["size"]: r["us_per_step"] for r in rows if r["devices"] == 1}
    lines = ["| devices | floats per device | lane map | µs per step | added by the all-reduce µs | compile s |",
             "|---:|---:|---|---:|---:|---:|"]  # fmt: skip
    for r in rows:
        added = "—" if r["devices"] == 1 else f"{r['us_per_step'] - floor[r['size']]:.1f}"
        lines.append(f"| {r['devices']} | {r['size']:,} | {r['impl']} | {r['us_per_step']:.1f} | {added} | "
                     f"{r['compile_s']:.1f} |")  # fmt: skip
    return "\n".join(lines)


def collective_environment() -> dict[str, str]:
    """The environment variables that shape collectives (``NCCL_*``, ``XLA_FLAGS``, ``JAXRL_LANE_MAP``)."""
    return {k: v for k, v in sorted(os.environ.items())
            if k.startswith("NCCL_") or k in ("XLA_FLAGS", "JAXRL_LANE_MAP")}  # fmt: skip


def main(argv: list[str] | None = None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--sizes", type=positive, nargs="+", default=[256, 65536, 1048576], help="floats per device")
    p.add_argument("--steps", type=positive, default=1000, help="loop steps per timed call")
    p.add_argument("--repeats", type=positive, default=5)
    p.add_argument("--label", default="", help="suffix of the results file")
    p.add_argument("--out", default=RESULTS)
    provenance.add_args(p)
    args = p.parse_args(argv)
    env = collective_environment()
    prov = provenance.record("benchmarks.collectives", argv, allow_dirty=args.allow_dirty,
                             seeds="none: the loop's input is zeros", environment=env)  # fmt: skip
    rows = []
    for d in device_counts(jax.device_count()):
        for impl in ("shard_map",) if d == 1 else ("vmap", "shard_map"):
            for s in args.sizes:
                rows.append(time_loop(d, s, args.steps, args.repeats, impl))
                r = rows[-1]
                print(f"{d} device(s), {impl}, {s} floats: {r['us_per_step']:.1f} µs per step "
                      f"(value {r['value']:.4f})", flush=True)  # fmt: skip
    name = f"{device_label()}x{jax.device_count()}-collectives" + (f"-{args.label}" if args.label else "")
    text = "\n".join([
        f"# One all-reduce per loop step — {provenance.device_words(provenance.device())}",
        "",
        f"A jitted loop of {args.steps} steps, each `x = pmean(0.5 x + 1)` over the lane mesh "
        f"(`python -m benchmarks.collectives`); median of {args.repeats} calls, compile apart. "
        f"Environment: {', '.join(f'`{k}={v}`' for k, v in env.items()) or 'no NCCL_* or XLA_FLAGS set'}.",
        "",
        table(rows),
        "",
    ])  # fmt: skip
    provenance.write(os.path.join(args.out, name), {"provenance": prov, "rows": rows}, text, echo=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
