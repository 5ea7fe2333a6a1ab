"""Reproducer: MJX physics inside ``shard_map`` over several GPUs (each variant in its own process).

``python -m benchmarks.multigpu_repro [--variants a,b] [--lanes 256] [--out FILE]`` runs every
variant in a fresh subprocess (a segmentation fault only ends that variant) and prints a table
of exit codes (``--out FILE.json``: also written there, with ``FILE.md`` beside it). A variant
compiles and runs the rollout of ``arm7`` in ``pd`` mode (MJX position servos) for a few steps on
all visible devices, lanes split over the ``"lanes"`` mesh axis.

Variants:
  one_device      shard_map over a 1-device mesh (control);
  shard_map       ``parallel.shard_lanes(..., impl="shard_map")`` of the rollout (``jax.shard_map``);
  vmap            ``parallel.shard_lanes(..., impl="vmap")``: vmap over a device axis, partitioned by XLA;
  jit_sharded     ``jax.jit`` with ``NamedSharding`` in/out shardings and no shard_map;
  shard_map+<F>   shard_map with one XLA flag ``F`` added to ``XLA_FLAGS`` (e.g. autotune off);
  shard_map_no_shardy   shard_map with ``jax_use_shardy_partitioner=False``;
  env_arg         the shard_map variant (the env's rollout) with the env's MJX model and initial data traced
                  arguments of the mapped function, swapped into the env while it is traced;
  <V>@args        variant V with the arrays its mapped function closes over passed in as arguments of the jitted
                  program (:func:`constants_as_arguments`); ``shard_map_args``: ``shard_map@args``;
  trainer         ``parallel.shard_lanes`` with its default implementation for the mesh;
  kinematic       shard_map of ``arm7`` in ``kinematic`` mode (plain JAX, no MJX: the control that compiles);
  unicycle        shard_map of ``unicycle`` in ``dynamic`` mode (MJX, another model);
  unicycle_kinematic   ``unicycle`` in ``kinematic`` mode (plain JAX, an ``mjx.Data`` carried in the state);
  cholesky        shard_map of no env: a batched Cholesky factorisation and solve of 7 x 7 systems per lane
                  and step, as MJX's forward dynamics factorises the mass matrix (is the linear-algebra
                  custom call what does not compile?);
  sparse          shard_map of ``arm7`` ``pd`` with ``jacobian="sparse"`` (MuJoCo's option), under which MJX
                  factorises the mass matrix with plain JAX operations instead of ``cho_factor`` / ``cho_solve``;
  op:<O>          shard_map of no env: one kind of operation on NumPy constants (:data:`OPS`);
  const, const_numpy, const_device0   shard_map of no env: a closed-over constant, an uncommitted device
                  array, a NumPy array or an array committed to the first device;
  stage:<S>       shard_map of MJX's pipeline on ``arm7``'s model (no env, no wrapper), every stage of
                  :data:`STAGES` up to and including ``S`` per step (``step``: ``mjx.step``; ``substeps``: the
                  env's ``fori_loop`` of ``mjx.step``), to find the first stage that XLA:GPU cannot compile;
                  ``stage:<S>/numpy``: the model's arrays as NumPy constants; ``/uncommitted``: on no
                  device in particular; ``stage:<S>/arg``: the model a
                  replicated argument.

A variant that dies keeps the Python stack ``faulthandler`` printed (the extension-module list cut).
"""

from __future__ import annotations

import argparse
import json
import os
import re
import subprocess
import sys
import time

from benchmarks import provenance
from benchmarks.arguments import positive

