"""Precision evaluation: success at 5, 2 and 1 cm from one run on the strictest env, checked against
separate runs on envs with each goal threshold (an independent oracle) and by construction."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from brax.envs.base import State

import envs_mjx
from jaxrl_robot.evaluation import (
    evaluate,
    evaluation_kind,
    freeze,
    precision_summary,
    run_test_episodes,
    sampling_policy,
    summarize_episodes,
    two_policies,
)


def aim_beside_the_goal(env):
    """Move straight at a point beside the goal (the largest step C allows), ``obs [E, 9] -> [E, 3]``; the
    point lies 0-3 cm from the goal along x, different per goal, so the episodes' precision varies."""

    def policy(obs):
        goal = obs[..., 6:9]
        offset = 0.03 * jnp.abs(jnp.sin(1000.0 * goal[..., :1]))
        d = (obs[..., 3:6] + offset * jnp.asarray([1.0, 0.0, 0.0])) / env.action_scale
        return d / jnp.maximum(jnp.max(jnp.abs(d), axis=-1, keepdims=True), 1.0)

    return policy


def test_success_at_each_threshold_equals_a_run_on_the_env_with_that_threshold():
    """On the standard env (5 cm) and on the precise one (1 cm: its own run serves every threshold). The
    oracle of each threshold is a run on an env of that threshold (the policy depends on the action scale,
    not the threshold): the 2 cm env's run here, and each evaluation's own ``success_rate`` for 5 and 1 cm."""
    key = jax.random.PRNGKey(3)
    alone = envs_mjx.make("arm7", mode="kinematic", goal_threshold=0.02)
    episodes = jax.jit(lambda k: run_test_episodes(k, alone, aim_beside_the_goal(alone), 64))(key)
    oracle = {0.02: summarize_episodes(jax.device_get(episodes))["success_rate"]}
    evaluations = {}
    for own in (0.05, 0.01):
        env = envs_mjx.make("arm7", mode="kinematic", goal_threshold=own)
        evaluations[own] = evaluate(key, env, aim_beside_the_goal(env), 64, precision=True)
        oracle[own] = evaluations[own]["success_rate"]
    for own, got in evaluations.items():
        for t in (0.05, 0.02, 0.01):
            assert got[f"success_{t * 100:g}cm"] == pytest.approx(oracle[t]), (own, t)
        assert got[f"success_{own * 100:g}cm"] == pytest.approx(got["success_rate"])  # the evaluation's own figure
        rates = (got["success_5cm"], got["success_2cm"], got["success_1cm"])
        assert rates[0] > rates[1] > rates[2] > 0.0, rates  # the thresholds tell the episodes apart
        assert got["closest_distance_median"] <= got["closest_distance_p90"] <= got["closest_distance_max"]


class _FallsAfterThreeSteps:
    """An episode of 3 steps (reward 1 each) whose env, stepped on after the end, returns NaN rewards
    (as brax's inverted_double_pendulum on MJX can once the fallen pendulum is left to run)."""

    episode_length = 10

    def reset(self, key):
        z = jnp.zeros(())
        return State(z, jnp.zeros(1), z, z, {}, {})

    def step(self, state, action):
        t = state.pipeline_state + 1.0
        reward = jnp.where(t > 3, jnp.nan, 1.0)
        return state.replace(pipeline_state=t, obs=jnp.full(1, t), reward=reward, done=(t >= 3).astype(jnp.float32))


def test_returns_count_only_the_live_steps_of_an_env_that_turns_nan_after_the_end():
    got = run_test_episodes(jax.random.PRNGKey(0), _FallsAfterThreeSteps(), lambda obs: jnp.zeros((obs.shape[0], 1)), 4)
    np.testing.assert_array_equal(got["return"], 3.0)
    np.testing.assert_array_equal(got["length"], 3.0)
    np.testing.assert_array_equal(got["terminated"], 1.0)


def test_freeze_keeps_the_last_state_of_finished_lanes_by_hand():
    old = {"x": jnp.array([1.0, 2.0, 3.0]), "q": jnp.array([[1.0, 1.0], [2.0, 2.0], [3.0, 3.0]])}
    new = {"x": jnp.array([10.0, jnp.nan, 30.0]), "q": jnp.array([[10.0, 10.0], [jnp.nan, 0.0], [30.0, 30.0]])}
    got = freeze(jnp.array([1.0, 0.0, 0.0]), old, new)
    np.testing.assert_array_equal(got["x"], [10.0, 2.0, 3.0])
    np.testing.assert_array_equal(got["q"], [[10.0, 10.0], [2.0, 2.0], [3.0, 3.0]])


