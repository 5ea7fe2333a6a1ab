"""A tiny goal-conditioned point-mass env with arm7's goal API, for replay and DDPG tests.

A point ``p ∈ R^3`` starts uniformly in ``[-0.5, 0.5]^3``; the action moves it by
``C · a`` with ``C = action_scale``.  The goal is drawn uniformly in ``[-0.5, 0.5]^3``.  The
episode terminates on success (``‖g − p‖ < threshold``) or on leaving the feasible
region ``‖p‖_∞ <= 1``.  Observation ``[p, g − p, g]`` (9-dim, like arm7's HER layout).
"""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
from brax.envs.base import State

from envs_mjx.base import RobotEnv, sanitize_action
from envs_mjx.config import check_choice


@dataclasses.dataclass(frozen=True)
class ToyGoalConfig:
    max_steps: int = 20
    action_scale: float = 0.1
    threshold: float = 0.1
    reward: str = "sparse"
    region: float = 1.0

    def validate(self):
        check_choice("reward", self.reward, ("sparse", "shaped"))


class ToyGoalEnv(RobotEnv):
    name = "toy_goal"
    Config = ToyGoalConfig
    observation_size = 9
    action_size = 3

    # goal-conditioned API (same names and signatures as arm7)
    def achieved_goal(self, state):
        return state.info["ee_pos"]

    def desired_goal(self, state):
        return state.info["goal"]

    def sample_goal(self, key):
        return jax.random.uniform(key, (3,), minval=-0.5, maxval=0.5)

    def in_feasible_region(self, pos):
        return jnp.all(jnp.abs(pos) <= self.config.region, axis=-1)

    def goal_reached(self, achieved, goal):
        return jnp.linalg.norm(goal - achieved, axis=-1) < self.config.threshold

    def compute_reward(self, achieved_next, goal, achieved_prev):
        d = jnp.linalg.norm(goal - achieved_next, axis=-1)
        reached = d < self.config.threshold
        out = ~self.in_feasible_region(achieved_next)
        if self.config.reward == "sparse":
            return jnp.where(reached, 0.0, -1.0)
        return -d + jnp.where(reached, 1.0, 0.0) - jnp.where(out, 1.0, 0.0)

    def obs_from(self, ee_pos, goal):
        return jnp.concatenate([ee_pos, goal - ee_pos, goal], axis=-1)

    def reset(self, rng, params=None):
        k1, k2 = jax.random.split(rng)
        p = jax.random.uniform(k1, (3,), minval=-0.5, maxval=0.5)
        g = self.sample_goal(k2)
        zero = jnp.zeros(())
        return State(
            pipeline_state=p,
            obs=self.obs_from(p, g),
            reward=zero,
            done=zero,
            metrics={"success": zero, "invalid_action": zero},
            info={"goal": g, "ee_pos": p},
        )

    def step(self, state, action):
        a, invalid = sanitize_action(action)
        p_prev = state.info["ee_pos"]
        g = state.info["goal"]
        p = p_prev + self.action_scale * a
        reward = self.compute_reward(p, g, p_prev)
        success = self.goal_reached(p, g).astype(jnp.float32)
        failed = (~self.in_feasible_region(p)).astype(jnp.float32)
        done = jnp.maximum(success, failed)
        info = dict(state.info)
        info["ee_pos"] = p
        return state.replace(
            pipeline_state=p,
            obs=self.obs_from(p, g),
            reward=reward,
            done=done,
            metrics={"success": success, "invalid_action": invalid},
            info=info,
        )
