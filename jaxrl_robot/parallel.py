"""Devices: the lane mesh, ``shard_map`` over it, collectives. The only module that knows about devices.

Batch lanes (parallel workers) are split evenly over a 1-D device mesh whose axis is named
``"lanes"``. Code inside :func:`shard_lanes` sees its device's slice of the lanes and uses
:func:`pmean` / :func:`psum` to combine gradients and statistics, so parameters stay identical
on every device. With one device the same code runs unchanged (the collectives are no-ops).

On a CPU, ``XLA_FLAGS=--xla_force_host_platform_device_count=4`` (set before importing jax)
gives four devices for testing.
"""

from __future__ import annotations

from collections.abc import Callable, Sequence
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
from jax.sharding import Mesh, NamedSharding, PartitionSpec

__all__ = [
    "LANES",
    "P",
    "all_gather",
    "global_lane_ids",
    "initialize_multihost",
    "lane_mesh",
    "lane_sharding",
    "local_lane_count",
    "pmean",
    "psum",
    "shard_lanes",
]

LANES = "lanes"
P = PartitionSpec


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


def shard_lanes(fn: Callable[..., Any], mesh: Mesh, in_specs: Any, out_specs: Any) -> Callable[..., Any]:
    """``jax.shard_map`` over the lane mesh: ``P("lanes")`` splits a leading lane axis, ``P()`` replicates."""
    return jax.shard_map(fn, mesh=mesh, in_specs=in_specs, out_specs=out_specs, check_vma=False)


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


def initialize_multihost(**kwargs: Any) -> None:
    """Join a multi-host run (``jax.distributed.initialize``); call once before using devices.

    Each host then sees all global devices in ``jax.devices()``; fold ``jax.process_index()``
    into per-host keys.
    """
    jax.distributed.initialize(**kwargs)
