"""Wrappers, config validation and the registry, on a toy point-mass env."""

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from brax.envs.base import State

import envs_mjx
from envs_mjx.base import RobotEnv, sanitize_action, wrap_for_training
from envs_mjx.config import ConfigError, apply_overrides, check_choice, check_range


@dataclasses.dataclass(frozen=True)
class ToyConfig:
    max_steps: int = 5
    scale: float = 0.5
    goal_radius: float = 0.1
    mode: str = "a"

    def validate(self):
        check_range("max_steps", self.max_steps, 1)
        check_range("scale", self.scale, 0.0, lo_open=True)
        check_choice("mode", self.mode, ("a", "b"))


class Toy(RobotEnv):
    """1-D point starting at a random x in [1, 2]; terminates when |x| < goal_radius."""

    name = "toy"
    Config = ToyConfig

    @property
    def observation_size(self):
        return 1

    @property
    def action_size(self):
        return 1

    @property
    def action_scale(self):
        return jnp.array([self.config.scale])

    def default_params(self):
        return {"offset": jnp.zeros(())}

    def reset(self, rng, params=None):
        params = self.default_params() if params is None else params
        x = jax.random.uniform(rng, (1,), minval=1.0, maxval=2.0) + params["offset"]
        zero = jnp.zeros(())
        return State(
            pipeline_state=x,
            obs=x,
            reward=zero,
            done=zero,
            metrics={"invalid_action": zero},
            info={"params": params, "x0": x[0]},
        )

    def step(self, state, action):
        a, invalid = sanitize_action(action)
        x = state.pipeline_state + self.action_scale * a
        done = (jnp.abs(x[0]) < self.config.goal_radius).astype(jnp.float32)
        return state.replace(
            pipeline_state=x,
            obs=x,
            reward=-jnp.abs(x[0]),
            done=done,
            metrics={"invalid_action": invalid},
        )


def test_sanitize_action_handles_nan_inf_and_range():
    a, invalid = sanitize_action(jnp.array([jnp.nan, 3.0, -jnp.inf, 0.25]))
    np.testing.assert_allclose(a, [0.0, 1.0, 0.0, 0.25])
    assert float(invalid) == 1.0
    _, invalid = sanitize_action(jnp.array([0.1, -2.0]))
    assert float(invalid) == 0.0


def test_config_errors_name_field_and_choices():
    with pytest.raises(ConfigError, match="unknown setting 'nope'.*max_steps"):
        Toy(nope=1)
    with pytest.raises(ConfigError, match=r"scale=-1.*\(0, inf\]"):
        Toy(scale=-1.0)
    with pytest.raises(ConfigError, match="mode='c'.*'a', 'b'"):
        Toy(mode="c")
    cfg = Toy.default_config()
    new = apply_overrides(cfg, {"scale": 0.25})
    assert new.scale == 0.25 and cfg.scale == 0.5  # caller's config untouched


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
