"""Sum-tree: exact sums after batched updates with repeats, no drift, zero slots unreachable."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from jaxrl_robot.replay import sum_tree

_set = jax.jit(sum_tree.set)  # compiled once per (tree shape, batch shape)
_find = jax.jit(sum_tree.find)
BATCH = 12


def _check_consistent(tree):
    """Every block of running sums is the left-to-right float32 sum of its children; the root is the leaf sum."""
    levels = tree.levels  # node sums, root first
    for level in range(tree.depth, 0, -1):
        children = np.asarray(levels[level], np.float32).reshape(-1, tree.branching)
        running = np.asarray(tree.prefix[level - 1]).reshape(-1, tree.branching)
        if tree.branching <= sum_tree.UNROLL_MAX:  # sequential adds: exactly numpy's float32 cumsum
            np.testing.assert_array_equal(running, np.cumsum(children, axis=-1, dtype=np.float32))
        else:
            np.testing.assert_allclose(running, np.cumsum(children.astype(np.float64), axis=-1), rtol=1e-5, atol=1e-6)
        assert np.all(np.diff(running, axis=-1) >= 0)  # non-decreasing along every block
        sums = np.asarray(levels[level], np.float64).reshape(-1, tree.branching).sum(-1)
        np.testing.assert_allclose(np.asarray(levels[level - 1]), sums, rtol=1e-5, atol=1e-6)
    np.testing.assert_allclose(float(sum_tree.total(tree)), np.asarray(tree.leaves, np.float64).sum(), rtol=1e-5)


@st.composite
def tree_updates(draw):
    capacity = draw(st.sampled_from([1, 7, 70]))
    branching = draw(st.sampled_from([2, 3, 16, 64]))  # 64: the cumsum + cummax blocks
    batches = []
    for _ in range(draw(st.integers(1, 4))):
        n = draw(st.integers(1, BATCH))
        # few distinct indices so that one batch repeats some of them
        idx = draw(st.lists(st.integers(0, min(capacity - 1, 5)), min_size=n, max_size=n))
        if draw(st.booleans()):
            idx = draw(st.lists(st.integers(0, capacity - 1), min_size=n, max_size=n))
        value = st.floats(0.0, 100.0, allow_nan=False, allow_subnormal=False, width=32)
        vals = draw(st.lists(value, min_size=n, max_size=n))
        batches.append((idx, vals))
    return capacity, branching, batches


@settings(max_examples=40, deadline=None)
@given(tree_updates())
def test_root_is_sum_of_leaves_after_batched_updates_with_duplicates(case):
    capacity, branching, batches = case
    tree = sum_tree.init(capacity, branching)
    reference = np.zeros(capacity)
    for idx, vals in batches:
        pad = BATCH - len(idx)  # fixed shapes: padded rows are masked out
        mask = jnp.arange(BATCH) < len(idx)
        tree = _set(tree, jnp.asarray(idx + [0] * pad, jnp.int32), jnp.asarray(vals + [5.0] * pad, jnp.float32), mask)
        for i, v in zip(idx, vals, strict=True):  # sequential semantics: the last write wins
            reference[i] = v
    np.testing.assert_allclose(np.asarray(tree.leaves), reference.astype(np.float32))
    _check_consistent(tree)


def test_last_occurrence_wins_and_mask_ignores_rows():
    tree = sum_tree.init(8, 2)
    tree = _set(tree, jnp.array([5, 2, 5, 5, 2]), jnp.array([1.0, 2.0, 3.0, 4.0, 7.0]))
    np.testing.assert_array_equal(np.asarray(tree.leaves), [0, 0, 7, 0, 0, 4, 0, 0])
    tree = _set(tree, jnp.array([1, 2]), jnp.array([9.0, 1.0]), mask=jnp.array([False, True]))
    np.testing.assert_array_equal(np.asarray(tree.leaves), [0, 0, 1, 0, 0, 4, 0, 0])
    assert float(sum_tree.total(tree)) == 5.0
    # negative priorities are stored as zero
    tree = _set(tree, jnp.array([5]), jnp.array([-3.0]))
    assert float(sum_tree.total(tree)) == 1.0


def test_find_intervals_follow_prefix_sums():
    tree = _set(sum_tree.init(6, 2), jnp.arange(6), jnp.array([1.0, 0.0, 2.0, 0.0, 0.0, 3.0]))
    queries = jnp.array([0.0, 0.5, 0.999, 1.0, 2.999, 3.0, 5.999])
    np.testing.assert_array_equal(np.asarray(_find(tree, queries)), [0, 0, 0, 2, 2, 5, 5])


@pytest.mark.parametrize("branching", [2, 16, 64])
def test_zero_and_unwritten_slots_never_sampled(branching):
    capacity = 1000
    tree = sum_tree.init(capacity, branching)
    # huge values written then cleared leave nothing behind (an incremental tree keeps rounding debris)
    tree = _set(tree, jnp.arange(0, 1000, 7), jnp.full((143,), 3e7))
    tree = _set(tree, jnp.arange(0, 1000, 7), jnp.zeros((143,)))
    written = jnp.array([3, 400, 401, 998])
    tree = _set(tree, written, jnp.array([1e-30, 1e-3, 5.0, 2e-7]))
    _check_consistent(tree)
    total = sum_tree.total(tree)
    edge = jnp.stack([total, jnp.nextafter(total, 0.0), total * 1.0001, jnp.asarray(0.0), jnp.asarray(-1.0)])
    idx = _find(tree, edge)
    keys = jax.random.split(jax.random.PRNGKey(0), 50)
    sampled = jax.jit(jax.vmap(lambda k: sum_tree.stratified_sample(k, tree, 128)))(keys)
    allowed = set(np.asarray(written).tolist())
    assert set(np.asarray(idx).tolist()) <= allowed
    assert set(np.unique(np.asarray(sampled)).tolist()) <= allowed
    # the large leaf takes almost every stratum; the tiny ones are still reachable in principle
    assert np.mean(np.asarray(sampled) == 401) > 0.99


def test_no_drift_after_many_random_updates():
    capacity = 4096
    tree = sum_tree.init(capacity, 16)

    def body(i, t):
        k1, k2 = jax.random.split(jax.random.fold_in(jax.random.PRNGKey(1), i))
        idx = jax.random.randint(k1, (64,), 0, capacity)
        vals = jax.random.uniform(k2, (64,)) ** 8 * 1e4  # spread over 8 orders of magnitude
        return sum_tree.set(t, idx, vals)

    tree = jax.jit(lambda t: jax.lax.fori_loop(0, 3000, body, t))(tree)
    _check_consistent(tree)
    rebuilt = jax.jit(sum_tree.rebuild)(tree)
    for a, b in zip(rebuilt.prefix, tree.prefix, strict=True):  # the history leaves no trace: bit-identical
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))


def test_bad_sizes_raise():
    with pytest.raises(ValueError, match="capacity=0"):
        sum_tree.init(0)
    with pytest.raises(ValueError, match="branching=1"):
        sum_tree.init(4, 1)


def test_repeats_resolved_alike_by_pairwise_compare_and_by_sort():
    rng = np.random.default_rng(0)
    for n in (7, sum_tree.PAIRWISE_MAX, sum_tree.PAIRWISE_MAX + 300):  # the last one takes the sort path
        idx = rng.integers(0, n // 3 + 1, n)
        expected = np.array([i not in idx[k + 1 :] for k, i in enumerate(idx)])
        np.testing.assert_array_equal(np.asarray(sum_tree.last_occurrence_mask(jnp.asarray(idx))), expected)


def test_unique_indices_write_and_vmapped_trees_match_single_trees():
    # the ring buffer's fresh slots: distinct, some rows masked out
    set_unique = jax.jit(lambda t, i, v, m: sum_tree.set(t, i, v, m, unique_indices=True))
    mask = jnp.array([True, True, False])
    tree = set_unique(sum_tree.init(10, 3), jnp.array([4, 9, 4]), jnp.array([2.0, 3.0, 7.0]), mask)
    np.testing.assert_array_equal(np.asarray(tree.leaves), [0, 0, 0, 0, 2, 0, 0, 0, 0, 3])
    _check_consistent(tree)
    # vmapped over a stack of trees: set and find agree with the trees one by one
    idx = jnp.array([[0, 5, 5, 9], [3, 3, 1, 0]])
    vals = jnp.array([[1.0, 2.0, 4.0, 0.5], [6.0, 1.0, 2.0, 0.0]])
    stack = jax.tree.map(lambda x: jnp.stack([x, x]), sum_tree.init(10, 3))
    stack = jax.jit(jax.vmap(sum_tree.set))(stack, idx, vals)
    queries = jnp.array([[0.0, 1.2, 4.9, 5.4], [0.5, 1.5, 2.5, 2.99]])
    found = jax.jit(jax.vmap(sum_tree.find))(stack, queries)
    for t in range(2):
        single = _set(sum_tree.init(10, 3), idx[t], vals[t])
        np.testing.assert_array_equal(np.asarray(stack.leaf_values[t]), np.asarray(single.leaf_values))
        np.testing.assert_array_equal(np.asarray(found[t]), np.asarray(_find(single, queries[t])))
    np.testing.assert_array_equal(np.asarray(found), [[0, 5, 5, 9], [1, 1, 3, 3]])