FLAGS = {
    "autotune0": "--xla_gpu_autotune_level=0",
    "no_cmdbuf": "--xla_gpu_enable_command_buffer=",
    "no_triton_gemm": "--xla_gpu_enable_triton_gemm=false",
    "no_lhs": "--xla_gpu_enable_latency_hiding_scheduler=false",
    "no_dbuf": "--xla_gpu_enable_while_loop_double_buffering=false",
    "no_constant_folding": "--xla_disable_hlo_passes=constant_folding",
    "no_simplify": "--xla_disable_hlo_passes=algsimp",
}
STAGES = ("kinematics", "com_pos", "crb", "factor_m", "collision", "make_constraint", "transmission", "com_vel",
          "passive", "rne", "fwd_actuation", "fwd_acceleration", "solve", "step", "substeps")
"""MJX's forward pipeline in its order (``mujoco.mjx._src.forward``), then a whole step and the env's substeps."""
DEFAULT = ["one_device", "jit_sharded", "vmap", "trainer", "shard_map", "shard_map_no_shardy"]
DEFAULT += [f"shard_map+{f}" for f in FLAGS]


OPS = ("gather", "scatter", "segment_sum", "quat", "fori", "empty_const", "empty_carry")
"""The ``op:<name>`` variants: a gather / scatter-add with NumPy indices, a ``segment_sum`` with NumPy segment ids,
quaternion products with a NumPy table of quaternions (as MJX's kinematics composes body frames), a ``fori_loop``
over a NumPy table, a closed-over zero-size constant (MJX's models and data hold many), a zero-size array in every
lane's loop state (as an ``mjx.Data`` carried in an env's state)."""


def op_roll(keys, steps: int, op: str):
    """[lanes] keys -> ([lanes, 64] values, [steps] mean): ``steps`` steps of operation ``op`` (:data:`OPS`)."""
    import jax
    import jax.numpy as jnp
    import numpy as np

    from jaxrl_robot import parallel

    if op not in OPS:
        raise SystemExit(f"op: {op!r} is not one of {', '.join(OPS)}")
    rng = np.random.default_rng(0)
    idx, seg = rng.integers(0, 64, 64), np.sort(rng.integers(0, 8, 64))
    table = rng.normal(size=(16, 4)).astype(np.float32)

    def quat_mul(u, v):  # [..., 4] x [..., 4] -> [..., 4], (w, x, y, z)
        w0, x0, y0, z0 = jnp.moveaxis(u, -1, 0)
        w1, x1, y1, z1 = jnp.moveaxis(v, -1, 0)
        w = w0 * w1 - x0 * x1 - y0 * y1 - z0 * z1
        x = w0 * x1 + x0 * w1 + y0 * z1 - z0 * y1
        y = w0 * y1 - x0 * z1 + y0 * w1 + z0 * x1
        return jnp.stack([w, x, y, w0 * z1 + x0 * y1 - y0 * x1 + z0 * w1], -1)

    def one(x):  # [64] -> [64]
        if op == "gather":
            return x[idx] * 0.5 + x
        if op == "scatter":
            return x.at[idx].add(0.1 * x)
        if op == "segment_sum":
            return x + jax.ops.segment_sum(x, seg, num_segments=8)[seg] * 0.1
        if op == "quat":
            q = quat_mul(table, x[:64].reshape(16, 4))
            return (q / jnp.linalg.norm(q, axis=-1, keepdims=True)).reshape(64)
        if op == "empty_const":
            return jnp.concatenate([x[:63], jnp.asarray(empty).reshape(-1), x[63:] + jnp.sum(empty)]) * 0.9
        return jax.lax.fori_loop(0, 16, lambda i, y: y * 0.9 + jnp.tile(jnp.asarray(table)[i], 16), x)

    empty = np.zeros((1, 0), np.float32)
    x = jax.vmap(lambda k: jax.random.normal(k, (64,)))(keys)
    if op == "empty_carry":  # [lanes, 64] and [lanes, 0] carried through the loop
        def step2(c, _):
            y, e = c
            y = jax.vmap(lambda v: jax.lax.fori_loop(0, 4, lambda i, w: w * 0.9 + 0.1, v))(y)
            return (y, e * 2.0), jnp.mean(y) + jnp.sum(e)

        (x, _), r = jax.lax.scan(step2, (x, jnp.zeros((x.shape[0], 0), jnp.float32)), None, length=steps)
        return x, parallel.pmean(r)

    def body(x, _):
        x = jax.vmap(one)(x)
        return x, jnp.mean(x)

    x, r = jax.lax.scan(body, x, None, length=steps)
    return x, parallel.pmean(r)


