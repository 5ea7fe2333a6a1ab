"""The env-throughput report: the markdown of :mod:`benchmarks.env_throughput`'s measurements."""

from __future__ import annotations

from typing import Any


def markdown(meta: dict[str, Any], rows: list[dict[str, Any]], mlp: list[dict[str, Any]]) -> str:
    lines = [
        f"# Environment throughput — {meta['device_label']}",
        "",
        f"{meta['device']}; jax {meta['jax']}, mujoco {meta['mujoco']}; {meta['date']}. "
        f"{meta['steps']} control steps per timed call, median of {meta['repeats']} (`xla-default`: one call of "
        "one step after a warm-up); env cases run "
        "`wrap_for_training` (auto-reset) under random actions; raw MJX = `mjx.step` of the same model, "
        "same substeps. `no-algsimp`: XLA's `algsimp` pass disabled for the computation (what "
        "`envs_mjx` uses on the CPU); `xla-default`: XLA's default pipeline."
        + (
            f" Load average {meta['loadavg_start']:.1f} at the start, {meta['loadavg_end']:.1f} at the end "
            f"(the machine was shared; CPU figures are noisy)."
            if meta.get("loadavg_start") is not None
            else ""
        ),
    ]
    impls = meta.get("impls", ["jax"])
    if impls != ["jax"]:
        lines += ["", impl_note(meta)]
    by_impl = impls != ["jax"]
    lines += [
        "",
        "| case |" + (" impl |" if by_impl else "") + " XLA | lanes | control steps/s | physics steps/s | x raw MJX "
        "| compile s |" + (" first call s | start-up s |" if by_impl else ""),
        "|---|" + ("---|" if by_impl else "") + "---|---:|---:|---:|---:|---:|" + ("---:|---:|" if by_impl else ""),
    ]
    for r in rows:
        phys = f"{r['physics_steps_per_s']:,.0f}" if r.get("physics_steps_per_s") else "—"
        ratio = f"{r['ratio_to_raw']:.2f}" if r.get("ratio_to_raw") else "—"
        impl = f" {r.get('impl', 'jax')} |" if by_impl else ""
        startup = f" {r['first_call_s']:.1f} | {r['startup_s']:.1f} |" if by_impl else ""
        lines.append(
            f"| {r['case']} |{impl} {r['xla']} | {r['lanes']} | {r['steps_per_s']:,.0f} | {phys} | {ratio} | "
            f"{r['compile_s']:.1f} |{startup}"
        )
    side = side_by_side(rows)
    if side:
        lines += ["", "Warp beside JAX (same case, lanes and XLA setting):", "", *side]
    speedups = []
    for r in rows:
        if r["xla"] != "xla-default":
            continue
        fixed = [
            f for f in rows
            if f["case"] == r["case"] and f["lanes"] == r["lanes"] and f["xla"] == "no-algsimp"
            and f.get("impl", "jax") == r.get("impl", "jax")
        ]  # fmt: skip
        if fixed:
            x = fixed[0]["steps_per_s"] / r["steps_per_s"]
            times = f"{x:,.0f}x" if x >= 10 else f"{x:.2f}x"
            speedups.append(
                f"- {r['case']} at {r['lanes']} lanes: {times} the steps/s of XLA's default pipeline "
                f"(compile {r['compile_s']:.0f} s -> {fixed[0]['compile_s']:.0f} s)"
            )
    if speedups:
        lines += [
            "",
            "Before/after of the CPU fix (`no-algsimp` over `xla-default`, same case and lanes; the `xla-default` "
            "rows come from a single one-step call, so ratios near 1 are within noise):",
            "",
            *speedups,
        ]
    if mlp:
        lines += ["", "Side cost on a 2 x 256 MLP Adam update (1024 x 9 batch):", ""]
        lines += [f"- {m['xla']}: {m['updates_per_s']:,.0f} updates/s (compile {m['compile_s']:.1f} s)" for m in mlp]
    return "\n".join(lines) + "\n"


def impl_note(meta: dict[str, Any]) -> str:
    """The markdown sentence on the physics backends of a ``--impl`` run."""
    cache = meta.get("warp_kernel_cache", "default")
    fresh = cache == "fresh"
    where = "an empty folder, kernels compiled anew" if fresh else "the machine's, kernels of earlier runs loaded"
    return (
        f"Physics backends (env setting `impl`): {', '.join(meta['impls'])}; warp-lang {meta.get('warp', '—')}. "
        "`compile s`: tracing and XLA's compilation; `first call s`: the untimed warm-up call, where MuJoCo Warp "
        f"compiles or loads its kernels (Warp's kernel cache: {where}); `start-up s`: the two together. Cases "
        "without MJX physics run on `jax` only."
    )


def side_by_side(rows: list[dict[str, Any]]) -> list[str]:
    """One line per case, lanes and XLA setting measured on both backends: start-up and steps/s."""
    out = []
    for w in rows:
        if w.get("impl") != "warp":
            continue
        key = (w["case"], w["lanes"], w["xla"])
        j = [r for r in rows if r.get("impl", "jax") == "jax" and (r["case"], r["lanes"], r["xla"]) == key]
        if not j:
            continue
        j = j[0]
        out.append(
            f"- {w['case']} at {w['lanes']} lanes ({w['xla']}): start-up {j['startup_s']:.1f} s (jax) vs "
            f"{w['startup_s']:.1f} s (warp); {j['steps_per_s']:,.0f} vs {w['steps_per_s']:,.0f} control steps/s "
            f"(warp/jax {w['steps_per_s'] / j['steps_per_s']:.2f})"
        )
    return out
