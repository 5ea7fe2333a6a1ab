"""Checks shared by the tests of the tracking environments (``scara``, ``unicycle``)."""

import math
from collections.abc import Callable

import jax
import jax.numpy as jnp
import numpy as np


def start(frac, limit=math.inf):
    """Episode parameters starting at fraction ``frac`` of the reference, early-termination limit ``limit``."""
    return {"start_lo": frac, "start_hi": frac, "et_limit": limit}


def rollout_fn(env, keys, record: Callable):
    """``run(params, actions [lanes, T, A])`` -> (start state, per-step records ``[lanes, max_steps]``).

    One lane per key of ``keys [lanes, 2]``; ``record(state)`` gives the dict kept after each step.
    Actions are padded with zeros to ``max_steps`` steps, so the scan compiles once; NaN rows mean
    the reference's own command.
    """

    def one(key, params, actions):
        state = env.reset(key, params)

        def body(s, a):
            a = jnp.where(jnp.isnan(a), env.reference_action(s.info["k"]), a)
            s = env.step(s, a)
            return s, record(s)

        return state, jax.lax.scan(body, state, actions)[1]

    run = jax.jit(jax.vmap(one, in_axes=(0, None, 0)))

    def padded(params, actions):
        actions = jnp.asarray(actions, jnp.float32)
        pad = jnp.zeros((keys.shape[0], env.max_steps - actions.shape[1], env.action_size), jnp.float32)
        return run(keys, params, jnp.concatenate([actions, pad], axis=1))

    return padded


def rsi_starts(env, key, fracs, reference_state: Callable, atol):
    """Reset (jitted) at each fraction of ``fracs``: the episode starts at step
    ``k0 = floor(frac · max_steps)`` with ``(qpos, qvel) = reference_state(k0)`` (within ``atol``)
    and all tracking errors of the observation zero.  Returns the start states."""
    reset = jax.jit(env.reset)
    states = []
    for frac in fracs:
        state = reset(key, start(frac))
        k0 = int(math.floor(frac * env.max_steps))
        assert int(state.info["k"]) == k0
        np.testing.assert_allclose(state.info["t"], k0 * env.dt, rtol=1e-6)
        qpos, qvel = reference_state(k0)
        np.testing.assert_allclose(state.pipeline_state.qpos, qpos, atol=atol)
        np.testing.assert_allclose(state.pipeline_state.qvel, qvel, atol=atol)
        np.testing.assert_allclose(state.obs[7:], 0.0, atol=1e-6)  # every error is zero
        states.append(state)
    return states


def assert_early_termination(env, rec, n, limit):
    """Lane 0 of ``rec`` over its first ``n`` steps terminates on exactly the ``limit + 1``-th
    over-threshold step, earns reward before and none from then on; returns that step."""
    over = np.asarray(rec["pos_error"][0, :n]) > env.config.et_threshold
    done = np.asarray(rec["done"][0, :n])
    first = int(np.argmax(done > 0))
    assert over[first] and np.cumsum(over)[first] == limit + 1
    assert not done[:first].any() and done[first:].all()
    assert np.all(np.asarray(rec["reward"][0, :first]) > 0)
    np.testing.assert_array_equal(rec["reward"][0, first:n], 0.0)
    return first


def counting_step(wrapped):
    """``(jitted wrapped.step, traces)``: ``traces`` grows by one each time the step is traced."""
    traces = []

    def step(state, action):
        traces.append(1)
        return wrapped.step(state, action)

    return jax.jit(step), traces


def step_extreme_actions(jstep, state, action_size, nan_column, check: Callable | None = None):
    """Step 1024 lanes with random, huge (even lanes 1e6, odd −inf), NaN and huge actions again.

    The NaN actions ``[1024, action_size]`` keep one finite column, ``nan_column``, on every third
    lane.  After each step observation, reward, ``qpos`` and ``qvel`` are finite and
    ``check(state)`` holds; at the end exactly the odd lanes count an invalid action.  Returns the
    last state.
    """
    lanes = jnp.arange(1024)[:, None]
    extreme = jnp.where(lanes % 2 == 0, 1e6, -jnp.inf) * jnp.ones((1024, action_size), jnp.float32)
    nan = jnp.full((1024, action_size), jnp.nan, jnp.float32).at[::3, nan_column].set(0.5)
    rand = jax.random.uniform(jax.random.PRNGKey(1), (1024, action_size), minval=-1, maxval=1)
    for actions in (rand, extreme, nan, extreme):
        state = jstep(state, actions)
        for x in (state.obs, state.reward, state.pipeline_state.qpos, state.pipeline_state.qvel):
            assert bool(jnp.all(jnp.isfinite(x)))
        if check is not None:
            check(state)
    np.testing.assert_array_equal(state.metrics["invalid_action"], np.where(np.arange(1024) % 2 == 0, 0.0, 1.0))
    return state
