"""Wrappers, config validation and the registry, on a toy point-mass env."""


import jax
import jax.numpy as jnp
import numpy as np
import pytest

import envs_mjx
from envs_mjx.base import RobotEnv, map_lanes, sanitize_action, top_indices, wrap_for_training
from envs_mjx.config import ConfigError, apply_overrides
from tests.envs.toy import Toy


def test_sanitize_action_handles_nan_inf_and_range():
    a, invalid = sanitize_action(jnp.array([jnp.nan, 3.0, -jnp.inf, 0.25]))
    np.testing.assert_allclose(a, [0.0, 1.0, 0.0, 0.25])
    assert float(invalid) == 1.0
    _, invalid = sanitize_action(jnp.array([0.1, -2.0]))
    assert float(invalid) == 0.0


def test_config_errors_name_field_and_choices():
    with pytest.raises(ConfigError, match="unknown setting 'nope'.*max_steps"):
        Toy(nope=1)
    with pytest.raises(ConfigError, match=r"action_scale=-1.*\(0, inf\]"):
        Toy(action_scale=-1.0)
    with pytest.raises(ConfigError, match="mode='c'.*'a', 'b'"):
        Toy(mode="c")
    cfg = Toy.default_config()
    new = apply_overrides(cfg, {"action_scale": 0.25})
    assert new.action_scale == 0.25 and cfg.action_scale == 0.5  # caller's config untouched


def test_registry_unknown_name_lists_valid_names():
    with pytest.raises(ValueError, match="unknown environment 'nope'; valid names"):
        envs_mjx.make("nope")
    for name in envs_mjx.names():
        assert issubclass(envs_mjx.env_class(name), RobotEnv)


def test_time_limit_marks_truncation_not_termination():
    env = wrap_for_training(Toy(max_steps=3), num_envs=2)
    state = jax.jit(env.reset)(jax.random.PRNGKey(0))
    step = jax.jit(env.step)
    # lane 0 never moves (truncated at step 3); lane 1 runs into the goal at step 2.
    x1 = float(state.obs[1, 0])
    dones, truncs = [], []
    for t in range(3):
        a1 = -x1 / 0.5 / 2 if t < 2 else 0.0
        state = step(state, jnp.array([[0.0], [a1]]))
        dones.append(np.asarray(state.done))
        truncs.append(np.asarray(state.info["truncation"]))
    np.testing.assert_array_equal(np.stack(dones)[:, 0], [0, 0, 1])
    np.testing.assert_array_equal(np.stack(truncs)[:, 0], [0, 0, 1])
    assert dones[1][1] == 1 and truncs[1][1] == 0  # termination is not truncation


def test_auto_reset_gives_fresh_start_and_keeps_final_step():
    env = wrap_for_training(Toy(max_steps=2), num_envs=4)
    state = jax.jit(env.reset)(jax.random.PRNGKey(1))
    step = jax.jit(env.step)
    starts = [np.asarray(state.info["x0"])]
    for _ in range(6):
        prev_obs = state.obs
        state = step(state, jnp.full((4, 1), 0.1))
        if bool(state.done.all()):
            # the terminal observation is kept for bootstrapping; obs is the new episode's
            np.testing.assert_allclose(state.info["final_obs"], prev_obs + 0.05, rtol=1e-6)
            np.testing.assert_array_equal(state.info["episode_length"], 2.0)
            np.testing.assert_allclose(state.info["episode_return"], -(2 * prev_obs[:, 0] + 0.05), rtol=1e-5)
            starts.append(np.asarray(state.info["x0"]))
            np.testing.assert_allclose(state.obs[:, 0], starts[-1])
    starts = np.stack(starts)
    assert starts.shape == (4, 4)
    # every episode of every lane starts somewhere new (a true reset, not a cached state)
    assert len(np.unique(starts.round(6))) == starts.size


class KeepsDone(Toy):
    """The toy stepped as brax's halfcheetah and reacher step: ``done`` is never written (kept as given)."""

    def step(self, state, action):
        return super().step(state, action).replace(done=state.done)


