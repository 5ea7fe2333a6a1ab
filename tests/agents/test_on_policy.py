"""The on-policy family's shared steps by hand: mini-batches of whole sequences and segments, the restart
marks of training sequences, the start-state source of new episodes."""

import jax
import jax.numpy as jnp
import numpy as np

from jaxrl_robot.agents import on_policy

N, B = 8, 3
# step t of lane b holds 100 t + b, and a second leaf its negative with a trailing axis
STEPS = jnp.arange(N)[:, None] * 100.0 + jnp.arange(B)[None, :]
DATA = (STEPS, -STEPS[..., None])
draw_sequences = jax.jit(on_policy.draw_sequences, static_argnums=(3, 4))
draw_segments = jax.jit(on_policy.draw_segments, static_argnums=(3, 4))


def _columns(x):
    """``[L, M]`` -> list of (lane, first step) of each column, asserting it is a run of consecutive steps."""
    out = []
    for col in np.asarray(x).T:
        lane, steps = int(col[0]) % 100, (col // 100).astype(int)
        assert np.all(col % 100 == lane) and np.all(np.diff(steps) == 1), col
        out.append((lane, int(steps[0])))
    return out


def test_draw_sequences_takes_whole_sequences_from_every_lane_without_replacement():
    lane_ids = jnp.array([5, 6, 7])
    first, second = draw_sequences(jax.random.PRNGKey(0), lane_ids, DATA, 2, 3)
    assert first.shape == (2, 9) and second.shape == (2, 9, 1)
    np.testing.assert_array_equal(second[..., 0], -first)
    picked = _columns(first)
    for lane in range(B):
        starts = [s for b, s in picked if b == lane]
        assert len(starts) == 3 and len(set(starts)) == 3 and all(s % 2 == 0 for s in starts), picked
    # a lane's draw depends on its global index only: the same lane under another position draws the same
    moved = draw_sequences(jax.random.PRNGKey(0), lane_ids[::-1], (DATA[0][:, ::-1],), 2, 3)[0]
    assert set(_columns(moved)) == set(picked)


def test_draw_segments_takes_distinct_whole_segments_of_any_lane():
    first, second = draw_segments(jax.random.PRNGKey(1), jnp.array([0, 1, 2]), DATA, 4, 5)
    assert first.shape == (4, 5) and second.shape == (4, 5, 1)
    np.testing.assert_array_equal(second[..., 0], -first)
    picked = _columns(first)
    assert len(set(picked)) == 5 and all(s % 4 == 0 for _, s in picked), picked


def test_sequence_resets_mark_episode_and_sequence_starts():
    starts = jnp.array([[1.0, 0.0], [0.0, 0.0], [0.0, 1.0], [0.0, 0.0], [1.0, 0.0], [0.0, 0.0]])
    np.testing.assert_array_equal(
        on_policy.sequence_resets(starts, 3), [[1, 1], [0, 0], [0, 1], [1, 1], [1, 0], [0, 0]]
    )


def test_start_states_take_the_table_entry_of_the_reference_step_or_zeros():
    zeros = lambda shape: np.zeros(shape + (2,))  # noqa: E731
    table = np.arange(10.0).reshape(5, 2)
    state = type("S", (), {"info": {"k": np.array([3, 0])}, "done": np.zeros(2)})()
    np.testing.assert_array_equal(on_policy.StartStates(zeros, True).of(table, state), [[6, 7], [0, 1]])
    np.testing.assert_array_equal(on_policy.StartStates(zeros, True).first(table), [0, 1])
    np.testing.assert_array_equal(on_policy.StartStates(zeros).of((), state), np.zeros((2, 2)))
    assert on_policy.StartStates(zeros).table(None) == ()
