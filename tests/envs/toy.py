"""1-D point-mass envs for the wrapper and trainer tests: a point ``x`` moved by ``action_scale · a`` towards 0.

:class:`Toy` starts at a random x in ``[1, 2]``, observes ``x``, is rewarded ``-|x|`` and reports invalid
actions; :class:`tests.agents.test_ppo.Line` changes the start, the observation, the reward and the metrics.
Both take the episode parameter ``offset`` (added to the start) and terminate when ``|x| < goal_radius``."""

import dataclasses

import jax
import jax.numpy as jnp
from brax.envs.base import State

from envs_mjx.base import RobotEnv, sanitize_action
from envs_mjx.config import check_choice, check_range


@dataclasses.dataclass(frozen=True)
class ToyConfig:
    max_steps: int = 5
    action_scale: float = 0.5
    goal_radius: float = 0.1
    mode: str = "a"

    def validate(self):
        check_range("max_steps", self.max_steps, 1)
        check_range("action_scale", self.action_scale, 0.0, lo_open=True)
        check_choice("mode", self.mode, ("a", "b"))


class Toy(RobotEnv):
    """1-D point starting at a random x in ``start`` (+ ``offset``); terminates when |x| < goal_radius."""

    name = "toy"
    Config = ToyConfig
    observation_size = 1
    action_size = 1
    start = (1.0, 2.0)

    def default_params(self):
        return {"offset": jnp.zeros(())}

    def observe(self, x):
        """The observation of position ``x`` ([1])."""
        return x

    def reward(self, x_prev, x):
        """The reward of the step from ``x_prev`` to ``x`` ([1] each)."""
        del x_prev
        return -jnp.abs(x[0])

    def metrics(self, done, invalid):
        """The step's metrics from its termination flag and :func:`sanitize_action`'s invalid flag."""
        del done
        return {"invalid_action": invalid}

    def reset(self, rng, params=None):
        params = self.default_params() if params is None else params
        x = jax.random.uniform(rng, (1,), minval=self.start[0], maxval=self.start[1]) + params["offset"]
        zero = jnp.zeros(())
        return State(pipeline_state=x, obs=self.observe(x), reward=zero, done=zero, metrics=self.metrics(zero, zero),
                     info={"params": params, "x0": x[0]})  # fmt: skip

    def step(self, state, action):
        a, invalid = sanitize_action(action)
        x = state.pipeline_state + self.action_scale * a
        done = (jnp.abs(x[0]) < self.config.goal_radius).astype(jnp.float32)
        return state.replace(pipeline_state=x, obs=self.observe(x), reward=self.reward(state.pipeline_state, x),
                             done=done, metrics=self.metrics(done, invalid))  # fmt: skip