class CountsResets(Toy):
    """The toy whose ``reset`` depends on its key alone (no episode parameters in ``info``, as Playground's
    envs) and computes its start through a host function that records each lane it computes in ``calls``:
    a side-effect-free callback, which XLA may move as it moves the rest of a reset."""

    calls: list = []

    @staticmethod
    def _record(x):
        CountsResets.calls.append(len(x))
        return x

    def reset(self, rng, params=None):
        s = super().reset(rng)
        x = jax.pure_callback(self._record, jax.ShapeDtypeStruct(s.obs.shape, s.obs.dtype), s.obs,
                              vmap_method="sequential")  # fmt: skip
        return s.replace(pipeline_state=x, obs=x, info={"x0": x[0]})


@pytest.mark.parametrize("seeds", [0, 2], ids=["lanes", "vmapped-seeds"])
def test_auto_reset_computes_the_reset_only_at_steps_where_a_lane_is_done(seeds):
    # Episodes of 3 steps that never terminate (zero action): lanes are done at steps 3 and 6 only. An env
    # whose reset costs many physics steps (Playground's CheetahRun settles 200) must not pay them at every
    # step, in a trainer's lanes nor with its seeds vmapped over them.
    env = wrap_for_training(CountsResets(max_steps=3), num_envs=2)
    if seeds:
        reset, step = jax.jit(jax.vmap(env.reset)), jax.jit(jax.vmap(env.step))
        state, action = reset(jax.random.split(jax.random.PRNGKey(0), seeds)), jnp.zeros((seeds, 2, 1))
    else:
        reset, step = jax.jit(env.reset), jax.jit(env.step)
        state, action = reset(jax.random.PRNGKey(0)), jnp.zeros((2, 1))
    resets, starts = [], [np.asarray(state.obs)]
    for _ in range(7):
        jax.effects_barrier()
        CountsResets.calls.clear()
        state = step(state, action)
        jax.effects_barrier()
        resets.append(len(CountsResets.calls) > 0)
        starts.append(np.asarray(state.obs))
    assert resets == [False, False, True, False, False, True, False]
    # the episodes that start at steps 3 and 6 are fresh draws, different from the ones before
    assert not np.allclose(starts[3], starts[0]) and not np.allclose(starts[6], starts[3])


@pytest.mark.parametrize("refresh", [1.0, 0.5])
def test_time_limit_restarts_an_env_that_never_writes_done(refresh):
    # Episodes of 3 steps, reward -|x| with x constant (zero action): done at steps 3 and 6 only, and
    # each episode's return is the sum of its own 3 rewards (not one step's reward after the first limit).
    env = wrap_for_training(KeepsDone(max_steps=3), num_envs=2, reset_refresh=refresh, reset_group=2)
    state = jax.jit(env.reset)(jax.random.PRNGKey(3))
    step = jax.jit(env.step)
    dones, returns = [], []
    for _ in range(7):
        x = np.asarray(state.obs[:, 0])
        state = step(state, jnp.zeros((2, 1)))
        dones.append(np.asarray(state.done))
        returns.append((np.asarray(state.info["episode_return"]), -3 * x))
    np.testing.assert_array_equal(np.stack(dones), [[0, 0], [0, 0], [1, 1], [0, 0], [0, 0], [1, 1], [0, 0]])
    for t in (2, 5):
        np.testing.assert_allclose(returns[t][0], returns[t][1], rtol=1e-6)


def test_action_repeat_holds_the_action_sums_rewards_and_stops_at_done():
    env = envs_mjx.ActionRepeatWrapper(Toy(action_scale=2.0, goal_radius=0.1), 3)
    state = env.reset(jax.random.PRNGKey(4))
    x0 = float(state.obs[0])
    out = env.step(state, jnp.array([-0.05]))  # x moves by 2 · -0.05 = -0.1 three times
    np.testing.assert_allclose(out.obs[0], x0 - 0.3, rtol=1e-6)
    np.testing.assert_allclose(out.reward, -((x0 - 0.1) + (x0 - 0.2) + (x0 - 0.3)), rtol=1e-6)
    assert float(out.done) == 0.0
    # an action that reaches the goal (|x| < 0.1) on the second step: the third leaves the state and adds nothing
    a = -(x0 - 0.02) / 2 / 2.0
    out = env.step(state, jnp.array([a]))
    np.testing.assert_allclose(out.obs[0], 0.02, atol=1e-6)
    np.testing.assert_allclose(out.reward, -(x0 - (x0 - 0.02) / 2) - 0.02, rtol=1e-5)
    assert float(out.done) == 1.0


