"""The two sides of :mod:`benchmarks.brax_tasks`: our algorithm, configured from brax's row, trained and evaluated
as brax evaluates; brax's own trainer with the same row."""

from __future__ import annotations

import time
from collections.abc import Callable
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from benchmarks import seeds as bench_seeds
from benchmarks.brax_tasks_report import is_playground
from envs_mjx.base import ActionRepeatWrapper
from envs_mjx.config import apply_overrides
from jaxrl_robot import parallel
from jaxrl_robot.agents import ddpg, ppo, sac
from jaxrl_robot.evaluation import run_test_episodes, two_policies
from jaxrl_robot.types import Trainer
from train.presets import (
    TD3_OWN,
    brax_ppo_config,
    brax_sac_ddpg_config,
    ddpg_config_of_sac_row,
    ppo_config_of_row,
)
from train.sac import sac_config
from train.td3 import TD3_SETTINGS


def our_config(algo: str, task: str, action_size: int, row: dict[str, float], steps: int,
               overrides: dict[str, Any] | None = None) -> Any:  # fmt: skip
    """Our validated config of ``algo`` for the task's ``row`` and ``steps`` env steps, with ``overrides``
    (fields of :class:`PPOConfig` or :class:`DDPGConfig`) over it; ``ConfigError`` naming a bad one.
    PPO's ``segments=true|false`` among them picks brax's own update or the thesis's
    (:func:`train.presets.brax_ppo_config`'s ``segments``; by default the task's preset) and
    ``tuned=false`` leaves out the task's :data:`train.presets.BRAX_PPO_TUNED` fields; TD3's and
    DDPG's ``own_settings=true|false`` TD3's own settings or the SAC row's, and ``tuned=false`` leaves
    out the task's :data:`train.presets.BRAX_SAC_TUNED` entries
    (:func:`train.presets.brax_sac_ddpg_config`). A ``playground:<Name>`` task's row is converted by the same
    code (:func:`train.presets.ppo_config_of_row`, brax's own update unless ``segments=false``;
    :func:`train.presets.ddpg_config_of_sac_row`); it has no tuned fields."""
    overrides = dict(overrides or {})
    tuned = bool(overrides.pop("tuned", True))
    own = bool(overrides.pop("own_settings", True)) if algo != "ppo" else True
    if algo == "ppo":
        segments = overrides.pop("segments", None)  # None: the task's preset
        if is_playground(task):
            config = ppo_config_of_row(row, action_size, True if segments is None else bool(segments))
        else:
            config = brax_ppo_config(task, action_size, None if segments is None else bool(segments), tuned, **row)
    else:
        if is_playground(task):
            config = ddpg_config_of_sac_row(row, TD3_OWN if own else None)
        else:
            config = brax_sac_ddpg_config(task, own, tuned, **row)
        config = config.replace(**TD3_SETTINGS) if algo == "td3" else sac_config(config) if algo == "sac" else config
    return apply_overrides(config.replace(total_steps=steps), overrides, type(config).__name__).validate()


def our_trainer(algo: str, task: str, env: Any, row: dict[str, float], steps: int,
                overrides: dict[str, Any] | None = None, devices: int = 1) -> tuple[Trainer, int]:  # fmt: skip
    """Our trainer of ``algo`` with the task's ``row`` (and ``overrides``, see :func:`our_config`) for
    ``steps`` env steps, its lanes spread over the first ``devices`` devices (0: all), and its episode
    length."""
    config = our_config(algo, task, int(env.action_size), row, steps, overrides)
    mesh = parallel.lane_mesh(devices or None)
    if algo == "ppo":
        return ppo.make_trainer(config, env, mesh=mesh), config.episode_length
    every = update_chunk(config.iterations)
    make_trainer = sac.make_trainer if algo == "sac" else ddpg.make_trainer
    return make_trainer(config, env, mesh=mesh, iterations_per_update=every), config.episode_length


