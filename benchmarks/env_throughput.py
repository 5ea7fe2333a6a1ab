"""Environment throughput: control steps/s of our envs beside raw MJX stepping, in one run.

    python -m benchmarks.env_throughput                        # sizes chosen for the device
    python -m benchmarks.env_throughput --batches 256 1024 --cases "arm7 pd" "raw MJX arm7"

Each case in ``CASES`` is timed at every batch size (lanes): a jitted call runs ``--steps``
control steps under ``lax.scan``.  Environment cases step ``wrap_for_training(env)`` (vmap, time
limit, auto-reset with a fresh episode per finished lane) under uniform random actions; raw-MJX
cases step ``env.mjx_model`` with ``mjx.step`` ``n_substeps`` times per control step under fixed
random controls, i.e. the same model and substeps with no IK, rewards or resets.  Compilation is
timed apart (``lower().compile()``), then the median of ``--repeats`` timed calls
(``block_until_ready``) gives steps/s.  Ratios divide each case by the raw-MJX case of the same
model, batch and XLA setting.

On the CPU every case also runs with XLA's default pipeline beside the setting this package uses
(``envs_mjx.xla``: the ``algsimp`` pass disabled for MJX) — the before/after of that fix — plus a
small MLP training step under both settings, its side cost.  The default-XLA MJX cases are slow,
so they run only at the batches in ``--default-xla-batches``.

``--impl jax warp`` times every MJX case on each physics backend (env setting ``impl``,
``envs_mjx.backend``: MJX's JAX implementation, MuJoCo Warp) side by side; cases without MJX physics
(``kinematic`` modes, ``racecar``) run on ``jax`` only.  Warp compiles its kernels at the first call, not in
``compile()``, so each row also has ``first_call_s`` (the untimed warm-up call) and ``startup_s`` = compile
+ first call, the cold start a training run sees.  Warp keeps compiled kernels on disk (``~/.cache/warp``,
``$WARP_CACHE_PATH``); ``--warp-kernel-cache fresh`` starts from an empty folder, as on a new machine.

    python -m benchmarks.env_throughput --impl jax warp --cases "arm7 pd" "raw MJX arm7" --batches 64

Results: ``benchmarks/results/<device>-env_throughput.json`` and ``.md`` (``…-env_throughput-jax-warp``
with ``--impl``).  To add an environment, append a ``Case`` to ``CASES`` (and a ``RawMJX`` case if it is
simulated by MJX).
"""

from __future__ import annotations

import os

# Leave XLA_FLAGS alone: this script compares XLA settings per computation (envs_mjx.xla).
os.environ.setdefault("ENVS_MJX_XLA_CPU_FIX", "0")

import argparse  # noqa: E402
import dataclasses  # noqa: E402
import datetime  # noqa: E402
import statistics  # noqa: E402
import tempfile  # noqa: E402
import time  # noqa: E402
import warnings  # noqa: E402
from collections.abc import Callable  # noqa: E402
from typing import Any  # noqa: E402

import jax  # noqa: E402
import jax.numpy as jnp  # noqa: E402
import mujoco  # noqa: E402
from mujoco import mjx  # noqa: E402

import envs_mjx  # noqa: E402
from benchmarks import provenance  # noqa: E402
from benchmarks.arguments import positive  # noqa: E402
from benchmarks.env_throughput_report import markdown
from envs_mjx import backend, wrap_for_training  # noqa: E402

warnings.filterwarnings("ignore", message="arm7 pd mode steps MJX")  # options are set per computation here

RESULTS = os.path.join(os.path.dirname(os.path.abspath(__file__)), "results")


