"""Greedy straight-to-goal controller on ``arm7``: ``python -m envs_mjx.demo``.

Runs one episode on each of ``--lanes`` parallel lanes per physics mode, the action being the
largest step ``C`` allows along the straight line to the goal, and prints the success rate, the
mean extra distance (path length minus the straight start-goal distance, successful episodes),
the mean episode length and the control steps per second (after compilation).
"""

from __future__ import annotations

import argparse
import time

import jax
import jax.numpy as jnp

import envs_mjx
from envs_mjx import xla


def greedy_action(env, state):
    """``[B, 3]`` action moving straight at the goal by at most ``C`` per axis."""
    d = (state.info["goal"] - state.info["ee_pos"]) / env.action_scale
    return d / jnp.maximum(jnp.max(jnp.abs(d), axis=-1, keepdims=True), 1.0)


def make_rollout(env, lanes: int):
    """``rollout(key) -> dict`` of per-lane first-episode results, ``[lanes]`` each (pure, jittable)."""
    steps = env.episode_length

    def rollout(key):
        state = jax.vmap(env.reset)(jax.random.split(key, lanes))

        def body(carry, _):
            state, done, success, length, extra = carry
            nxt = jax.vmap(env.step)(state, greedy_action(env, state))
            live = 1.0 - done
            ended = live * nxt.done
            success = success + ended * nxt.metrics["success"]
            extra = jnp.where(ended > 0, nxt.metrics["extra_distance"], extra)
            return (nxt, jnp.maximum(done, nxt.done), success, length + live, extra), None

        zero = jnp.zeros(lanes)
        (_, _, success, length, extra), _ = jax.lax.scan(body, (state, zero, zero, zero, zero), None, steps)
        return {"success": success, "length": length, "extra": extra}

    return rollout


def run(mode: str, lanes: int, seed: int) -> dict[str, float]:
    env = envs_mjx.make("arm7", mode=mode)
    rollout = xla.jit(make_rollout(env, lanes))
    key = jax.random.PRNGKey(seed)
    t0 = time.perf_counter()
    jax.block_until_ready(rollout(key))
    compile_s = time.perf_counter() - t0
    t0 = time.perf_counter()
    out = jax.block_until_ready(rollout(jax.random.fold_in(key, 1)))
    run_s = time.perf_counter() - t0
    ok = out["success"] > 0
    return {
        "success": float(ok.mean()),
        "extra": float(jnp.where(ok, out["extra"], 0.0).sum() / jnp.maximum(ok.sum(), 1)),
        "length": float(out["length"].mean()),
        "steps_per_s": lanes * env.episode_length / run_s,
        "compile_s": compile_s,
    }


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--lanes", type=int, default=256, help="parallel episodes per mode")
    parser.add_argument("--modes", nargs="+", default=["kinematic", "pd"], choices=["kinematic", "pd"])
    parser.add_argument("--seed", type=int, default=0)
    args = parser.parse_args(argv)
    print(f"arm7 greedy controller, {args.lanes} lanes, device: {jax.devices()[0].device_kind}")
    print(f"{'mode':<10} {'success':>8} {'extra (m)':>10} {'steps/ep':>9} {'steps/s':>10} {'compile (s)':>12}")
    for mode in args.modes:
        r = run(mode, args.lanes, args.seed)
        print(
            f"{mode:<10} {r['success']:>8.1%} {r['extra']:>10.4f} {r['length']:>9.1f}"
            f" {r['steps_per_s']:>10.0f} {r['compile_s']:>12.1f}"
        )


if __name__ == "__main__":
    main()
