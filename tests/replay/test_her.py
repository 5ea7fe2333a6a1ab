"""HER relabelling: copy counts per strategy, goal provenance, recomputed rewards and observations."""

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from jaxrl_robot.replay import GoalEpisode, flatten_copies, make_her, make_uniform_replay, num_copies
from tests.replay.toy_goal_env import ToyGoalEnv

T = 8


def _episode(env, key, actions, length):
    """Run ``env`` for ``length`` steps with ``actions`` and pad to ``T`` steps."""
    state = env.reset(key)
    rows, ee = [], [state.info["ee_pos"]]
    for t in range(length):
        nxt = env.step(state, actions[t])
        rows.append((state.obs, actions[t], nxt.reward, nxt.obs, nxt.done,
                     nxt.done * (1 - nxt.metrics["success"])))
        ee.append(nxt.info["ee_pos"])
        state = nxt
    pad = T - length
    cols = [jnp.stack(c) for c in zip(*rows, strict=True)]
    cols = [jnp.concatenate([c, jnp.zeros((pad, *c.shape[1:]), c.dtype)]) for c in cols]
    ee = jnp.stack(ee + [ee[-1]] * pad)
    valid = (jnp.arange(T) < length).astype(jnp.float32)
    return GoalEpisode(*cols, valid=valid, achieved=ee, ee_pos=ee, goal=state.info["goal"])


@pytest.fixture(scope="module")
def episode():
    env = ToyGoalEnv(reward="sparse")
    actions = jnp.tile(jnp.array([[1.0, 0.5, -0.5]]), (T, 1))
    return env, _episode(env, jax.random.PRNGKey(0), actions, length=5)


@pytest.mark.parametrize("strategy,k,copies", [("none", 0, 1), ("final", 0, 2), ("future", 2, 3),
                                               ("future", 4, 5), ("random", 2, 3)])
def test_copy_counts(episode, strategy, k, copies):
    env, ep = episode
    her = make_her(env, strategy, k)
    assert her.copies == copies == num_copies(strategy, k)
    tr, mask, goals = jax.jit(her.relabel)(jax.random.PRNGKey(1), ep)
    assert mask.shape == (T, copies) and tr.reward.shape == (T, copies) and tr.obs.shape == (T, copies, 9)
    assert int(mask.sum()) == 5 * copies  # 5 valid steps, every copy kept
    assert not bool(mask[5:].any())
    # copy 0 is the original transition, unchanged
    np.testing.assert_array_equal(tr.obs[:, 0], ep.obs)
    np.testing.assert_array_equal(tr.reward[:, 0], ep.reward)
    np.testing.assert_array_equal(tr.termination[:, 0], ep.termination)
    # every copy carries the recomputed reward and rebuilt observations for its goal
    v = slice(0, 5)  # the valid steps (padding is masked out)
    reward = env.compute_reward(ep.achieved[1:, None], goals, ep.achieved[:-1, None])
    np.testing.assert_allclose(tr.reward[v], reward[v])
    ee_prev, ee_next = (jnp.broadcast_to(e[:, None], goals.shape) for e in (ep.ee_pos[:-1], ep.ee_pos[1:]))
    np.testing.assert_allclose(tr.obs[v], env.obs_from(ee_prev, goals)[v], rtol=1e-6)
    np.testing.assert_allclose(tr.next_obs[v], env.obs_from(ee_next, goals)[v], rtol=1e-6)
    np.testing.assert_array_equal(tr.action, jnp.broadcast_to(ep.action[:, None], tr.action.shape))


def test_final_goal_is_last_achieved_and_reached_at_the_end(episode):
    env, ep = episode
    tr, mask, goals = make_her(env, "final").relabel(jax.random.PRNGKey(0), ep)
    np.testing.assert_array_equal(goals[:5, 1], jnp.broadcast_to(ep.achieved[5], (5, 3)))
    # the last real step reaches the relabelled goal: sparse reward 0 and terminal
    assert float(tr.reward[4, 1]) == 0.0 and float(tr.termination[4, 1]) == 1.0
    assert bool((tr.reward[:4, 1] == -1.0).all())
    # a caller's goal test replaces the env's: never reached -> only failures are terminal
    tr, _, _ = make_her(env, "final", goal_reached=lambda a, g: jnp.zeros(a.shape[:-1], bool)).relabel(
        jax.random.PRNGKey(0), ep
    )
    assert float(tr.termination[4, 1]) == 0.0 and float(tr.reward[4, 1]) == 0.0


def test_final_is_skipped_when_the_final_state_left_the_feasible_region():
    env = ToyGoalEnv(reward="sparse", action_scale=0.4)
    ep = _episode(env, jax.random.PRNGKey(0), jnp.ones((T, 3)), length=T)
    length = int(np.argmax(np.asarray(ep.termination))) + 1  # the env terminates on leaving the region
    ep = ep._replace(valid=(jnp.arange(T) < length).astype(jnp.float32))
    assert not bool(env.in_feasible_region(ep.ee_pos[length]))
    _, mask, _ = make_her(env, "final").relabel(jax.random.PRNGKey(0), ep)
    assert int(mask[:, 0].sum()) == length and not bool(mask[:, 1].any())


def test_future_goals_come_from_later_in_the_same_episode(episode):
    env, ep = episode
    her = make_her(env, "future", 4)
    achieved = np.asarray(ep.achieved)
    seen = set()
    for s in range(20):
        _, mask, goals = her.relabel(jax.random.PRNGKey(s), ep)
        for t in range(5):
            for c in range(1, 5):
                match = np.where(np.all(achieved[: 6] == np.asarray(goals[t, c]), axis=-1))[0]
                assert match.size and match.max() > t and match.max() <= 5, (t, match)
                seen.add((t, int(match.max())))
    # every later state is used at some point (uniform over t < j <= L)
    assert seen == {(t, j) for t in range(5) for j in range(t + 1, 6)}


def test_random_goals_come_from_the_goal_sampler(episode):
    env, ep = episode
    _, _, goals = make_her(env, "random", 2).relabel(jax.random.PRNGKey(7), ep)
    g = np.asarray(goals[:, 1:]).reshape(-1, 3)
    assert np.all(np.abs(g) <= 0.5) and len(np.unique(g.round(6), axis=0)) == g.shape[0]
    assert not np.any(np.all(np.isin(g, np.asarray(ep.achieved)), axis=-1))


def test_relabelled_copies_go_to_replay_through_the_mask(episode):
    env, ep = episode
    her = make_her(env, "future", 2)
    eps = jax.tree.map(lambda x: jnp.stack([x, x]), ep)  # two lanes
    tr, mask, _ = jax.vmap(her.relabel)(jax.random.split(jax.random.PRNGKey(0), 2), eps)
    replay = make_uniform_replay(capacity=100, batch_size=4)
    state = replay.init(jax.tree.map(lambda x: x[0, 0, 0], tr))
    state = replay.add(state, flatten_copies(flatten_copies(tr)), mask=mask.reshape(-1))
    assert int(state.size) == 2 * 5 * 3


def test_bad_strategy_lists_choices():
    with pytest.raises(ValueError, match="her strategy='best' is not valid; choose one of 'none', 'final'"):
        num_copies("best", 2)
    with pytest.raises(ValueError, match="her k=0 must be >= 1"):
        num_copies("future", 0)
