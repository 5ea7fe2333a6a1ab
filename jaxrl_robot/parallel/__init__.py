"""Devices: the lane mesh, ``shard_map`` over it, collectives. The only module that knows about devices.

Batch lanes (parallel workers) are split evenly over a 1-D device mesh whose axis is named
``"lanes"``. Code inside :func:`shard_lanes` sees its device's slice of the lanes and uses
:func:`pmean` / :func:`psum` to combine gradients and statistics, so parameters stay identical
on every device. With one device the same code runs unchanged (the collectives are no-ops).

On a CPU, ``XLA_FLAGS=--xla_force_host_platform_device_count=4`` (set before importing jax)
gives four devices for testing.

Two implementations of the lane map, one semantics
--------------------------------------------------
:func:`shard_lanes` gives ``fn`` a *per-device view*: ``fn`` sees ``[num_lanes / D, ...]`` of every
split input and combines over devices with the collectives of this module. It is built in one
of two ways (``impl``; the environment variable ``JAXRL_LANE_MAP`` overrides the default):

* ``"shard_map"`` — ``jax.shard_map``: XLA compiles ``fn`` once per device as a manually
  partitioned program. The default on a one-device mesh, and on several devices for envs that step no MJX
  physics.
* ``"vmap"`` — the split inputs are reshaped to ``[D, num_lanes / D, ...]``; ``fn`` is vmapped
  over the leading device axis with ``axis_name="lanes"`` (so ``pmean``/``psum``/``all_gather``/
  ``axis_index`` become reductions and gathers over that axis) and the axis is constrained to
  the mesh, so XLA's automatic SPMD partitioner places one slice per device and turns the
  reductions into all-reduces. The default on a mesh of several devices where MJX physics is mapped.

Why ``vmap`` on several devices where MJX physics is mapped: XLA:GPU (jax 0.11.2, two H200s) ends the process
with a segmentation fault while compiling a ``shard_map`` program over several GPUs that holds a zero-size constant,
and MJX's models and data hold dozens (``benchmarks/results/gpu-nvidia_h200x2-multigpu_repro-empty.md``; the
reproducer is ``python -m benchmarks.multigpu_repro``, each variant in its own process). :func:`shard_lanes` now
makes such arrays inside the program (:func:`_shard_map_no_empty_constants`), and MJX physics compiles and runs
under ``shard_map`` on two H200s (``arm7`` in ``pd`` mode with either Jacobian, ``unicycle`` in both modes, the
observations of one device; ``benchmarks/results/gpu-nvidia_h200x2-multigpu_repro-no-empty.md``); its speed there
is not measured yet, so MJX physics keeps ``vmap`` by default (``JAXRL_LANE_MAP=shard_map`` takes the other). The
partitioned ``vmap`` program can be far slower on GPUs: DDPG's single learner with HER on ``arm7`` in
``kinematic`` mode ran 25-29 k env-steps/s on two H200s under ``vmap`` against 1.17 M under ``shard_map`` and
1.16 M on one H200 (``benchmarks/results/gpu-nvidia_h200x4-lane_map-ddpg.md``). So the trainers take
``shard_map`` on several devices wherever the env declares that it steps no MJX physics
(``envs_mjx.base.steps_mjx_physics``; :func:`lane_map_impl`'s ``mjx_physics``), and ``vmap`` for MJX physics (and
for envs that declare nothing). Both implementations run the same arithmetic, so they agree up to float summation
order (``tests/agents/test_ppo_devices.py`` checks 4 fake CPU devices of either kind against one).

Runs over several processes (joining one, a lost process found at once) are :mod:`.multihost`'s, re-exported
here; this package is the only place in the library that asks JAX about devices and backends.
"""

from __future__ import annotations

import os
from collections.abc import Callable, Sequence
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
from jax.sharding import Mesh, NamedSharding, PartitionSpec

from jaxrl_robot.parallel.multihost import (
    exit_at_once,
    initialize_multihost,
    lost_peer,
    set_peer_loss_note,
    watch_peers,
)

__all__ = [
    "LANES",
    "P",
    "all_gather",
    "device_summary",
    "exit_at_once",
    "global_lane_ids",
    "initialize_multihost",
    "lane_map_impl",
    "lane_mesh",
    "lane_sharding",
    "local_lane_count",
    "local_sharding",
    "lost_peer",
    "on_accelerator",
    "on_gpu",
    "pmean",
    "psum",
    "set_peer_loss_note",
    "shard_lanes",
    "watch_peers",
]

LANES = "lanes"
P = PartitionSpec
IMPLS = ("shard_map", "vmap")
IMPL_ENV = "JAXRL_LANE_MAP"


def on_accelerator() -> bool:
    """Whether JAX's default backend is an accelerator (a GPU or TPU) rather than the CPU."""
    return jax.default_backend() != "cpu"


def on_gpu() -> bool:
    """Whether JAX's default backend is a GPU (where Pallas's Triton kernels run)."""
    return jax.default_backend() == "gpu"