@dataclasses.dataclass(frozen=True)
class Case:
    """An environment stepped through ``wrap_for_training`` under random actions."""

    label: str
    env: str
    overrides: tuple[tuple[str, Any], ...] = ()
    raw: str | None = None  # label of the RawMJX case to compare with
    mjx: bool = True  # simulated by MJX (runs on every --impl), else on jax only

    def build(self, lanes: int, steps: int, impl: str = "jax") -> tuple[Callable, Any, dict[str, Any]]:
        env = envs_mjx.make(self.env, **dict(self.overrides), **({"impl": impl} if self.mjx else {}))
        train_env = wrap_for_training(env, num_envs=lanes)

        def chunk(state, key):
            def body(state, k):
                action = jax.random.uniform(k, (lanes, env.action_size), minval=-1.0, maxval=1.0)
                return train_env.step(state, action), None

            state, _ = jax.lax.scan(body, state, jax.random.split(key, steps))
            return state

        state = jax.jit(train_env.reset)(jax.random.PRNGKey(0))
        return chunk, state, {"substeps": getattr(env.config, "n_substeps", None)}


@dataclasses.dataclass(frozen=True)
class RawMJX:
    """``mjx.step`` of an env's ``mjx_model``, ``n_substeps`` per control step, fixed random controls."""

    label: str
    env: str
    overrides: tuple[tuple[str, Any], ...] = ()
    raw: str | None = None
    mjx: bool = True

    def build(self, lanes: int, steps: int, impl: str = "jax") -> tuple[Callable, Any, dict[str, Any]]:
        env = envs_mjx.make(self.env, **dict(self.overrides), impl=impl)
        model, substeps = env.mjx_model, int(env.config.n_substeps)
        lo, hi = env.mj_model.actuator_ctrlrange[:, 0], env.mj_model.actuator_ctrlrange[:, 1]
        data0 = backend.make_data(env.mj_model, model)

        def init(key):
            kq, ku = jax.random.split(key)
            qpos = jax.random.uniform(kq, (model.nq,), minval=0.5 * lo, maxval=0.5 * hi)
            ctrl = jax.random.uniform(ku, (model.nu,), minval=0.5 * lo, maxval=0.5 * hi)
            return data0.replace(qpos=qpos, ctrl=ctrl)

        def control_step(data):
            return jax.lax.fori_loop(0, substeps, lambda _, d: mjx.step(model, d), data)

        def chunk(data, key):
            del key
            data, _ = jax.lax.scan(lambda d, _: (jax.vmap(control_step)(d), None), data, None, steps)
            return data

        state = jax.jit(jax.vmap(init))(jax.random.split(jax.random.PRNGKey(0), lanes))
        return chunk, state, {"substeps": substeps}


CASES: list[Case | RawMJX] = [
    Case("arm7 pd", "arm7", (("mode", "pd"),), raw="raw MJX arm7"),
    Case("arm7 kinematic", "arm7", (("mode", "kinematic"),), raw="raw MJX arm7", mjx=False),
    RawMJX("raw MJX arm7", "arm7", (("mode", "pd"),)),
    Case("scara", "scara", raw="raw MJX scara"),
    RawMJX("raw MJX scara", "scara"),
    Case("unicycle dynamic", "unicycle", (("mode", "dynamic"),), raw="raw MJX unicycle"),
    Case("unicycle kinematic", "unicycle", (("mode", "kinematic"),), raw="raw MJX unicycle", mjx=False),
    RawMJX("raw MJX unicycle", "unicycle", (("mode", "dynamic"),)),
    Case("racecar", "racecar", mjx=False),
]

XLA_SETTINGS = {"no-algsimp": {"xla_disable_hlo_passes": "algsimp"}, "xla-default": {}}


def device_label() -> str:
    d = jax.devices()[0]
    return "cpu" if d.platform == "cpu" else f"{d.platform}-{d.device_kind}".replace(" ", "_").lower()


