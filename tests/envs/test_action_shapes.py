"""Actions of the wrong static shape raise one clear line instead of broadcasting.

Every check happens while tracing, so the tests only trace (``jax.eval_shape``): nothing compiles.
"""

import contextlib

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from brax.envs.base import Env, State

import envs_mjx
from envs_mjx import ActionShapeError, wrap_for_training
from envs_mjx.base import (
    ActionRepeatWrapper,
    AutoResetWrapper,
    ClipActionWrapper,
    EpisodeWrapper,
    TanhActionWrapper,
    VmapWrapper,
    sanitize_action,
)

KEY = jax.random.PRNGKey(0)
ENVS = {
    "arm7": {"mode": "kinematic"},
    "arm7_precise": {"mode": "kinematic"},
    "scara": {},
    "unicycle": {"mode": "kinematic"},
    "racecar": {"road": "test1"},
}


def spec(shape, dtype=jnp.float32):
    return jax.ShapeDtypeStruct(shape, dtype)


@contextlib.contextmanager
def raises_line(message):
    """Expect an :class:`ActionShapeError` whose message is exactly ``message`` (one line; JAX may add a
    note on its filtered traceback, which ``str`` leaves out)."""
    with pytest.raises(ActionShapeError) as info:
        yield
    assert str(info.value) == message


@pytest.fixture(scope="module", params=sorted(ENVS))
def env_state(request):
    """``(env, state shapes)`` of each registered env (reset traced, not run)."""
    env = envs_mjx.make(request.param, **ENVS[request.param])
    return env, jax.eval_shape(env.reset, KEY)


def test_every_registered_env_is_covered():
    assert sorted(ENVS) == envs_mjx.names()


def test_wrong_action_shapes_raise_one_line_naming_env_and_shapes(env_state):
    env, state = env_state
    n = env.action_size
    assert (env.name, n) in {("arm7", 3), ("arm7_precise", 3), ("scara", 3), ("unicycle", 2), ("racecar", 3)}
    for bad in [(1,), (n + 1,), (n - 1,), (1, n), ()]:
        with raises_line(f"{env.name}.step: action has shape {bad}, expected ({n},) (action_size={n})"):
            jax.eval_shape(env.step, state, spec(bad))
    with raises_line(f"{env.name}.step: action has shape (1,), expected ({n},) (action_size={n})"):
        env.step(state, [0.5])  # a plain list is checked too
    assert issubclass(ActionShapeError, ValueError)


def test_right_action_shape_steps_and_any_real_dtype_gives_the_float32_result(env_state):
    env, state = env_state
    n = env.action_size
    out = jax.eval_shape(env.step, state, spec((n,)))
    assert jax.tree.structure(out) == jax.tree.structure(state)
    assert out.obs.shape == (env.observation_size,) and out.reward.shape == () and out.done.shape == ()
    # an int action steps as a float32 one would: the same float32 state (sanitize_action converts it)
    assert jax.eval_shape(env.step, state, spec((n,), jnp.int32)) == out
    for dtype in (jnp.bool_, jnp.complex64):
        expected = f"{env.name}.step: action has dtype {np.dtype(dtype)}, expected a real number type (float or int)"
        with raises_line(expected):
            jax.eval_shape(env.step, state, spec((n,), dtype))


def test_unicycle_model_reward_checks_its_action():
    env = envs_mjx.make("unicycle", mode="kinematic")
    state = jax.eval_shape(env.reset, KEY)
    assert jax.eval_shape(env.model_reward, state, spec((2,))).shape == ()
    with raises_line("unicycle.model_reward: action has shape (1,), expected (2,) (action_size=2)"):
        jax.eval_shape(env.model_reward, state, spec((1,)))


def test_sanitize_action_converts_ints_and_float64_to_float32():
    a, invalid = sanitize_action(jnp.array([3, -2, 0], jnp.int32))
    assert a.dtype == jnp.float32 and invalid.dtype == jnp.float32
    np.testing.assert_array_equal(a, [1.0, -1.0, 0.0])
    assert float(invalid) == 0.0
    a, invalid = sanitize_action(np.array([0.25, np.inf, -5.0], np.float64))
    assert a.dtype == jnp.float32
    np.testing.assert_array_equal(a, [0.25, 0.0, -1.0])
    assert float(invalid) == 1.0


@pytest.fixture(scope="module")
def arm7():
    return envs_mjx.make("arm7", mode="kinematic")


@pytest.mark.parametrize("refresh, wrapper", [(1.0, "VmapWrapper"), (0.5, "PoolResetWrapper")])
def test_training_wrappers_check_the_batched_action(arm7, refresh, wrapper):
    env = wrap_for_training(arm7, num_envs=4, reset_refresh=refresh, reset_group=4)
    assert type(env).__name__ == wrapper
    state = jax.eval_shape(env.reset, KEY)
    for bad in [(3,), (1, 3), (4, 1), (4, 4), (2, 4, 3)]:  # (1, 3) and (4, 1) would broadcast
        with raises_line(f"{wrapper}.step (arm7): action has shape {bad}, expected (4, 3) (lanes=4, action_size=3)"):
            jax.eval_shape(env.step, state, spec(bad))
    out = jax.eval_shape(env.step, state, spec((4, 3)))
    assert out.obs.shape == (4, arm7.observation_size) and out.done.shape == (4,)


class Broadcasting(Env):
    """A minimal brax env (not a ``RobotEnv``) whose ``step`` would broadcast any action, as brax's do."""

    observation_size = 2
    action_size = 2
    backend = "test"

    def reset(self, rng):
        zero = jnp.zeros(())
        return State(pipeline_state=jnp.zeros(2), obs=jnp.zeros(2), reward=zero, done=zero)

    def step(self, state, action):
        x = state.pipeline_state + action
        return state.replace(pipeline_state=x, obs=x, reward=-jnp.sum(x**2))


def test_unbatched_wrappers_check_a_foreign_env_action():
    raw = Broadcasting()
    state = raw.reset(KEY)
    assert raw.step(state, jnp.ones(1)).obs.shape == (2,)  # unwrapped, (1,) broadcasts silently
    wrappers = {
        "EpisodeWrapper": EpisodeWrapper(raw, 5),
        "AutoResetWrapper": AutoResetWrapper(EpisodeWrapper(raw, 5)),
        "ClipActionWrapper": ClipActionWrapper(raw),
        "TanhActionWrapper": TanhActionWrapper(raw),
        "ActionRepeatWrapper": ActionRepeatWrapper(raw, 2),
    }
    for name, env in wrappers.items():
        st = jax.eval_shape(env.reset, KEY)
        with raises_line(f"{name}.step (Broadcasting): action has shape (1,), expected (2,) (action_size=2)"):
            jax.eval_shape(env.step, st, spec((1,)))
        assert jax.eval_shape(env.step, st, spec((2,))).obs.shape == (2,)


def test_vmap_wrapper_checks_a_foreign_env_action():
    env = VmapWrapper(EpisodeWrapper(Broadcasting(), 5), batch_size=3)
    state = jax.eval_shape(env.reset, KEY)
    expected = "VmapWrapper.step (Broadcasting): action has shape (3, 1), expected (3, 2) (lanes=3, action_size=2)"
    with raises_line(expected):
        jax.eval_shape(env.step, state, spec((3, 1)))
    assert jax.eval_shape(env.step, state, spec((3, 2))).obs.shape == (3, 2)