def update_chunk(iterations: int, calls: int = 20) -> int:
    """Iterations per ``update`` call of an off-policy run of ``iterations``: of the call counts from
    ``calls // 2`` to ``2 · calls`` (the points the evaluations pick from), the one whose calls overshoot
    the budget least, then the one nearest ``calls``, then the larger; ``calls`` calls of
    ``ceil(iterations / calls)`` overshoot by fewer than ``calls`` iterations, so the pick does too, and a
    count of iterations with a divisor in that range (brax's SAC counts of :func:`brax_sac_steps`) is run
    exactly. Fewer iterations than ``calls // 2``: one per call."""
    counts = range(max(calls // 2, 1), min(2 * calls, iterations) + 1)
    if not counts:
        return 1
    best = min(counts, key=lambda c: (c * -(-iterations // c) - iterations, abs(c - calls), -c))
    return -(-iterations // best)


def eval_points(num_updates: int, evals: int = 10) -> list[int]:
    """The updates done at each evaluation: 0, then ``evals - 1`` points spread evenly to the end (as
    brax's ``ppo.train`` evaluates ``num_evals`` times)."""
    return sorted({round(i * num_updates / max(evals - 1, 1)) for i in range(evals)})


def ours(env: Any, task: str, row: dict[str, float], steps: int, seeds: int, eval_episodes: int,
         seed_map: str = "loop", algo: str = "ppo", mode: str = "stochastic",
         overrides: dict[str, Any] | None = None, evals: int = 10,
         done: Callable[[dict[str, Any]], None] | None = None, devices: int = 1,
         seed_ids: list[int] | None = None) -> dict[str, Any]:  # fmt: skip
    """Train our ``algo`` on ``seeds`` seeds (``seed_ids``, default 0 …: :mod:`benchmarks.seeds`' keys), one
    vmapped program (``seed_map='vmap'``) or one compiled
    program called per key (``'loop'``; each seed's lanes spread over ``devices`` devices, 0: all),
    evaluating at the ``evals`` :func:`eval_points` (as brax does) in
    ``mode`` where the trainer can sample, and with the mean action; returns, evaluation curves,
    training-episode curves and wall time (compilation and the evaluations included, as brax's).

    ``done`` is called with the record so far after each evaluation that adds to it (a run cut short
    keeps it): every seed's evaluations so far with ``vmap``; with ``loop`` the seeds finished, or, before
    the first one finishes, its evaluations so far. A record of a run not yet at its end has ``cut``."""
    repeat = int(row.get("action_repeat", 1))  # each decision held for `repeat` env steps, as brax's wrapper does
    if repeat > 1:
        env = ActionRepeatWrapper(env, repeat)
        row = {**row, "episode_length": int(row["episode_length"]) // repeat}
    trainer, episode_length = our_trainer(algo, task, env, row, steps // repeat, overrides, devices)
    sampled = mode == "stochastic" and trainer.sample_policy is not None
    trainer_devices = devices or jax.device_count()
    points = eval_points(trainer.num_updates, evals)
    per_update = trainer.env_steps_per_update * repeat  # env steps, as brax counts them
    replicated = parallel.lane_sharding(parallel.lane_mesh(devices or None), split=False)

    def segment(state: Any, buf: jax.Array, start: jax.Array, n: jax.Array) -> tuple[Any, jax.Array]:
        """``n`` updates from update ``start`` on, each chunk's training-episode return (and the acting
        policy's mean σ, where the trainer reports it) written to ``buf [2, num_updates]``."""

        def body(i: jax.Array, carry: tuple[Any, jax.Array]) -> tuple[Any, jax.Array]:
            state, buf = carry
            state, metrics = trainer.update(state)
            std = metrics.get("policy_std", jnp.full((), jnp.nan))
            return state, buf.at[:, start + i].set(jnp.stack([metrics["episode_return"], std]).astype(buf.dtype))

        return jax.lax.fori_loop(0, n, body, (state, buf))

    def test(state: Any, key: jax.Array) -> tuple[jax.Array, jax.Array]:
        """Mean returns ``(in mode, of the mean action)``: both modes' episodes in one rollout."""
        mean_action = trainer.policy(state)
        if not sampled:
            r = jnp.mean(run_test_episodes(key, env, mean_action, eval_episodes, episode_length)["return"])
            return r, r
        both = two_policies(trainer.sample_policy(state, jax.random.fold_in(key, 1)), mean_action, eval_episodes)
        r = run_test_episodes(key, env, both, 2 * eval_episodes, episode_length)["return"]
        return jnp.mean(r[:eval_episodes]), jnp.mean(r[eval_episodes:])

    def record(curves: np.ndarray, curves_mean: np.ndarray, per_chunk: np.ndarray, updates: int,
               walls: list[list[float]]) -> dict[str, Any]:  # fmt: skip
        """The side's record of ``curves`` / ``curves_mean`` ``[S, E]`` (the first E evaluations), the
        per-update returns and σ ``per_chunk [S, 2, U]`` after ``updates`` updates, and ``walls``: per program
        (one for ``vmap``, one per seed for ``loop``) the seconds since the start at each evaluation."""
        wall, n = time.perf_counter() - t0, curves.shape[0]
        trained = per_update * (np.arange(updates) + 1)
        return {"returns": curves[:, -1].tolist(), "eval_mode": "stochastic" if sampled else "deterministic",
                "returns_deterministic": curves_mean[:, -1].tolist(),
                "wall_s": wall, "wall_per_seed_s": wall / n, "seed_map": seed_map,
                "env_steps": per_update * updates, "env_steps_per_s": n * per_update * updates / wall,
                "curve_kind": "evaluation", "curve_steps": [per_update * p for p in points[: curves.shape[1]]],
                "curves": curves.tolist(), "curves_deterministic": curves_mean.tolist(),
                "training_curve_steps": trained.tolist(), "training_curves": per_chunk[:, 0, :updates].tolist(),
                "training_policy_std": per_chunk[:, 1, :updates].tolist(), "overrides": dict(overrides or {}),
                "devices": trainer_devices, "curve_wall_s": walls, "seeds_per_program": n if seed_map == "vmap" else 1,
                **({"cut": True} if updates < trainer.num_updates else {})}  # fmt: skip

    def report(curves: np.ndarray, curves_mean: np.ndarray, per_chunk: np.ndarray, updates: int,
               walls: list[list[float]]) -> None:  # fmt: skip
        if done is not None:
            done(record(curves, curves_mean, per_chunk, updates, walls))

    def run(init_fn: Callable, seg_fn: Callable, test_fn: Callable, keys: jax.Array, eval_keys: jax.Array,
            on_eval: Callable) -> tuple[np.ndarray, np.ndarray, np.ndarray, list[float]]:  # fmt: skip
        """Train from ``keys`` (one seed, or ``[S]`` with the vmapped functions) with an evaluation at every
        point, each followed by ``on_eval(curve, curve_mean, per_chunk, updates, [walls])`` of the run so far
        (``walls``: the seconds since the start at each evaluation, returned last)."""
        state = init_fn(keys)
        # replicated over the trainer's mesh, as ``segment`` returns it: its later calls reuse the first's program
        buf = jax.device_put(jnp.full(keys.shape[:-1] + (2, trainer.num_updates), jnp.nan, jnp.float32), replicated)
        curve, curve_mean, trained, walls = [], [], 0, []
        for p in points:
            if p > trained:
                state, buf = seg_fn(state, buf, trained, p - trained)
                trained = p
            r, m = jax.block_until_ready(test_fn(state, eval_keys))
            walls.append(time.perf_counter() - t0)
            print(f"  ours {algo}: {p * per_update:,} env steps, eval return "
                  f"{np.round(np.asarray(r), 1).tolist()}, {time.perf_counter() - t0:.0f} s", flush=True)
            curve.append(np.asarray(r))
            curve_mean.append(np.asarray(m))
            on_eval(np.stack(curve, -1), np.stack(curve_mean, -1), np.asarray(buf), p, [walls])
        return np.stack(curve, -1), np.stack(curve_mean, -1), np.asarray(buf), walls

    ids = list(seed_ids or range(seeds))
    keys, eval_keys = bench_seeds.keys(ids), bench_seeds.eval_keys(ids)
    t0 = time.perf_counter()
    if seed_map == "vmap":
        *outs, walls = run(jax.jit(jax.vmap(trainer.init)), jax.jit(jax.vmap(segment, in_axes=(0, 0, None, None))),
                           jax.jit(jax.vmap(test)), keys, eval_keys, report)  # fmt: skip
        return record(*outs, trainer.num_updates, [walls])
    init_one, seg_one, test_one = jax.jit(trainer.init), jax.jit(segment), jax.jit(test)
    runs: list[tuple[Any, ...]] = []

    def first_seed(c: np.ndarray, cm: np.ndarray, b: np.ndarray, p: int, walls: list[list[float]]) -> None:
        if not runs and p < trainer.num_updates:  # the first seed's evaluations so far
            report(c[None], cm[None], b[None], p, walls)

    def stacked() -> tuple[Any, ...]:
        """The seeds so far: curves, mean-action curves and per-update buffers stacked, then each seed's times."""
        return (*(np.stack([r[i] for r in runs]) for i in range(3)), trainer.num_updates, [r[3] for r in runs])

    for k, ek in zip(keys, eval_keys, strict=True):
        runs.append(run(init_one, seg_one, test_one, k, ek, first_seed))
        report(*stacked())
    return record(*stacked())


def theirs(env: Any, row: dict[str, float], steps: int, seeds: int, peer: str = "ppo",
           done: Callable[[dict[str, Any]], None] | None = None,
           mode: str = "stochastic", first_seed: int = 0, evals: int = 10,
           wrap_env_fn: Callable[..., Any] | None = None) -> dict[str, Any]:  # fmt: skip
    """brax's ``ppo.train`` (``peer='sac'``: ``sac.train``) with the task's ``row`` (brax's terms) and
    ``evals`` evaluations, seeds ``first_seed … first_seed + seeds − 1`` one after another, evaluated in
    ``mode``; ``done`` is called with the record of the seeds so far after each one, and before the first
    one finishes, after each of its evaluations with that seed's so far (``cut``: a run cut short keeps it).
    ``wrap_env_fn``: brax's ``wrap_env_fn`` (a MuJoCo Playground env: its ``wrapper.wrap_for_brax_training``)."""
    from benchmarks.peers.brax_ppo import train_published

    runs: list[dict[str, Any]] = []

    def report(shown: list[dict[str, Any]], cut: bool = False) -> dict[str, Any]:
        record = {**summary(shown), "eval_mode": mode, "seed_ids": list(range(first_seed, first_seed + len(shown))),
                  **({"cut": True} if cut else {})}  # fmt: skip
        if done is not None:
            done(record)
        return record

    def so_far(partial: dict[str, Any]) -> None:
        if not runs:
            report([partial], cut=True)

    for seed in range(first_seed, first_seed + seeds):
        runs.append(train_published(env, row, steps, seed, peer, deterministic_eval=mode == "deterministic",
                                    num_evals=evals, on_eval=so_far,
                                    **({"wrap_env_fn": wrap_env_fn} if wrap_env_fn else {})))  # fmt: skip
        record = report(runs)
    return record


def summary(runs: list[dict[str, Any]]) -> dict[str, Any]:
    """The record of brax's runs (one per seed) as the report reads it: a return per seed (``seeds`` of them),
    so that a comparison states each side's seeds and its noise (:func:`benchmarks.stats.compare`)."""
    walls = [r["wall_s"] for r in runs]
    return {"returns": [r["final_return"] for r in runs], "seeds": len(runs), "wall_s": float(sum(walls)),
            "wall_per_seed_s": float(np.mean(walls)), "env_steps": runs[0]["env_steps"],
            "env_steps_per_s": sum(r["env_steps"] for r in runs) / sum(walls),
            "curve_steps": runs[0]["curve_steps"], "curves": [r["curve"] for r in runs],
            **({"curve_wall_s": [r["curve_wall_s"] for r in runs]} if all("curve_wall_s" in r for r in runs)
               else {})}  # fmt: skip
