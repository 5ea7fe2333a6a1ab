"""Uniform ring buffer: wrap-around, masked packing, sampling only stored slots."""

import jax
import jax.numpy as jnp
import numpy as np

from jaxrl_robot.replay import Transition, make_uniform_replay


def _tr(lo, hi):
    i = jnp.arange(lo, hi, dtype=jnp.float32)
    return Transition(i[:, None], jnp.stack([i, i], -1), i, i[:, None] + 1, jnp.zeros_like(i))


def test_ring_wraps_and_mask_packs_rows():
    replay = make_uniform_replay(capacity=5, batch_size=64)
    state = replay.init(jax.tree.map(lambda x: x[0], _tr(0, 1)))
    state = replay.add(state, _tr(0, 3))
    state = replay.add(state, _tr(3, 7), mask=jnp.array([True, False, True, True]))
    # stored 0,1,2 then 3,5,6 -> 6 wraps onto slot 0
    np.testing.assert_array_equal(state.data.reward, [6, 1, 2, 3, 5])
    assert int(state.size) == 5 and int(state.insert_pos) == 1
    np.testing.assert_array_equal(state.data.action[:, 1], state.data.reward)


def test_samples_only_stored_slots():
    replay = make_uniform_replay(capacity=100, batch_size=256)
    state = replay.init(jax.tree.map(lambda x: x[0], _tr(0, 1)))
    state = replay.add(state, _tr(0, 7))
    sample = jax.jit(replay.sample)(jax.random.PRNGKey(0), state)
    idx = np.asarray(sample.indices)
    assert idx.min() >= 0 and idx.max() < 7 and len(np.unique(idx)) == 7
    np.testing.assert_array_equal(sample.experience.reward, idx)
