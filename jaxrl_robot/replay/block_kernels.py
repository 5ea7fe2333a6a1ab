"""The Pallas (Triton) kernels of :mod:`jaxrl_robot.replay.block_tree`: a whole stratified sample, and a
whole priority update, in one kernel each.

* :func:`sample` runs ``⌈m / G⌉`` programs of ``G`` queries; each computes the running sums of the ``K``
  block sums and of its queries' leaf rows in registers (the descent of ``block_tree``).
* :func:`update` runs one program per batch row; the first valid row of each touched block owns the block:
  it writes that block's leaves (the last occurrence of each index), synchronises its threads and sums
  the block from its leaves, so no two programs touch one block.  With a :class:`~block_tree.PriorityRule`
  it is a prioritised replay's whole update (``(|δ| + ε)^α``, the largest priority, β).

``interpret=True`` runs them with the Pallas interpreter (the tests on a CPU).  Pure functions; nothing is
jitted here.
"""

from __future__ import annotations

import functools
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
from jax.experimental import pallas as pl
from jax.experimental.pallas import triton as plgpu

from jaxrl_robot.replay.block_tree import (
    BlockTreeState,
    PriorityRule,
    _apply_rule,
    _descend,
    _last_occurrence,
    _pow2_at_least,
    _queries,
    next_scalars,
)

__all__ = ["sample", "update"]

GROUP = 4
"""Queries per program of the sampling kernel."""
SAMPLE_WARPS = 2
"""Warps per program of the sampling kernel."""
UPDATE_WARPS = 2
"""Warps per program of the update kernel."""