def constants_as_arguments(fn, *args, mesh=None) -> tuple:
    """``(g, consts)`` with ``g(consts, *args) == fn(*args)``: ``fn`` traced once on ``args``, every array it closes
    over moved from the traced program's constants into its argument ``consts`` (replicated over ``mesh``)."""
    import jax

    from jaxrl_robot import parallel

    closed, out_shape = jax.make_jaxpr(fn, return_shape=True)(*args)
    out_tree = jax.tree.structure(out_shape)

    def g(consts: list, *a):
        return jax.tree.unflatten(out_tree, jax.core.eval_jaxpr(closed.jaxpr, consts, *jax.tree.leaves(a)))

    consts = list(closed.consts)
    if mesh is not None:
        consts = jax.device_put(consts, parallel.NamedSharding(mesh, parallel.P()))
    return g, consts


def stage_fns(upto: str) -> list:
    """MJX's functions ``(model, data) -> data`` of :data:`STAGES` up to ``upto`` (``step`` / ``substeps``: alone)."""
    from mujoco import mjx
    from mujoco.mjx._src import solver

    if upto not in STAGES:
        raise SystemExit(f"stage: {upto!r} is not one of {', '.join(STAGES)}")
    if upto == "step":
        return [mjx.step]
    if upto == "substeps":
        return [lambda m, d: jax_fori(10, lambda d: mjx.step(m, d), d)]
    table = {"solve": solver.solve, **{n: getattr(mjx, n) for n in STAGES[:12]}}
    return [table[n] for n in STAGES[: STAGES.index(upto) + 1]]


def jax_fori(n: int, f, x):
    """``jax.lax.fori_loop`` of ``f`` over ``n`` steps, as the env's substeps."""
    import jax

    return jax.lax.fori_loop(0, n, lambda _, y: f(y), x)


def stage_model(how: str):
    """``arm7``'s MJX model and initial data; ``how``: ``""`` as the env holds them (device arrays closed over by
    the traced function), ``numpy``: the model's arrays NumPy arrays (constants embedded in the program) and the
    data's on no device in particular, ``uncommitted``: both on no device in particular."""
    import jax
    import jax.numpy as jnp
    import numpy as np

    import envs_mjx

    env = envs_mjx.make("arm7")
    m, d0 = env.mjx_model, env._data0
    if how == "numpy":
        m = jax.tree.map(lambda x: np.asarray(x) if isinstance(x, jax.Array) else x, m)
    if how in ("numpy", "uncommitted"):  # the data's arrays on no device in particular
        d0 = jax.tree.map(lambda x: jnp.asarray(np.asarray(x)) if isinstance(x, jax.Array) else x, d0)
    if how == "uncommitted":
        m = jax.tree.map(lambda x: jnp.asarray(np.asarray(x)) if isinstance(x, jax.Array) else x, m)
    return m, d0