def device_summary() -> list[tuple[int, str, str, int]]:
    """Every device of the run, in JAX's order, as ``(id, platform, kind, process index)``: what a compiled
    program is built for (part of the key of a program kept between processes)."""
    return [(d.id, d.platform, d.device_kind, d.process_index) for d in jax.devices()]


def local_sharding() -> jax.sharding.SingleDeviceSharding:
    """An array whole on this process's first device (e.g. where a checkpoint is restored to be read here)."""
    return jax.sharding.SingleDeviceSharding(jax.local_devices()[0])


def lane_mesh(num_devices: int | None = None, devices: Sequence[jax.Device] | None = None) -> Mesh:
    """A 1-D mesh named ``"lanes"`` over ``devices`` (default: the first ``num_devices`` devices, or all)."""
    devs = list(jax.devices() if devices is None else devices)
    if num_devices is not None:
        if not 1 <= num_devices <= len(devs):
            raise ValueError(f"num_devices={num_devices} is out of range; allowed [1, {len(devs)}]")
        devs = devs[:num_devices]
    return Mesh(np.array(devs), (LANES,))


def local_lane_count(num_lanes: int, mesh: Mesh) -> int:
    """Lanes per device; raises a clear error unless ``num_lanes`` divides evenly over the mesh."""
    n = mesh.shape[LANES]
    if num_lanes % n:
        raise ValueError(f"num_envs={num_lanes} must be a multiple of the number of devices ({n})")
    return num_lanes // n


def lane_sharding(mesh: Mesh, split: bool = True) -> NamedSharding:
    """Sharding that splits the leading axis over the lanes (``split``) or replicates."""
    return NamedSharding(mesh, P(LANES) if split else P())


def lane_map_impl(mesh: Mesh, impl: str | None = None, mjx_physics: bool = True) -> str:
    """The lane-map implementation for ``mesh``: ``impl``, else ``$JAXRL_LANE_MAP``, else by mesh and env.

    One device, or a mapped function that steps no MuJoCo MJX physics (``mjx_physics=False``, e.g. an env
    whose ``steps_mjx_physics`` is False): ``"shard_map"``; MJX physics on several devices: ``"vmap"``
    (see the module docstring for why).
    """
    impl = impl or os.environ.get(IMPL_ENV, "").strip() or None
    if impl is None:
        return "shard_map" if mesh.devices.size == 1 or not mjx_physics else "vmap"
    if impl not in IMPLS:
        raise ValueError(f"{IMPL_ENV}={impl!r} is not a lane-map implementation; valid: {', '.join(IMPLS)}")
    return impl


def shard_lanes(
    fn: Callable[..., Any], mesh: Mesh, in_specs: Any, out_specs: Any, *, impl: str | None = None
) -> Callable[..., Any]:
    """Map ``fn`` over the lane mesh: ``P("lanes")`` splits a leading lane axis, ``P()`` replicates.

    ``in_specs`` is a tuple with one spec-tree per positional argument (a prefix of the argument's
    pytree); ``out_specs`` a spec-tree prefix of the output. ``fn`` sees this device's slice of
    every split input and may call :func:`pmean`, :func:`psum`, :func:`all_gather` and
    :func:`global_lane_ids`. A ``P()`` output must be the same on every device (the first
    device's value is returned). ``impl``: ``"shard_map"`` or ``"vmap"`` (default:
    :func:`lane_map_impl`).
    """
    if lane_map_impl(mesh, impl) != "shard_map":
        return _vmap_lanes(fn, mesh, in_specs, out_specs)
    if mesh.shape[LANES] == 1:
        return jax.shard_map(fn, mesh=mesh, in_specs=in_specs, out_specs=out_specs, check_vma=False)
    return _shard_map_no_empty_constants(fn, mesh, in_specs, out_specs)


