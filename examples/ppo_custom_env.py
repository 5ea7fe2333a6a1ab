"""Train jaxrl_robot's PPO on your own brax environment, several seeds in one program.

    python examples/ppo_custom_env.py                      # 3 seeds, 300 k env steps each
    python examples/ppo_custom_env.py --seeds 5 --total-steps 1000000

The environment below is written against brax's ``Env`` interface only (``reset(rng)``,
``step(state, action)``, ``observation_size``, ``action_size``, ``backend``), unbatched and pure,
as any brax environment is. ``make_train(config, env)`` wraps it for training (lanes, time limit,
auto-reset) and returns ``train(key) -> (final state, metrics per chunk)``, a pure function, so
``jax.jit(jax.vmap(train))`` trains one agent per key in one compiled program. The trained
policies are then tested on fresh episodes with ``jaxrl_robot.evaluation.run_test_episodes``.
"""

from __future__ import annotations

import argparse
import time
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
from brax.envs.base import Env, State

from jaxrl_robot.agents.ppo import PPOConfig, make_train, make_trainer
from jaxrl_robot.evaluation import run_test_episodes


class PointReach(Env):
    """A point in the unit square driven by velocity commands toward a random goal.

    Observation ``[x, y, goal_x, goal_y]``; action ``[vx, vy]`` in ``[-1, 1]`` scaled by
    ``step_size``; reward: the decrease of the distance to the goal; the episode ends (``done``)
    when the point is within ``goal_radius`` of the goal (``metrics["success"] = 1``).
    """

    def __init__(self, step_size: float = 0.1, goal_radius: float = 0.05):
        self.step_size = step_size
        self.goal_radius = goal_radius

    @property
    def observation_size(self) -> int:
        return 4

    @property
    def action_size(self) -> int:
        return 2

    @property
    def backend(self) -> str:
        return "jax"

    def reset(self, rng: jax.Array) -> State:
        point_key, goal_key = jax.random.split(rng)
        pos = jax.random.uniform(point_key, (2,), minval=-1.0, maxval=1.0)
        goal = jax.random.uniform(goal_key, (2,), minval=-1.0, maxval=1.0)
        obs = jnp.concatenate([pos, goal])
        zero = jnp.zeros(())
        return State(pipeline_state=obs, obs=obs, reward=zero, done=zero, metrics={"success": zero}, info={})

    def step(self, state: State, action: jax.Array) -> State:
        pos, goal = state.pipeline_state[:2], state.pipeline_state[2:]
        new = pos + self.step_size * jnp.clip(action, -1.0, 1.0)
        before, after = jnp.linalg.norm(goal - pos), jnp.linalg.norm(goal - new)
        success = (after < self.goal_radius).astype(jnp.float32)
        obs = jnp.concatenate([new, goal])
        return state.replace(pipeline_state=obs, obs=obs, reward=before - after, done=success,
                             metrics={"success": success})  # fmt: skip


def config(total_steps: int) -> PPOConfig:
    """PPO settings for :class:`PointReach` (64 lanes × 16 steps per iteration, 2 × 64 networks)."""
    return PPOConfig(
        total_steps=total_steps, num_envs=64, unroll_length=16, minibatch_size=256, actor_updates=8,
        critic_updates=8, actor_lr=1e-3, critic_lr=1e-3, gamma=0.95, actor_hidden=(64, 64),
        critic_hidden=(64, 64), batch_norm=False, episode_length=50,
    )  # fmt: skip


def main(argv: list[str] | None = None) -> dict[str, Any]:
    """Train ``--seeds`` agents at once, test each on 100 episodes; returns the per-seed figures."""
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--seeds", type=int, default=3)
    p.add_argument("--total-steps", type=int, default=300_000)
    args = p.parse_args(argv)
    env, cfg = PointReach(), config(args.total_steps)

    train = make_train(cfg, env, iterations_per_update=10)  # one chunk = 10 iterations
    trainer = make_trainer(cfg, env)  # for its policy(state) -> obs -> action

    def test(state: Any, key: jax.Array) -> jax.Array:
        episodes = run_test_episodes(key, env, trainer.policy(state), 100, episode_length=50)
        return jnp.mean(episodes["success"])

    keys = jax.random.split(jax.random.PRNGKey(0), args.seeds)
    t0 = time.perf_counter()
    states, metrics = jax.jit(jax.vmap(train))(keys)  # metrics: [seeds, chunks] per name
    success = np.asarray(jax.jit(jax.vmap(test))(states, jax.random.split(jax.random.PRNGKey(1), args.seeds)))
    wall = time.perf_counter() - t0
    returns = np.asarray(metrics["episode_return"])  # mean return of the episodes finished in each chunk
    for seed in range(args.seeds):
        print(f"seed {seed}: return {returns[seed, 0]:.2f} (first chunk) -> {returns[seed, -1]:.2f} (last); "
              f"test success {success[seed]:.0%}")  # fmt: skip
    print(f"{args.seeds} seeds x {args.total_steps:,} env steps in {wall:.1f} s (compilation included)")
    return {"success": success, "returns": returns, "wall_s": wall}


if __name__ == "__main__":
    main()