def stage_roll(keys, steps: int, upto: str, model):
    """[lanes] keys -> ([lanes, 1] sum of each lane's float data, [steps] mean qacc): ``steps`` steps of the
    pipeline prefix ``upto`` (a suffix ``/...`` ignored) on ``arm7``'s MJX model, each lane from its own perturbed
    ``qpos``; ``model``: ``(m, d0)`` of :func:`stage_model`, closed over or passed in as arguments."""
    import jax
    import jax.numpy as jnp

    upto = upto.partition("/")[0]
    m, d0 = model
    fns = stage_fns(upto)

    def one(d):
        for f in fns:
            d = f(m, d)
        return d.replace(qpos=d.qpos + 1e-3 * jnp.tanh(d.qvel + d.qacc + d.xpos.sum()))

    d = jax.vmap(lambda k: d0.replace(qpos=d0.qpos + 0.05 * jax.random.normal(k, d0.qpos.shape)))(keys)

    def body(d, _):
        d = jax.vmap(one)(d)
        return d, jnp.mean(d.qacc)

    d, r = jax.lax.scan(body, d, None, length=steps)
    leaves = [x.reshape(x.shape[0], -1).sum(1) for x in jax.tree.leaves(d) if jnp.issubdtype(x.dtype, jnp.floating)
              and x.ndim >= 1 and x.shape[0] == keys.shape[0]]  # fmt: skip
    return jnp.stack(leaves, 1).sum(1, keepdims=True), r


def child(variant: str, lanes: int, steps: int) -> None:
    label = variant
    variant = {"shard_map_args": "shard_map@args"}.get(variant, variant)
    variant, hoist = variant.removesuffix("@args"), variant.endswith("@args")
    import jax
    import jax.numpy as jnp
    import numpy as np

    if variant == "shard_map_no_shardy":
        jax.config.update("jax_use_shardy_partitioner", False)
    import envs_mjx
    from envs_mjx.base import wrap_for_training
    from jaxrl_robot import parallel

    name, config = {"kinematic": ("arm7", {"mode": "kinematic"}), "unicycle": ("unicycle", {"mode": "dynamic"}),
                    "unicycle_kinematic": ("unicycle", {"mode": "kinematic"}),
                    "sparse": ("arm7", {"jacobian": "sparse"})}.get(variant, ("arm7", {}))  # fmt: skip
    env = envs_mjx.make(name, **config)
    wrapped = wrap_for_training(env, episode_length=50)
    n_dev = 1 if variant == "one_device" else len(jax.devices())
    mesh = parallel.lane_mesh(n_dev)
    act = jnp.full((env.action_size,), 0.1, jnp.float32)

    def factorise(keys):  # [lanes] keys -> ([lanes, 7] solutions, [steps] mean)
        a = jax.vmap(lambda k: jax.random.normal(k, (7, 7)))(keys)
        m = a @ jnp.swapaxes(a, -1, -2) + 7.0 * jnp.eye(7)

        def body(x, _):
            x = jax.scipy.linalg.cho_solve(jax.scipy.linalg.cho_factor(m), x + 1.0)
            return x, jnp.mean(x)

        x, r = jax.lax.scan(body, jnp.zeros(m.shape[:2]), None, length=steps)
        return x, parallel.pmean(r)

    # a stage variant's model and data, built before tracing (their arrays closed over by the traced function)
    built = stage_model(variant.partition("/")[2]) if variant.startswith("stage:") else None

    def roll(keys):
        if variant == "cholesky":
            return factorise(keys)
        if variant.startswith("stage:"):
            obs, r = stage_roll(keys, steps, variant.split(":", 1)[1], built)
            return obs, parallel.pmean(r)
        if variant.startswith("op:"):  # one kind of operation MJX's kinematics uses, on constant NumPy operands
            return op_roll(keys, steps, variant[3:])
        if variant.startswith("const"):  # a closed-over constant: NumPy, uncommitted or committed to device 0
            c = np.arange(64.0, dtype=np.float32)
            c = {"const_numpy": c, "const": jnp.asarray(c),
                 "const_device0": jax.device_put(c, jax.devices()[0])}[variant]
            x = jax.vmap(lambda k: jax.random.normal(k, (64,)))(keys)
            return x + jnp.take(c, jnp.arange(63, -1, -1)), parallel.pmean(jnp.mean(x * c, 1)[:steps])
        state = wrapped.reset(keys)

        def body(s, _):
            s = wrapped.step(s, jnp.broadcast_to(act, (s.obs.shape[0], env.action_size)))
            return s, jnp.mean(s.reward)

        state, r = jax.lax.scan(body, state, None, length=steps)
        # the mean reward over all lanes (inside shard_lanes, over every device's lanes)
        return state.obs, (r if variant == "jit_sharded" else parallel.pmean(r))

    keys = jax.random.split(jax.random.PRNGKey(0), lanes)
    if variant == "env_arg":  # the env's rollout, its model and initial data traced arguments of the mapped function
        model = jax.device_put((env.mjx_model, env._data0), parallel.NamedSharding(mesh, parallel.P()))

        def roll_with(k, mod):
            held = env.mjx_model, env._data0
            env.mjx_model, env._data0 = mod  # read while tracing: the traced arguments stand in for the constants
            try:
                return roll(k)
            finally:
                env.mjx_model, env._data0 = held

        spec_m = jax.tree.map(lambda _: parallel.P(), model)
        mapped = parallel.shard_lanes(roll_with, mesh, (parallel.P(parallel.LANES), spec_m),
                                      (parallel.P(parallel.LANES), parallel.P()), impl="shard_map")  # fmt: skip
        placed = jax.device_put(keys, parallel.lane_sharding(mesh))
        run_program(label, n_dev, lambda: (mapped, (placed, model)))
        return
    if variant.endswith("/arg"):  # the model as a replicated argument of the mapped function, not a constant
        model = jax.device_put(built, parallel.NamedSharding(mesh, parallel.P()))  # replicated
        spec_m = jax.tree.map(lambda _: parallel.P(), model)
        mapped = parallel.shard_lanes(lambda k, mod: pmean_second(stage_roll(k, steps, variant[6:-4], mod)), mesh,
                                      (parallel.P(parallel.LANES), spec_m), (parallel.P(parallel.LANES), parallel.P()))
        placed = jax.device_put(keys, parallel.lane_sharding(mesh))
        run_program(label, n_dev, lambda: (mapped, (placed, model)))
        return
    placed = jax.device_put(keys, parallel.lane_sharding(mesh))
    if variant == "jit_sharded":
        split = parallel.lane_sharding(mesh)
        fn = jax.jit(roll, in_shardings=split, out_shardings=(split, parallel.lane_sharding(mesh, False)))
    elif hoist:  # the arrays the mapped function closes over: arguments of the jitted program
        impl = {"trainer": None, "vmap": "vmap"}.get(variant, "shard_map")
        specs = (parallel.P(parallel.LANES), (parallel.P(parallel.LANES), parallel.P()))
        placed = jax.device_put(keys, parallel.lane_sharding(mesh))

        def hoisted():  # traced inside the compile clock
            g, consts = constants_as_arguments(parallel.shard_lanes(roll, mesh, *specs, impl=impl), placed, mesh=mesh)
            return g, (consts, placed)

        run_program(label, n_dev, hoisted)
        return
    else:
        impl = {"trainer": None, "vmap": "vmap"}.get(variant, "shard_map")
        specs = (parallel.P(parallel.LANES), (parallel.P(parallel.LANES), parallel.P()))
        fn = parallel.shard_lanes(roll, mesh, *specs, impl=impl)
    run_program(label, n_dev, lambda: (fn, (placed,)))