def test_episode_params_survive_auto_reset():
    env = wrap_for_training(Toy(max_steps=1), num_envs=3)
    state = env.reset(jax.random.PRNGKey(2), {"offset": jnp.asarray(10.0)})
    assert np.all(np.asarray(state.obs) >= 11.0)
    # a trainer changes the schedule in the state; the next resets follow it
    state = state.replace(info={**state.info, "params": {"offset": jnp.full((3,), -10.0)}})
    state = jax.jit(env.step)(state, jnp.zeros((3, 1)))
    assert np.all(np.asarray(state.obs) <= -8.0)


def test_invalid_action_counted_and_state_finite():
    env = wrap_for_training(Toy(), num_envs=2)
    state = env.reset(jax.random.PRNGKey(3))
    state = jax.jit(env.step)(state, jnp.array([[jnp.nan], [0.5]]))
    np.testing.assert_array_equal(state.metrics["invalid_action"], [1.0, 0.0])
    assert np.all(np.isfinite(np.asarray(state.obs)))


def test_brax_training_wrapper_accepts_base_env():
    from brax.envs.wrappers import training

    env = training.wrap(Toy(), episode_length=4)
    state = jax.jit(env.reset)(jax.random.split(jax.random.PRNGKey(0), 3))
    state = jax.jit(env.step)(state, jnp.zeros((3, 1)))
    assert state.obs.shape == (3, 1)


# ---- PoolResetWrapper ------------------------------------------------------------------


def _run(env, state, actions):
    step = jax.jit(env.step)
    out = []
    for a in actions:
        state = step(state, a)
        out.append(state)
    return out


def test_pool_reset_fresh_when_few_lanes_finish_and_keeps_final_step():
    # refresh 1/2 of 4 lanes per step; lanes finish two at a time (max_steps 2, staggered):
    # every finished lane is redrawn at the step it finishes, so every episode is new.
    env = wrap_for_training(Toy(max_steps=2), num_envs=4, reset_refresh=0.5, reset_group=4)
    assert env.group_sizes(4) == (4, 2)
    state = jax.jit(env.reset)(jax.random.PRNGKey(1))
    # stagger: lanes 0 and 1 start one step into their episode
    state = state.replace(info={**state.info, "steps": jnp.array([1, 1, 0, 0], jnp.int32)})
    starts, prev = [np.asarray(state.info["x0"])], state
    for nstate in _run(env, state, [jnp.full((4, 1), 0.1)] * 6):
        done = np.asarray(nstate.done) > 0
        assert done.sum() == 2
        np.testing.assert_allclose(nstate.info["final_obs"][done], prev.obs[done] + 0.05, rtol=1e-6)
        np.testing.assert_array_equal(nstate.info["pool_reused"], 0.0)
        # a new episode starts at its own start (obs == x0) with a zeroed episode clock
        np.testing.assert_allclose(nstate.obs[done, 0], nstate.info["x0"][done])
        np.testing.assert_array_equal(nstate.info["steps"][done], 0)
        starts.append(np.asarray(nstate.info["x0"])[done])
        prev = nstate
    starts = np.concatenate(starts)
    assert len(np.unique(starts.round(6))) == starts.size


def test_pool_reset_burst_reuses_consumed_entries_and_counts_them():
    # 4 lanes, 1 redraw per step, all lanes hit the time limit together every 2 steps.
    env = wrap_for_training(Toy(max_steps=2), num_envs=4, reset_refresh=0.25, reset_group=4)
    state = jax.jit(env.reset)(jax.random.PRNGKey(2))
    zero = jnp.zeros((4, 1))
    s1, s2, s3, s4 = _run(env, state, [zero] * 4)
    # step 2: all finish; their entries were drawn at reset (one redrawn at step 1, one now):
    # none had been consumed, so no repeats
    assert np.asarray(s2.done).all()
    np.testing.assert_array_equal(s2.info["pool_reused"], 0.0)
    np.testing.assert_array_equal(s2.info["pool_stale"], 1.0)
    # step 3 redraws one consumed entry; step 4 (all finish again) redraws one more for a
    # finished lane: the two others restart from the episode they already played
    np.testing.assert_array_equal(s3.info["pool_stale"].sum(), 3.0)
    assert np.asarray(s4.done).all()
    reused = np.asarray(s4.info["pool_reused"]) > 0
    assert reused.sum() == 2
    np.testing.assert_allclose(np.asarray(s4.info["x0"])[reused], np.asarray(s2.info["x0"])[reused])
    assert np.all(np.asarray(s4.info["x0"])[~reused] != np.asarray(s2.info["x0"])[~reused])