def measure(chunk: Callable, state: Any, lanes: int, steps: int, repeats: int, options: dict) -> dict[str, Any]:
    """Compile time and median steps/s of ``chunk(state, key)`` (``lanes * steps`` control steps a call).

    ``compile_s``: tracing and XLA's compilation (``lower().compile()``); ``first_call_s``: the untimed
    warm-up call (where MuJoCo Warp compiles or loads its kernels); ``startup_s``: the two together."""
    fn = jax.jit(chunk, compiler_options=options or None)
    key = jax.random.PRNGKey(1)
    t0 = time.perf_counter()
    compiled = fn.lower(state, key).compile()
    compile_s = time.perf_counter() - t0
    t0 = time.perf_counter()
    state = jax.block_until_ready(compiled(state, key))  # warm-up
    first_call_s = time.perf_counter() - t0
    times = []
    for i in range(repeats):
        k = jax.random.fold_in(key, i)
        t = time.perf_counter()
        state = jax.block_until_ready(compiled(state, k))
        times.append(time.perf_counter() - t)
    med = statistics.median(times)
    return {
        "compile_s": compile_s, "first_call_s": first_call_s, "startup_s": compile_s + first_call_s,
        "times_s": times, "median_s": med, "steps_per_s": lanes * steps / med,
    }  # fmt: skip


def mlp_side_cost(options: dict, repeats: int) -> dict[str, Any]:
    """Adam updates/s of a 2 x 256 MLP on a 1024 x 9 batch (50 per call) under ``options``."""
    import flax.linen as nn
    import optax

    class MLP(nn.Module):
        @nn.compact
        def __call__(self, x):
            for h in (256, 256):
                x = nn.relu(nn.Dense(h)(x))
            return nn.Dense(3)(x)

    net, opt = MLP(), optax.adam(1e-3)
    x = jax.random.normal(jax.random.PRNGKey(0), (1024, 9))
    params = net.init(jax.random.PRNGKey(1), x)

    def chunk(carry, key):
        def update(c, _):
            p, s = c
            g = jax.grad(lambda p: jnp.mean((net.apply(p, x) - jnp.sin(x[:, :3])) ** 2))(p)
            u, s = opt.update(g, s, p)
            return (optax.apply_updates(p, u), s), None

        return jax.lax.scan(update, carry, None, 50)[0]

    out = measure(chunk, (params, opt.init(params)), 1, 50, max(repeats, 7), options)
    out["updates_per_s"] = out.pop("steps_per_s")
    return out