def run_program(label: str, n_dev: int, build) -> None:
    """``build() -> (fn, args)``, then ``fn`` jitted, lowered for ``args`` and compiled (all on the compile clock),
    called on ``args``, and its result line reported."""
    import jax

    t0 = time.perf_counter()
    fn, args = build()
    compiled = jax.jit(fn).lower(*args).compile()
    t1 = time.perf_counter()
    obs, r = compiled(*args)
    report(label, n_dev, t1 - t0, obs, r)


def pmean_second(pair: tuple) -> tuple:
    """``(a, b)`` -> ``(a, pmean(b))``: the second output averaged over every device's lanes."""
    from jaxrl_robot import parallel

    return pair[0], parallel.pmean(pair[1])


def report(variant: str, n_dev: int, compile_s: float, obs, r) -> None:
    """The variant's result line (JSON) on stdout, after its outputs are ready."""
    import jax
    import jax.numpy as jnp

    jax.block_until_ready(obs)
    print(json.dumps({"variant": variant, "devices": n_dev, "device_kind": jax.devices()[0].device_kind,
                      "platform": jax.devices()[0].platform, "compile_s": round(compile_s, 2),
                      "obs_sum": float(jnp.sum(obs)), "reward_last": float(r[-1])}))  # fmt: skip


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--variants", default=",".join(DEFAULT))
    p.add_argument("--lanes", type=positive, default=256)
    p.add_argument("--steps", type=positive, default=4)
    p.add_argument("--timeout", type=positive, default=300)
    p.add_argument("--out", default="")
    p.add_argument("--child", default="", help=argparse.SUPPRESS)
    provenance.add_args(p)
    a = p.parse_args()
    if a.child:
        child(a.child, a.lanes, a.steps)
        return
    # jax is not started here (the variants each start it in a process of their own): they report the device
    prov = provenance.record("benchmarks.multigpu_repro", seeds="PRNGKey(0) (fixed in the code)",
                             allow_dirty=a.allow_dirty,
                             device_info={"name": "not reported by any variant", "platform": "?"})  # fmt: skip
    rows = []
    for v in a.variants.split(","):
        env = dict(os.environ)
        if "+" in v:
            env["XLA_FLAGS"] = (env.get("XLA_FLAGS", "") + " " + FLAGS[v.split("+", 1)[1]]).strip()
        t0 = time.time()
        try:
            base = v.split("+")[0]
            cmd = [sys.executable, "-X", "faulthandler", "-m", "benchmarks.multigpu_repro", "--child", base,
                   "--lanes", str(a.lanes), "--steps", str(a.steps)]  # fmt: skip
            proc = subprocess.run(cmd, env=env, capture_output=True, text=True, timeout=a.timeout)
            rc, out, err = proc.returncode, proc.stdout, proc.stderr
        except subprocess.TimeoutExpired:
            rc, out, err = "timeout", "", ""
        result = {}
        for line in out.splitlines():
            if line.startswith("{"):
                result = json.loads(line)
        err = re.sub(r"\nExtension modules:[^\n]*", "", err)  # faulthandler's list of loaded modules
        rows.append({"variant": v, "rc": rc, "wall_s": round(time.time() - t0, 1), **result,
                     "stderr_tail": err[-3000:] if rc != 0 else ""})
        print(f"{v:40s} rc={rc!s:8s} {json.dumps(result)}", flush=True)
        if rc != 0:
            print("   " + err[-1200:].replace("\n", "\n   "), flush=True)
    ran = [r for r in rows if "device_kind" in r]
    if ran:
        n = max(r["devices"] for r in ran)
        prov["device"] = {"name": ran[0]["device_kind"], "platform": ran[0]["platform"], "count": n,
                          "cpu_cores": os.cpu_count()}  # fmt: skip
    if a.out:
        provenance.write(os.path.splitext(a.out)[0], {"provenance": prov, "lanes": a.lanes, "steps": a.steps,
                                                       "rows": rows}, to_markdown(rows))  # fmt: skip


def to_markdown(rows: list[dict]) -> str:
    """The variants' table: exit code, devices, compile s, wall s, observation sum and last reward."""
    lines = ["# MJX physics inside shard_map over several GPUs: the variants", "",
             "| variant | exit code | devices | compile s | wall s | obs sum | last reward |",
             "|---|---:|---:|---:|---:|---:|---:|"]  # fmt: skip
    for r in rows:
        cells = [r.get(k, "—") for k in ("devices", "compile_s", "wall_s", "obs_sum", "reward_last")]
        lines.append(f"| {r['variant']} | {r['rc']} | " + " | ".join(map(str, cells)) + " |")
    return "\n".join(lines) + "\n"


if __name__ == "__main__":
    main()