def test_pool_reset_draws_with_current_params():
    env = envs_mjx.PoolResetWrapper(envs_mjx.EpisodeWrapper(Toy(), 1), batch_size=3, refresh=1.0, group=3)
    state = env.reset(jax.random.PRNGKey(2), {"offset": jnp.asarray(10.0)})
    assert np.all(np.asarray(state.obs) >= 11.0)
    state = state.replace(info={**state.info, "params": {"offset": jnp.full((3,), -10.0)}})
    state = jax.jit(env.step)(state, jnp.zeros((3, 1)))
    assert np.all(np.asarray(state.obs) <= -8.0)
    np.testing.assert_array_equal(state.info["params"]["offset"], -10.0)


def test_pool_reset_groups_are_independent():
    # lanes 0..3 of an 8-lane env with groups of 4 behave exactly like a 4-lane env with the
    # same per-lane keys: what a device holding those lanes would compute
    keys = jax.random.split(jax.random.PRNGKey(3), 8)
    acts = [jnp.full((8, 1), 0.1 * (-1) ** t) for t in range(5)]
    big = wrap_for_training(Toy(max_steps=2), reset_refresh=0.25, reset_group=4)
    small = wrap_for_training(Toy(max_steps=2), reset_refresh=0.25, reset_group=4)
    out8 = _run(big, big.reset(keys), acts)
    out4 = _run(small, small.reset(keys[:4]), [a[:4] for a in acts])
    for a, b in zip(out8, out4, strict=True):
        np.testing.assert_allclose(a.obs[:4], b.obs, rtol=1e-6)
        np.testing.assert_array_equal(a.info["pool_reused"][:4], b.info["pool_reused"])


def test_top_indices_is_lax_top_k_with_ties_to_the_lower_index():
    """The pool's ranking (a stable sort, partitioned per device) picks exactly ``lax.top_k``'s lanes."""
    rng = np.random.default_rng(0)
    for n, r in ((8, 1), (16, 5), (64, 64), (300, 37)):
        prio = jnp.asarray(rng.integers(0, 4, n), jnp.int32)  # few values: many ties
        got = np.asarray(top_indices(prio, r))
        np.testing.assert_array_equal(got, np.asarray(jax.lax.top_k(prio, r)[1]))
    np.testing.assert_array_equal(np.asarray(top_indices(jnp.array([1, 3, 3, 0, 3]), 2)), [1, 2])


def test_pool_reset_rejects_bad_refresh():
    with pytest.raises(ValueError, match=r"reset_refresh=0.*\(0, 1\]"):
        wrap_for_training(Toy(), num_envs=2, reset_refresh=0.0)
    with pytest.raises(ValueError, match="group=0"):
        envs_mjx.PoolResetWrapper(Toy(), refresh=0.5, group=0)


@pytest.mark.parametrize("refresh", [1.0, 0.5])
def test_lane_groups_step_exactly_like_one_batch(refresh):
    """Stepping 8 lanes as 4 groups of 2 gives the same states, resets included, as one vmap of 8."""
    acts = [jnp.asarray(np.random.default_rng(i).uniform(-1, 1, (8, 1)), jnp.float32) for i in range(7)]
    out = {}
    for group in (0, 2):
        env = wrap_for_training(Toy(max_steps=3), num_envs=8, reset_refresh=refresh, reset_group=4, lane_group=group)
        state = jax.jit(env.reset)(jax.random.PRNGKey(3))
        out[group] = [jax.device_get(s) for s in _run(env, state, acts)]
    for a, b in zip(out[0], out[2], strict=True):
        jax.tree.map(np.testing.assert_array_equal, a, b)
    assert sum(float(s.done.sum()) for s in out[0]) >= 8  # episodes ended and were reset on the way


def test_map_lanes_groups_and_rejects_an_uneven_split():
    calls = []

    def f(x):
        calls.append(x.shape)
        return 2.0 * x

    x = jnp.arange(12.0).reshape(6, 2)
    np.testing.assert_array_equal(jax.jit(lambda v: map_lanes(f, 3, v))(x), 2.0 * x)
    assert calls == [(2,)]  # traced once per lane, inside the group loop
    with pytest.raises(ValueError, match="lane_group=4 must divide the lanes per device \\(6\\)"):
        map_lanes(f, 4, x)