def _shard_map_no_empty_constants(fn: Callable[..., Any], mesh: Mesh, in_specs: Any, out_specs: Any) -> Callable:
    """``jax.shard_map`` of ``fn`` over several devices, each zero-size array ``fn`` closes over made inside the
    mapped program (``jnp.zeros``) instead of being one of its constants.

    XLA:GPU dies (segmentation fault) compiling a ``shard_map`` program over several GPUs that holds a zero-size
    constant, and compiles one that makes the same array inside it
    (``benchmarks/results/gpu-nvidia_h200x2-multigpu_repro-empty.md``); MJX's models and data hold dozens of
    zero-size arrays, and an env's state can carry an ``mjx.Data``. ``fn`` is traced once on this device's slice
    of the inputs (``jax.make_jaxpr`` with the lane axis bound); without zero-size constants it is mapped as it is.
    """
    num = mesh.shape[LANES]

    def local(spec: PartitionSpec, x: Any) -> jax.ShapeDtypeStruct:
        shape = tuple(np.shape(x))
        if _is_split(spec):
            _check_split(shape, num)
            shape = (shape[0] // num,) + shape[1:]
        return jax.ShapeDtypeStruct(shape, x.dtype if hasattr(x, "dtype") else jnp.result_type(x))

    def mapped(*args: Any) -> Any:
        specs = _arg_specs(in_specs, args)
        shapes = [jax.tree.map(lambda s, a: jax.tree.map(lambda x: local(s, x), a), t, a, is_leaf=_is_spec)
                  for t, a in zip(specs, args, strict=True)]  # fmt: skip
        closed, out_shape = jax.make_jaxpr(fn, axis_env=[(LANES, num)], return_shape=True)(*shapes)
        empty = [i for i, c in enumerate(closed.consts) if np.size(c) == 0]
        if not empty:
            return jax.shard_map(fn, mesh=mesh, in_specs=in_specs, out_specs=out_specs, check_vma=False)(*args)
        out_tree = jax.tree.structure(out_shape)

        def body(*xs: Any) -> Any:
            consts = list(closed.consts)
            for i in empty:
                consts[i] = jnp.zeros(np.shape(consts[i]), consts[i].dtype)
            return jax.tree.unflatten(out_tree, jax.core.eval_jaxpr(closed.jaxpr, consts, *jax.tree.leaves(xs)))

        return jax.shard_map(body, mesh=mesh, in_specs=in_specs, out_specs=out_specs, check_vma=False)(*args)

    return mapped


def _arg_specs(in_specs: Any, args: tuple) -> tuple:
    """One spec-tree per positional argument: ``in_specs`` itself when it is one spec for every argument."""
    specs = (in_specs,) * len(args) if _is_spec(in_specs) else tuple(in_specs)
    if len(specs) != len(args):
        raise ValueError(f"in_specs has {len(specs)} entries for {len(args)} arguments")
    return specs


def _check_split(shape: tuple, num: int) -> None:
    """A ``P("lanes")`` input's leading axis must split evenly over ``num`` devices."""
    if not shape or shape[0] % num:
        raise ValueError(f"a P('lanes') input of shape {shape} does not split over {num} devices")


def _is_spec(x: Any) -> bool:
    return isinstance(x, PartitionSpec)


def _is_split(spec: PartitionSpec) -> bool:
    if len(spec) == 0 or spec[0] is None:
        return False
    if spec[0] != LANES or any(s is not None for s in spec[1:]):
        raise ValueError(f"lane specs are P('lanes') or P(); got {spec}")
    return True


def _vmap_lanes(fn: Callable[..., Any], mesh: Mesh, in_specs: Any, out_specs: Any) -> Callable[..., Any]:
    """:func:`shard_lanes` as ``vmap`` over a ``[D]`` device axis partitioned by XLA (module docstring)."""
    num = mesh.shape[LANES]
    split_sharding = NamedSharding(mesh, P(LANES))
    replicated = NamedSharding(mesh, P())

    def to_devices(x: jax.Array) -> jax.Array:
        x = jnp.asarray(x)
        _check_split(x.shape, num)
        x = x.reshape((num, x.shape[0] // num) + x.shape[1:])
        return jax.lax.with_sharding_constraint(x, split_sharding)

    def from_devices(x: jax.Array) -> jax.Array:
        x = jax.lax.with_sharding_constraint(x, split_sharding)
        return jax.lax.with_sharding_constraint(x.reshape((x.shape[0] * x.shape[1],) + x.shape[2:]), split_sharding)

    def first(x: jax.Array) -> jax.Array:
        return jax.lax.with_sharding_constraint(x[0], replicated)

    def mapped(*args: Any) -> Any:
        specs = _arg_specs(in_specs, args)
        ins, axes = [], []
        for spec_tree, arg in zip(specs, args, strict=True):
            split = jax.tree.map(lambda s, a: jax.tree.map(lambda _: _is_split(s), a), spec_tree, arg, is_leaf=_is_spec)
            ins.append(jax.tree.map(lambda sp, a: to_devices(a) if sp else a, split, arg))
            axes.append(jax.tree.map(lambda sp: 0 if sp else None, split))
        out = jax.vmap(fn, in_axes=tuple(axes), out_axes=0, axis_name=LANES, spmd_axis_name=LANES)(*ins)
        return jax.tree.map(
            lambda s, o: jax.tree.map(from_devices if _is_split(s) else first, o), out_specs, out, is_leaf=_is_spec
        )

    return mapped


def pmean(tree: Any, axis_name: str = LANES) -> Any:
    """Mean over devices of every leaf (inside :func:`shard_lanes`)."""
    return jax.lax.pmean(tree, axis_name)


def psum(tree: Any, axis_name: str = LANES) -> Any:
    """Sum over devices of every leaf (inside :func:`shard_lanes`)."""
    return jax.lax.psum(tree, axis_name)


def all_gather(tree: Any, axis_name: str = LANES) -> Any:
    """Every leaf's leading axis concatenated over devices, in device order (inside :func:`shard_lanes`).

    ``[n_local, ...]`` on each device -> ``[n_local * devices, ...]`` on every device.
    """
    return jax.lax.all_gather(tree, axis_name, tiled=True)


def global_lane_ids(num_local: int, axis_name: str = LANES) -> jax.Array:
    """``[num_local]`` global indices of this device's lanes (inside :func:`shard_lanes`)."""
    return jax.lax.axis_index(axis_name) * num_local + jnp.arange(num_local)