def sample(u: jax.Array, state: BlockTreeState, interpret: bool) -> tuple[jax.Array, jax.Array]:
    """The leaves of the stratified queries of uniforms ``u [m]``: ``([m] int32 indices, [m] priorities)``."""
    m = u.shape[0]
    group = min(GROUP, _pow2_at_least(m))
    padded = -(-m // group) * group
    u = jnp.pad(u, (0, padded - m))
    size, dtype = state.block_size, state.leaf_values.dtype

    def kernel(u_ref, bs_ref, leaves_ref, idx_ref, prio_ref):
        start = pl.program_id(0) * group
        block_sums = bs_ref[...]
        q = _queries(u_ref[pl.ds(start, group)], jnp.sum(block_sums), start, m)
        cols = jax.lax.broadcasted_iota(jnp.int32, (1, size), 1)
        idx, prio = _descend(block_sums, lambda k: leaves_ref[k[:, None] * size + cols], q, size)
        idx_ref[pl.ds(start, group)] = idx
        prio_ref[pl.ds(start, group)] = prio

    idx, prio = pl.pallas_call(
        kernel,
        out_shape=(jax.ShapeDtypeStruct((padded,), jnp.int32), jax.ShapeDtypeStruct((padded,), dtype)),
        grid=(padded // group,),
        interpret=interpret,
        compiler_params=None if interpret else plgpu.CompilerParams(num_warps=SAMPLE_WARPS),
        name="block_tree_sample",
    )(u, state.block_sums, state.leaf_values)
    return idx[:m], prio[:m]


class _Update(NamedTuple):
    """The static settings of one update kernel: its inputs by name (``valid``, ``keep``, ``scalars`` and
    ``limit`` only where given), the padded batch, the tree's capacity and block size, the rule."""

    names: tuple[str, ...]
    padded: int
    capacity: int
    block_size: int
    rule: PriorityRule | None
    interpret: bool


def update(
    state: BlockTreeState, indices: jax.Array, values: jax.Array, valid: jax.Array | None, keep: jax.Array | None,
    interpret: bool, rule: PriorityRule | None = None, scalars: jax.Array | None = None,
    stored: jax.Array | None = None,
) -> tuple[BlockTreeState, jax.Array | None]:  # fmt: skip
    """The update kernel: one program per batch row ``[B]``; the first valid row of each touched block owns it.

    A row is valid where ``valid`` (all when None) and ``0 <= index < min(capacity, stored)``; ``keep``: the
    rows to write (None: the last occurrence of each valid index, found in the kernel).  With ``rule``, every
    program reads ``scalars`` (aliased, written by program 0): see :func:`~block_tree.raw_priorities`.
    Returns the tree and, with ``scalars``, the new scalars.
    """
    n = indices.shape[0]
    padded = _pow2_at_least(n)
    pad = (0, padded - n)
    if padded != n:
        indices, values = jnp.pad(indices, pad), jnp.pad(values, pad)
        valid = jnp.pad(jnp.ones((n,), bool) if valid is None else valid, pad)
        keep = None if keep is None else jnp.pad(keep, pad)
    limit = None if stored is None else jnp.reshape(stored.astype(jnp.int32), (1,))
    optional = {"valid": valid, "keep": keep, "scalars": scalars, "limit": limit}
    names = ("indices", "values", *(k for k, v in optional.items() if v is not None), "leaves", "sums")
    spec = _Update(names, padded, state.capacity, state.block_size, rule, interpret)
    args = [indices, values, *(v for v in optional.values() if v is not None), state.leaf_values, state.block_sums]
    out_shape = [jax.ShapeDtypeStruct(state.leaf_values.shape, state.leaf_values.dtype),
                 jax.ShapeDtypeStruct(state.block_sums.shape, state.block_sums.dtype)]  # fmt: skip
    aliases = {len(args) - 2: 0, len(args) - 1: 1}
    if scalars is not None:
        out_shape.append(jax.ShapeDtypeStruct(scalars.shape, scalars.dtype))
        aliases[names.index("scalars")] = 2
    outs = pl.pallas_call(
        functools.partial(_update_kernel, spec),
        out_shape=tuple(out_shape),
        grid=(padded,),
        input_output_aliases=aliases,
        interpret=interpret,
        compiler_params=None if interpret else plgpu.CompilerParams(num_warps=UPDATE_WARPS),
        name="block_tree_set",
    )(*args)
    return state.replace(leaf_values=outs[0], block_sums=outs[1]), (outs[2] if scalars is not None else None)


def _update_kernel(spec: _Update, *refs: Any) -> None:
    """The program of batch row ``i``: its row's validity and value; program 0 writes the scalars."""
    ref = dict(zip(spec.names, refs[: len(spec.names)], strict=True))
    out = dict(zip(["leaves", "sums", "scalars"], refs[len(spec.names) :], strict=False))
    i = pl.program_id(0)
    idx = ref["indices"][...]
    given = ref["valid"][...] if "valid" in ref else jnp.ones((spec.padded,), bool)
    ok = given & (idx >= 0) & (idx < spec.capacity)
    if "limit" in ref:
        ok = ok & (idx < jnp.sum(ref["limit"][...]))
    largest = None
    if "scalars" in ref:
        pos = jax.lax.broadcasted_iota(jnp.int32, (2,), 0)
        largest = jnp.sum(jnp.where(pos == 0, ref["scalars"][...], 0))
    val, raw = _apply_rule(ref["values"][...], spec.rule, spec.capacity, largest, ok)
    if "scalars" in ref:

        @pl.when(i == 0)
        def _():
            out["scalars"][...] = next_scalars(ref["scalars"][...], raw, ok, spec.rule)

    _own_block(spec, ref, out, i, idx, given, ok, val)


def _own_block(
    spec: _Update, ref: dict, out: dict, i: jax.Array, idx: jax.Array, given: jax.Array, ok: jax.Array,
    val: jax.Array,
) -> None:
    """Where row ``i`` is the first valid row of its block: write the block's leaves, then its sum."""
    size, padded = spec.block_size, spec.padded
    block = idx // size
    me = jax.lax.broadcasted_iota(jnp.int32, (padded,), 0)
    k = jnp.sum(jnp.where(me == i, block, 0))
    mine = ok & (block == k)
    first_of_block = jnp.min(jnp.where(mine, me, padded)) == i  # this row owns its block

    @pl.when(first_of_block)
    def _():
        # equal indices are equally in range: only the given rows decide which repeat is the last
        write = mine & (_last_occurrence(idx, given) if "keep" not in ref else ref["keep"][...])
        # rows not written store a written row's value at its slot: an unmasked store is the same
        # on the GPU and in the interpreter (whose masked store writes old values back)
        r = jnp.min(jnp.where(write, me, padded))
        target = jnp.where(write, idx, jnp.sum(jnp.where(me == r, idx, 0)))
        out["leaves"][target] = jnp.where(write, val, jnp.sum(jnp.where(me == r, val, 0)))
        if not spec.interpret:
            plgpu.debug_barrier()  # the block's writes are visible to every thread of this program
        cols = jax.lax.broadcasted_iota(jnp.int32, (size,), 0)
        row = plgpu.load(out["leaves"].at[k * size + cols], volatile=True)  # not from a stale L1 line
        out["sums"][pl.ds(k, 1)] = jnp.sum(row, keepdims=True)
