"""Deterministic reproduction of asynchronous gradient pushes (A3C, thesis §4.1.1).

``W`` workers each hold a snapshot of the global parameters. After a round in which every
worker computed one gradient with its own snapshot, the gradients are applied to the global
parameters one after another in a push order, and each worker re-syncs its snapshot right
after its own push (Algorithm 3, lines 17-18). The **staleness** of an applied gradient is the
number of global updates between the worker's last sync and its push: the gradient delay.

>>> order = push_order(key, W, "fixed")
>>> state, staleness = push_in_order(state, grads, order, apply_fn, snapshot_of, local_ids)
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import jax
import jax.numpy as jnp
from flax import struct

__all__ = ["PushState", "init_push_state", "push_in_order", "push_order", "staleness_histogram"]


@struct.dataclass
class PushState:
    """The global side of asynchronous training.

    Attributes:
      global_: the global parameters together with whatever ``apply_fn`` updates (optimiser
        states, batch-norm statistics): any pytree.
      snapshots: ``[W_local, ...]`` the parameter snapshots of this device's workers.
      versions: ``[W]`` int32, the global update count at each worker's last sync.
      pushes: ``[]`` int32, global updates applied so far.
    """

    global_: Any
    snapshots: Any
    versions: jax.Array
    pushes: jax.Array


def init_push_state(global_: Any, snapshot: Any, num_workers: int) -> PushState:
    """All ``num_workers`` workers synced to ``snapshot`` (the global parameters) at update 0.

    ``snapshots`` gets a leading ``[W]`` axis; split it over devices by sharding that axis.
    """
    snapshots = jax.tree.map(lambda x: jnp.broadcast_to(x, (num_workers,) + jnp.shape(x)), snapshot)
    return PushState(
        global_=global_,
        snapshots=snapshots,
        versions=jnp.zeros((num_workers,), jnp.int32),
        pushes=jnp.zeros((), jnp.int32),
    )


def push_order(key: jax.Array, num_workers: int, order: str) -> jax.Array:
    """``[W]`` worker ids in push order: ``'fixed'`` 0, 1, …, W-1; ``'random'`` a permutation from ``key``."""
    if order == "fixed":
        return jnp.arange(num_workers, dtype=jnp.int32)
    if order == "random":
        return jax.random.permutation(key, num_workers).astype(jnp.int32)
    raise ValueError(f"push_order={order!r} is not valid; choose one of 'random', 'fixed'")


def push_in_order(
    state: PushState,
    grads: Any,
    order: jax.Array,
    apply_fn: Callable[[Any, Any], Any],
    snapshot_of: Callable[[Any], Any],
    local_ids: jax.Array,
) -> tuple[PushState, jax.Array]:
    """Apply every worker's gradient to the global parameters in ``order``, re-syncing each pusher.

    Args:
      state: the :class:`PushState` before the round.
      grads: ``[W, ...]`` one gradient (any pytree, e.g. with batch-norm statistic deltas)
        per worker, gathered from all devices and indexed by global worker id.
      order: ``[W]`` global worker ids in push order (a permutation).
      apply_fn: ``(global_, grad) -> global_``, one global update (an optimiser step).
      snapshot_of: ``global_ -> snapshot``, the part of the global state a worker copies.
      local_ids: ``[W_local]`` global ids of this device's workers, consecutive (a worker
        whose id is not local is pushed but its snapshot lives on another device).
    Returns:
      ``(state, staleness [W])``; ``staleness[j]`` belongs to the ``j``-th push.
    """
    num_local = local_ids.shape[0]
    first = local_ids[0]

    def push(carry: PushState, w: jax.Array) -> tuple[PushState, jax.Array]:
        staleness = carry.pushes - carry.versions[w]
        global_ = apply_fn(carry.global_, jax.tree.map(lambda g: g[w], grads))
        pushes = carry.pushes + 1
        slot = w - first
        is_local = (slot >= 0) & (slot < num_local)
        slot = jnp.clip(slot, 0, num_local - 1)
        fresh = snapshot_of(global_)

        def resync(snap: jax.Array, new: jax.Array) -> jax.Array:
            return snap.at[slot].set(jnp.where(is_local, new, snap[slot]))

        carry = PushState(
            global_=global_,
            snapshots=jax.tree.map(resync, carry.snapshots, fresh),
            versions=carry.versions.at[w].set(pushes),
            pushes=pushes,
        )
        return carry, staleness

    return jax.lax.scan(push, state, order)


def staleness_histogram(staleness: jax.Array, bins: int, max_staleness: int) -> tuple[list[int], jax.Array]:
    """Share of pushes per staleness bin.

    Bins have equal integer width ``ceil((max_staleness + 1) / bins)``; the last bin also
    collects everything beyond it.

    Args:
      staleness: ``[...]`` int staleness of applied gradients.
      bins: number of bins.
      max_staleness: the largest staleness the push schedule can produce.
    Returns:
      ``(lower edges [bins'], shares [bins'])`` with ``bins' <= bins`` (no empty tail bins).
    """
    width = max(1, -(-(max_staleness + 1) // bins))
    edges = list(range(0, max_staleness + 1, width))[:bins]
    idx = jnp.clip(staleness.reshape(-1) // width, 0, len(edges) - 1)
    counts = jnp.zeros((len(edges),), jnp.float32).at[idx].add(1.0)
    return edges, counts / jnp.maximum(jnp.sum(counts), 1.0)
