"""Two-level block tree: exact leaves after batched updates with repeats, block sums from the leaves,
zero slots unreachable, and the Pallas kernels (run by the interpreter) equal to the XLA path."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from jaxrl_robot.replay import block_tree

BACKENDS = ("xla", "interpret")
BATCH = 12
CAPACITY = 70  # blocks of 16: 5 blocks, padded to 8


def _compiled(backend):
    return {
        "set": jax.jit(lambda t, i, v, m: block_tree.set(t, i, v, m, backend=backend)),
        "sample": jax.jit(lambda k, t: block_tree.stratified_sample_with_priorities(k, t, 64, backend=backend)),
    }


FNS = {b: _compiled(b) for b in BACKENDS}


def _check_sums(tree):
    """Every block sum is the sum of its leaves (float32 rounding only); empty blocks are exactly 0."""
    leaves = np.asarray(tree.leaf_values, np.float64).reshape(-1, tree.block_size)
    np.testing.assert_allclose(np.asarray(tree.block_sums), leaves.sum(1), rtol=1e-5, atol=1e-6)
    assert np.all(np.asarray(tree.block_sums)[leaves.sum(1) == 0] == 0)


@st.composite
def updates(draw):
    batches = []
    for _ in range(draw(st.integers(1, 4))):
        n = draw(st.integers(1, BATCH))
        hi = draw(st.sampled_from([5, CAPACITY - 1]))  # few distinct indices: repeats in one batch
        idx = draw(st.lists(st.integers(0, hi), min_size=n, max_size=n))
        vals = draw(st.lists(st.floats(0.0, 100.0, allow_subnormal=False, width=32), min_size=n, max_size=n))
        batches.append((idx, vals))
    return batches


@settings(max_examples=25, deadline=None)
@given(updates())
def test_leaves_follow_sequential_semantics_and_sums_follow_leaves(batches):
    trees = {b: block_tree.init(CAPACITY) for b in BACKENDS}
    reference = np.zeros(CAPACITY, np.float32)
    for idx, vals in batches:
        pad = BATCH - len(idx)
        args = (jnp.asarray(idx + [0] * pad, jnp.int32), jnp.asarray(vals + [5.0] * pad, jnp.float32),
                jnp.arange(BATCH) < len(idx))  # fmt: skip
        trees = {b: FNS[b]["set"](t, *args) for b, t in trees.items()}
        for i, v in zip(idx, vals, strict=True):  # the last write wins
            reference[i] = v
    for tree in trees.values():
        np.testing.assert_array_equal(np.asarray(tree.leaves), reference)
        _check_sums(tree)
    np.testing.assert_array_equal(np.asarray(trees["xla"].block_sums), np.asarray(trees["interpret"].block_sums))


def test_find_intervals_and_the_descent_by_hand():
    tree = block_tree.init(6, block_size=2)  # blocks [1, 0] [2, 0] [0, 3] (+ one empty block)
    tree = FNS["xla"]["set"](tree, jnp.arange(6), jnp.array([1.0, 0.0, 2.0, 0.0, 0.0, 3.0]), jnp.ones(6, bool))
    np.testing.assert_array_equal(np.asarray(tree.block_sums), [1, 2, 3, 0])
    queries = jnp.array([0.0, 0.5, 0.999, 1.0, 2.999, 3.0, 5.999, 6.0, 7.5, -1.0])
    np.testing.assert_array_equal(np.asarray(block_tree.find(tree, queries)), [0, 0, 0, 2, 2, 5, 5, 5, 5, 0])
    # stratified: 6 segments of width 1 -> leaves 0 | 2 2 | 5 5 5, with the priorities returned
    for backend in BACKENDS:
        idx, prio = block_tree.stratified_sample_with_priorities(jax.random.PRNGKey(0), tree, 6, backend=backend)
        np.testing.assert_array_equal(np.asarray(idx), [0, 2, 2, 5, 5, 5])
        np.testing.assert_array_equal(np.asarray(prio), [1, 2, 2, 3, 3, 3])


@pytest.mark.parametrize("backend", BACKENDS)
def test_zero_and_unwritten_slots_never_sampled_and_nothing_drifts(backend):
    tree = block_tree.init(1000)
    fn = FNS[backend]
    ones = jnp.ones(BATCH, bool)
    rng = np.random.default_rng(0)
    for _ in range(30):  # values over 10 orders of magnitude, then every one of them cleared
        idx = jnp.asarray(rng.integers(0, 1000, BATCH), jnp.int32)
        tree = fn["set"](tree, idx, jnp.asarray(10.0 ** rng.uniform(-3, 7, BATCH), jnp.float32), ones)
        tree = fn["set"](tree, idx, jnp.zeros(BATCH), ones)
    assert float(block_tree.total(tree)) == 0.0  # an incremental tree keeps rounding debris here
    written = jnp.array([3, 400, 401, 998] + [401] * (BATCH - 4))
    tree = fn["set"](tree, written, jnp.array([1e-30, 1e-3, 5.0, 2e-7] + [5.0] * (BATCH - 4)), ones)
    _check_sums(tree)
    allowed = {3, 400, 401, 998}
    total = block_tree.total(tree)
    edge = jnp.stack([total, jnp.nextafter(total, 0.0), total * 1.0001, jnp.asarray(0.0)])
    assert set(np.asarray(block_tree.find(tree, edge)).tolist()) <= allowed
    sampled = jnp.concatenate([fn["sample"](jax.random.PRNGKey(s), tree)[0] for s in range(20)])
    assert set(np.unique(np.asarray(sampled)).tolist()) <= allowed
    assert np.mean(np.asarray(sampled) == 401) > 0.99


def test_kernel_and_xla_agree_on_a_long_random_history():
    trees = {b: block_tree.init(3000, block_size=64) for b in BACKENDS}
    set_ = {b: jax.jit(lambda t, i, v, m, b=b: block_tree.set(t, i, v, m, backend=b)) for b in BACKENDS}
    rng = np.random.default_rng(1)
    for step in range(40):
        n = 32
        idx = jnp.asarray(rng.integers(0, 3000 if step % 2 else 100, n), jnp.int32)
        vals = jnp.asarray(rng.exponential(size=n) * (rng.random(n) > 0.3), jnp.float32)
        mask = jnp.asarray(rng.random(n) > 0.1)
        trees = {b: set_[b](t, idx, vals, mask) for b, t in trees.items()}
    x, k = trees["xla"], trees["interpret"]
    np.testing.assert_array_equal(np.asarray(x.leaf_values), np.asarray(k.leaf_values))
    np.testing.assert_allclose(np.asarray(x.block_sums), np.asarray(k.block_sums), rtol=1e-6)  # summation order
    _check_sums(x)
    key = jax.random.PRNGKey(2)
    s = [block_tree.stratified_sample_with_priorities(key, t, 100, backend=b) for b, t in trees.items()]
    # the same leaves, up to a query within rounding of a boundary (none on the CPU)
    assert np.mean(np.asarray(s[0][0]) == np.asarray(s[1][0])) >= 0.97
    for idx, prio in s:
        np.testing.assert_array_equal(np.asarray(prio), np.asarray(x.leaf_values)[np.asarray(idx)])
        assert np.all(np.asarray(prio) > 0)


@pytest.mark.parametrize("backend", BACKENDS)
def test_fused_priority_update_by_hand(backend):
    rule = block_tree.PriorityRule(alpha=0.5, eps=0.0, beta_increment=0.25)
    tree = block_tree.init(8, block_size=4)
    scalars = jnp.array([1.0, 0.5])
    tree, scalars = block_tree.set_priorities(tree, jnp.array([1, 6, 1]), jnp.array([-9.0, 0.25, 16.0]), scalars,
                                              rule, backend=backend)  # fmt: skip
    np.testing.assert_allclose(np.asarray(tree.leaves), [0, 4, 0, 0, 0, 0, 0.5, 0], rtol=1e-6)  # |δ|^0.5, last wins
    np.testing.assert_allclose(np.asarray(tree.block_sums), [4, 0.5], rtol=1e-6)
    np.testing.assert_allclose(np.asarray(scalars), [16.0, 0.75])  # the largest raw priority of the batch
    tree, scalars = block_tree.set_priorities(tree, jnp.array([0]), jnp.array([1.0]), scalars, rule, backend=backend)
    np.testing.assert_allclose(np.asarray(scalars), [16.0, 1.0])  # β stops at 1


def test_unique_writes_large_batches_and_bad_input():
    # fresh ring slots: distinct, masked rows ignored; a batch above the kernel's size takes the XLA path
    tree = block_tree.set(block_tree.init(10), jnp.array([4, 9, 4]), jnp.array([2.0, 3.0, 7.0]),
                          jnp.array([True, True, False]), unique_indices=True, backend="interpret")  # fmt: skip
    np.testing.assert_array_equal(np.asarray(tree.leaves), [0, 0, 0, 0, 2, 0, 0, 0, 0, 3])
    n = block_tree.KERNEL_BATCH_MAX + 100
    idx = jnp.asarray(np.random.default_rng(2).integers(0, 50, n), jnp.int32)
    big = block_tree.set(block_tree.init(50), idx, jnp.arange(n, dtype=jnp.float32), backend="interpret")
    last = {int(i): float(v) for v, i in enumerate(np.asarray(idx))}
    np.testing.assert_array_equal(np.asarray(big.leaves)[list(last)], list(last.values()))
    _check_sums(big)
    with pytest.raises(ValueError, match="capacity=0"):
        block_tree.init(0)
    with pytest.raises(ValueError, match="block_size=12 must be a power of two"):
        block_tree.init(100, block_size=12)
    with pytest.raises(ValueError, match=r"backend='cuda' is not one of \('auto', 'pallas', 'xla', 'interpret'\)"):
        block_tree.set(block_tree.init(4), jnp.array([0]), jnp.array([1.0]), backend="cuda")