def test_precision_summary_by_hand():
    got = precision_summary({"closest_distance": np.array([0.004, 0.012, 0.03, 0.07])})
    assert (got["success_5cm"], got["success_2cm"], got["success_1cm"]) == (0.75, 0.5, 0.25)
    assert got["closest_distance_median"] == pytest.approx(0.021) and got["closest_distance_max"] == 0.07


def test_race_evaluation_counts_laps_per_road():
    """``racecar`` is evaluated by laps on every road: a policy that only brakes stalls on each lap."""
    from envs_mjx.racecar import RaceCar

    env = RaceCar(n_opponents=2)
    out = evaluate(jax.random.PRNGKey(0), env, lambda obs: jnp.array([0.0, -1.0, 1.0]) + 0.0 * obs[..., :3], 2)
    assert out["kind"] == "racing" and out["laps_per_road"] == 2 and out["success_rate"] == 0.0
    for road in ("train", "test1", "test2", "test3"):
        assert out[f"{road}/stalled"] == 2 and out[f"{road}/success"] == 0 and out[f"{road}/collision"] == 0


def test_the_env_says_how_its_policies_are_evaluated():
    from envs_mjx.arm7 import Arm7
    from envs_mjx.racecar import RaceCar
    from envs_mjx.scara import Scara
    from envs_mjx.unicycle import Unicycle

    assert [evaluation_kind(cls) for cls in (Arm7, Scara, Unicycle, RaceCar)] == ["episodes", "tracking", "tracking",
                                                                                  "racing"]  # fmt: skip
    assert evaluation_kind(_FallsAfterThreeSteps()) == "episodes"  # an env that says nothing: test episodes
    bogus = type("Bogus", (), {"evaluation_kind": "laps"})()
    with pytest.raises(ValueError, match=r"^Bogus.evaluation_kind 'laps'; valid: episodes, tracking, racing$"):
        evaluation_kind(bogus)


def test_sampling_policy_draws_from_the_gaussian_per_episode_and_step_and_applies_to_env():
    mean, log_std = jnp.array([0.5, -2.0]), jnp.log(jnp.array([0.3, 0.1]))

    def dist(memory, obs):  # a fixed Gaussian; the memory counts the steps
        return memory + 1, (jnp.broadcast_to(mean, obs.shape), jnp.broadcast_to(log_std, obs.shape))

    policy = sampling_policy(dist, jnp.zeros(()), jax.random.PRNGKey(0), lambda a: jnp.clip(a, -1.0, 1.0))
    carry = jax.tree.map(lambda c: jnp.broadcast_to(c, (20_000,) + jnp.shape(c)), policy.carry)  # as for E episodes
    carry, a1 = policy.step(carry, jnp.zeros((20_000, 2)))
    carry, a2 = policy.step(carry, jnp.zeros((20_000, 2)))
    assert carry[0].shape == (20_000,) and float(carry[0][0]) == 2.0 and carry[1].shape == (20_000, 2)
    np.testing.assert_allclose(np.mean(a1[:, 0]), 0.5, atol=0.01)  # N(0.5, 0.3²), inside the clip
    np.testing.assert_allclose(np.std(a1[:, 0]), 0.3, atol=0.01)
    np.testing.assert_array_equal(a1[:, 1], -1.0)  # N(-2, 0.1²) clipped by to_env
    # the spread above is across episodes (one draw each); the next step draws afresh, uncorrelated
    assert abs(np.corrcoef(a1[:, 0], a2[:, 0])[0, 1]) < 0.03


def test_two_policies_act_on_their_own_halves_with_their_own_memories():
    """The first 3 episodes act with a counter policy (memory +1 per step, action = memory), the last 3 with
    a memoryless one (action = −obs): after two steps the halves hold their own actions and memories."""
    counter = sampling_policy(lambda m, o: (m + 1, (jnp.broadcast_to(m[:, None], o.shape), jnp.full(o.shape, -30.0))),
                              jnp.zeros(()), jax.random.PRNGKey(0))  # σ = e^-30: the action is the mean
    both = two_policies(counter, lambda obs: -obs, 3)
    carry = jax.tree.map(lambda c: jnp.broadcast_to(c, (6,) + jnp.shape(c)), both.carry)
    obs = jnp.arange(6.0)[:, None]
    carry, first = both.step(carry, obs)
    carry, second = both.step(carry, obs)
    np.testing.assert_allclose(first[:, 0], [0, 0, 0, -3, -4, -5], atol=1e-6)
    np.testing.assert_allclose(second[:, 0], [1, 1, 1, -3, -4, -5], atol=1e-6)
    np.testing.assert_array_equal(carry[0][0], [2, 2, 2, 0, 0, 0])  # only the first half's memory advanced