def main(argv: list[str] | None = None) -> None:
    on_cpu = jax.default_backend() == "cpu"
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--batches", type=positive, nargs="+",
                        default=[64, 256, 1024] if on_cpu else [1024, 8192, 65536])  # fmt: skip
    parser.add_argument("--cases", nargs="+", default=[c.label for c in CASES], help="labels from CASES")
    parser.add_argument("--steps", type=positive, default=10 if on_cpu else 20, help="control steps per timed call")
    parser.add_argument("--repeats", type=positive, default=5)
    parser.add_argument(
        "--default-xla-batches", type=positive, nargs="*", default=[64] if on_cpu else [],
        help="batches also measured with XLA's default pipeline (CPU before/after)",
    )  # fmt: skip
    parser.add_argument("--impl", nargs="+", choices=backend.IMPLS, default=["jax"],
                        help="physics backends of the MJX cases, timed side by side (env setting impl)")  # fmt: skip
    parser.add_argument("--warp-kernel-cache", choices=("default", "fresh"), default="default",
                        help="MuJoCo Warp's kernel cache: the machine's (default) or an empty folder")  # fmt: skip
    parser.add_argument("--out", default=None, help="JSON path (markdown beside it); default benchmarks/results/")
    provenance.add_args(parser)
    args = parser.parse_args(argv)
    impls = list(dict.fromkeys(args.impl))
    if "warp" in impls:
        try:
            backend.check_impl("warp")
        except backend.WarpMissingError as e:
            raise SystemExit(str(e)) from None
        if args.warp_kernel_cache == "fresh":
            import warp

            warp.config.kernel_cache_dir = tempfile.mkdtemp(prefix="env-throughput-warp-kernels-")
    seeds = "fixed in the code: states from PRNGKey(0), actions from PRNGKey(1), every case"
    prov = provenance.record("benchmarks.env_throughput", argv, seeds=seeds, allow_dirty=args.allow_dirty)

    cases = {c.label: c for c in CASES}
    unknown = [c for c in args.cases if c not in cases]
    if unknown:
        raise SystemExit(f"unknown case(s) {unknown}; valid: {list(cases)}")
    dev = jax.devices()[0]
    meta = {
        "device_label": device_label(),
        "device": f"{dev.platform}: {dev.device_kind}" + (f", {os.cpu_count()} cores" if on_cpu else ""),
        "jax": jax.__version__,
        "mujoco": mujoco.__version__,
        "date": datetime.datetime.now().strftime("%Y-%m-%d %H:%M"),
        "steps": args.steps,
        "repeats": args.repeats,
        "xla_flags": os.environ.get("XLA_FLAGS", ""),
        "loadavg_start": os.getloadavg()[0] if on_cpu else None,
        "impls": impls,
    }
    if "warp" in impls:
        import warp

        meta.update(warp=warp.__version__, warp_kernel_cache=args.warp_kernel_cache)
    suffix = "" if impls == ["jax"] else "-" + "-".join(impls)
    out = args.out or os.path.join(RESULTS, f"{meta['device_label']}-env_throughput{suffix}.json")
    os.makedirs(os.path.dirname(os.path.abspath(out)), exist_ok=True)
    rows: list[dict[str, Any]] = []
    mlp: list[dict[str, Any]] = []

    def save() -> None:
        if on_cpu:
            meta["loadavg_end"] = os.getloadavg()[0]
        result = {"provenance": prov, "meta": meta, "rows": rows, "mlp_side_cost": mlp}
        provenance.write(os.path.splitext(out)[0], result, markdown(meta, rows, mlp))

    order = sorted(args.cases, key=lambda label: 0 if isinstance(cases[label], RawMJX) else 1)
    for lanes in args.batches:
        settings = ["no-algsimp"] + (["xla-default"] if on_cpu and lanes in args.default_xla_batches else [])
        for xla_name in settings:
            # the default pipeline is the before/after of the CPU fix for MJX's JAX implementation only
            for impl in impls if xla_name == "no-algsimp" else ["jax"]:
                for label in order:
                    case = cases[label]
                    if impl != "jax" and not case.mjx:
                        continue
                    # XLA:CPU's default pipeline runs MJX thousands of times slower: time one short call
                    steps, repeats = (1, 1) if xla_name == "xla-default" else (args.steps, args.repeats)
                    chunk, state, extra = case.build(lanes, steps, impl)
                    r = measure(chunk, state, lanes, steps, repeats, XLA_SETTINGS[xla_name] if on_cpu else {})
                    row = {"case": label, "impl": impl, "xla": xla_name if on_cpu else "default", "lanes": lanes,
                           "steps": steps, **extra}  # fmt: skip
                    row.update(r)
                    if isinstance(case, RawMJX) and extra["substeps"]:
                        row["physics_steps_per_s"] = r["steps_per_s"] * extra["substeps"]
                    base = [
                        b for b in rows
                        if (b["case"], b["lanes"], b["xla"], b["impl"]) == (case.raw, lanes, row["xla"], impl)
                    ]  # fmt: skip
                    if base:
                        row["ratio_to_raw"] = r["steps_per_s"] / base[0]["steps_per_s"]
                    rows.append(row)
                    ratio = f"  x{row['ratio_to_raw']:.2f} raw" if "ratio_to_raw" in row else ""
                    print(
                        f"{label:<16} {impl:<4} {row['xla']:<11} lanes {lanes:>6}: {r['steps_per_s']:>12,.0f} steps/s "
                        f"(compile {r['compile_s']:.1f} s, first call {r['first_call_s']:.1f} s){ratio}",
                        flush=True,
                    )
                    save()
    if on_cpu:
        for xla_name in XLA_SETTINGS:
            m = mlp_side_cost(XLA_SETTINGS[xla_name], args.repeats)
            mlp.append({"xla": xla_name, **m})
            print(f"MLP update       {xla_name:<11}: {m['updates_per_s']:,.0f} updates/s", flush=True)
            save()
    print(f"wrote {out}")


if __name__ == "__main__":
    main()
