"""Our PPO beside brax's own on brax's standard tasks (our TD3 / DDPG beside brax's SAC with ``--algo``):
return at equal env steps, wall time, steps/s.

    python -m benchmarks.brax_tasks                                   # 5 tasks, 3 seeds, brax's budgets
    python -m benchmarks.brax_tasks --tasks inverted_pendulum --seeds 3
    python -m benchmarks.brax_tasks --tasks reacher --steps 5000000    # a shorter budget for both
    python -m benchmarks.brax_tasks --algo td3 --tasks hopper --steps 1000000   # off-policy: brax's SAC beside
    python -m benchmarks.brax_tasks --tasks halfcheetah --no-brax --ours activation=swish state_std=true \
        tanh_actions=true clip_actions=false                           # brax's policy parametrisation
    python -m benchmarks.brax_tasks --tasks hopper --ours segments=true   # brax's update (advantage_segment)
    python -m benchmarks.brax_tasks --tasks reacher --no-brax --devices 2 --seed-map loop   # each seed on 2 GPUs

Off-policy (``--algo td3``, ``ddpg`` or ``sac``; SAC takes DDPG's config, :func:`train.sac.sac_config`): the
tasks brax trains with SAC (:data:`train.presets.BRAX_SAC`,
hopper and walker2d), brax's ``sac.train`` with the row as it is, ours through
:func:`train.presets.brax_sac_ddpg_config`: the same envs, memory and networks, with TD3's own settings
(mini-batches of 256, γ 0.99, unscaled rewards) and two updates per env step on hopper and walker2d
(:data:`train.presets.BRAX_SAC_TUNED`; ``--ours tuned=false``: TD3's one; ``--ours own_settings=false``:
the row's ``grad_updates_per_step`` per ``num_envs`` env steps, discount and reward scaling), for the
env steps brax's SAC makes of the budget (:func:`brax_sac_steps`), split into update calls that end on
that count where it allows (:func:`update_chunk`). The updates
dominate the wall time: where env steps are cheap (thousands of simulated lanes) PPO's budget of 10–50 M
steps usually takes less time than the off-policy budget of a few million, and an off-policy method
is the tool when env steps are what costs (a real robot, a slow simulator).

Both train on the same env object (``brax.envs.get_environment(task, backend=--backend)``, MJX by
default) for the same env steps with the settings of :data:`train.presets.BRAX_PPO`: brax's
``ppo.train`` takes the row as it is; ours takes it through :func:`train.presets.brax_ppo_config`,
with our fields of :data:`train.presets.BRAX_PPO_TUNED` over it on the tasks that table names
(``--ours tuned=false``: the row alone; ``python -m train.ppo --env brax:<task>`` picks the same
preset). Our seeds run through one compiled program called per seed (``--seed-map vmap``: one vmapped
program), brax's one after another.

* **return**: brax: its own final evaluation (``eval/episode_reward``, 128 episodes of
  ``episode_length`` steps) of its policy's sampled actions (brax's default; PPO's unless
  ``--eval-mode`` says otherwise) or, with ``--eval-mode deterministic`` (TD3's and DDPG's default), of
  its mean action (``deterministic_eval``); ours: ``--eval-episodes`` fresh episodes
  of the same length (:func:`jaxrl_robot.evaluation.run_test_episodes`) in the same mode
  (``Trainer.sample_policy`` for sampled actions; TD3 and DDPG have only their deterministic policy), and
  with the mean action beside it (both modes' episodes in one rollout,
  :func:`jaxrl_robot.evaluation.two_policies`). Mean ± std over seeds; the goal compares returns of the
  same mode.
* **wall**: from the call to the trained parameters, compilation included (per seed: the seeds' total
  over their number); brax's includes the ``--evals`` evaluations (10 unless given) its trainer runs
  along the way (128 episodes each), ours its evaluations at the same points (:func:`eval_points`, twice
  the episodes: both modes); **env steps/s**: env steps of all seeds over that wall time. On a short
  off-policy budget the evaluations can take most of the wall: ``--evals 3`` evaluates before training,
  half-way and at the end.

MuJoCo Playground's tasks (``--tasks playground:<Name>`` of its ``dm_control_suite``; the ``playground``
extra): the row is Playground's own ``brax_ppo_config`` / ``brax_sac_config``
(:func:`train.presets.playground_row`: its steps, envs, batch, unroll, epochs, mini-batches, discount, reward
scaling, learning rate, entropy cost, normalisation, episode length, action repeat), brax's side trains the
Playground env wrapped by Playground's ``wrapper.wrap_for_brax_training`` (as Playground's training scripts
do), ours the same env object through :class:`envs_mjx.playground.PlaygroundEnv`, converted as brax's rows
(:func:`train.presets.ppo_config_of_row`, brax's own update; :func:`train.presets.ddpg_config_of_sac_row`);
``--env-config`` gives Playground's ``config_overrides`` (``impl=jax`` unless given)::

    python -m benchmarks.brax_tasks --tasks playground:CartpoleBalance playground:CartpoleSwingup \
        playground:PendulumSwingup playground:ReacherEasy playground:CheetahRun playground:WalkerWalk \
        --seeds 3 --label playground                                # Playground's own step counts

Each side's record is written as it grows (ours with ``--seed-map vmap``: after every evaluation; seeds
one after another: after every evaluation of the first seed, then after every seed), so a run cut short
(a time limit) leaves its evaluations so far, shown as ``cut at N steps`` and not compared with the other
side.

Goals: per task our return ≥ brax's and our wall per seed ≤ brax's. Results:
``benchmarks/results/<device>-brax_tasks[-<algo>].json`` and ``.md`` with one learning-curve figure per task.
"""

from __future__ import annotations

import argparse
import json
import os
import time
from collections.abc import Callable, Sequence
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from benchmarks import provenance, stats
from benchmarks import seeds as bench_seeds
from benchmarks.arguments import at_least, nonnegative, positive
from benchmarks.tracking_report import pairs
from benchmarks.train_throughput import RESULTS, device_label
from envs_mjx.base import ActionRepeatWrapper
from envs_mjx.config import ConfigError, apply_overrides
from jaxrl_robot import parallel, plots
from jaxrl_robot.agents import ddpg, ppo, sac
from jaxrl_robot.evaluation import run_test_episodes, two_policies
from jaxrl_robot.types import Trainer
from train.presets import (
    BRAX_PPO,
    BRAX_SAC,
    TD3_OWN,
    brax_ppo_config,
    brax_sac_ddpg_config,
    ddpg_config_of_sac_row,
    playground_row,
    playground_task,
    ppo_config_of_row,
)
from train.sac import sac_config
from train.td3 import TD3_SETTINGS

ALGOS = {"ppo": ("PPO", "ppo", BRAX_PPO), "td3": ("TD3", "sac", BRAX_SAC), "ddpg": ("DDPG", "sac", BRAX_SAC),
         "sac": ("SAC", "sac", BRAX_SAC)}
"""``--algo``: (our algorithm's name, brax's peer, the table of tasks and settings)."""


PLAYGROUND = "playground:"
"""The prefix of a MuJoCo Playground task (``playground:CartpoleBalance``)."""


def is_playground(task: str) -> bool:
    """Whether ``task`` is a MuJoCo Playground env (``playground:<Name>``) rather than one of brax's."""
    return task.startswith(PLAYGROUND)


def brax_row(task: str, num_envs: int, algo: str = "ppo") -> dict[str, float]:
    """The task's row of ``algo``'s table (a ``playground:<Name>`` task: MuJoCo Playground's own settings of
    ``algo``'s brax peer, :func:`train.presets.playground_row`); with ``num_envs`` that many envs (PPO: the
    batch scaled alike, the same unrolls per env and mini-batches per pass: a small machine's version of the
    task)."""
    row = playground_row(task, ALGOS[algo][1]) if is_playground(task) else dict(ALGOS[algo][2][task])
    if num_envs:
        if algo == "ppo":
            row["batch_size"] = max(1, int(row["batch_size"] * num_envs) // int(row["num_envs"]))
        row["num_envs"] = num_envs
    return row


def whole_epochs(steps: int, per_step: int, num_evals: int) -> int:
    """The env steps of ``num_evals − 1`` epochs (at least one) of whole training steps of ``per_step`` env
    steps that cover ``steps``: each epoch ``ceil`` of its share of the budget, as brax's trainers count."""
    epochs = max(num_evals - 1, 1)
    return epochs * per_step * -(-max(steps, 0) // (epochs * per_step))


def brax_ppo_steps(row: dict[str, float], steps: int, num_evals: int = 10) -> int:
    """The env steps brax's ``ppo.train`` makes of a ``steps`` budget: whole training steps of
    ``batch_size · num_minibatches · unroll_length · action_repeat`` env steps, ``ceil`` of the budget over
    ``num_evals − 1`` epochs of them (brax/training/agents/ppo/train.py), so never fewer than ``steps``; with
    the row's ``num_resets_per_eval`` R (MuJoCo Playground's rows: 10) an epoch is R rounds of ``ceil`` of
    the budget over ``(num_evals − 1) · R`` training steps."""
    per_step = int(row["batch_size"]) * int(row["num_minibatches"]) * int(row["unroll_length"])
    resets = max(int(row.get("num_resets_per_eval", 0)), 1)
    return whole_epochs(steps, per_step * int(row.get("action_repeat", 1)) * resets, num_evals)


def brax_sac_steps(row: dict[str, float], steps: int, num_evals: int = 10) -> int:
    """The env steps brax's ``sac.train`` makes of a ``steps`` budget (brax/training/agents/sac/train.py):
    a prefill of ``ceil(min_replay_size / num_envs)`` actor steps, then ``num_evals − 1`` epochs of
    ``ceil((steps − prefill) / ((num_evals − 1) · num_envs · action_repeat))`` actor steps each, an actor
    step being ``num_envs · action_repeat`` env steps; so never fewer than ``steps``."""
    per_step = int(row["num_envs"]) * int(row.get("action_repeat", 1))
    prefill = -(-int(row["min_replay_size"]) // int(row["num_envs"])) * per_step
    return prefill + whole_epochs(steps - prefill, per_step, num_evals)


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


EVAL_MODES = ("stochastic", "deterministic")
"""How the final evaluation acts: the policy's sampled actions (brax's default) or its mean action."""


def default_eval_mode(algo: str) -> str:
    """``--eval-mode`` unless given: PPO's sampled actions (brax's default); for TD3 and DDPG, whose only
    policy is deterministic, the mean action on both sides (brax's SAC with ``deterministic_eval``)."""
    return "stochastic" if algo == "ppo" else "deterministic"


def eval_mode(side: dict[str, Any], name: str) -> str:
    """The evaluation mode of a side's record; records without one: ours deterministic, brax's sampled
    (brax's ``deterministic_eval=False`` default, which the peer kept until the mode was recorded)."""
    return side.get("eval_mode", "deterministic" if name == "ours" else "stochastic")


def our_returns(side: dict[str, Any], mode: str) -> list[float] | None:
    """Our returns per seed in evaluation ``mode``, or None where that mode was not measured."""
    if eval_mode(side, "ours") == mode:
        return side["returns"]
    return side.get("returns_deterministic") if mode == "deterministic" else None


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


def training_wall_per_seed(side: dict[str, Any]) -> float | None:
    """A side's training wall per seed with compilation apart: the seconds from its second evaluation to its
    last (every program compiled by then: training and the last evaluation), scaled to all its env steps and
    divided among the seeds of one program (``seeds_per_program``: ours vmapped, 1 for a seed alone), averaged
    over programs. None where the record has no evaluation times (``curve_wall_s``: per program the seconds
    since its start at each evaluation), fewer than three evaluations, or was cut short."""
    walls, steps = side.get("curve_wall_s"), side.get("curve_steps") or []
    if not walls or len(steps) < 3 or side.get("cut") or any(len(w) != len(steps) for w in walls):
        return None
    scale = side["env_steps"] / (steps[-1] - steps[1])
    return float(np.mean([(w[-1] - w[1]) * scale for w in walls])) / side.get("seeds_per_program", 1)


def return_ratio(ours: float, brax: float) -> float:
    """Ours over brax's mean, or brax's over ours where brax's is negative (a cost): above 1 where our mean is
    higher. A ratio of means says nothing of the seeds' spread: whether ours is ahead beyond it is
    :func:`benchmarks.stats.compare`'s verdict, which the report gives beside."""
    if not brax or not ours:
        return float("nan")
    return ours / brax if brax > 0 else brax / ours


def to_markdown(result: dict[str, Any]) -> str:
    name, peer, _ = ALGOS[result.get("algo", "ppo")]
    table = "BRAX_PPO`, ours with the task's fields of `train.presets.BRAX_PPO_TUNED` unless `--ours tuned=false" \
        if peer == "ppo" else "BRAX_SAC"
    source = f"`train.presets.{table}`"
    pg = [t["task"] for t in result["tasks"] if is_playground(t["task"])]
    if pg:
        source += ("; on MuJoCo Playground's tasks its own `brax_" + ("ppo" if peer == "ppo" else "sac")
                   + "_config` (`train.presets.playground_row`; ours through the same conversion), brax's side on "
                   "the env wrapped by Playground's `wrapper.wrap_for_brax_training` as its training scripts do, "
                   f"Playground config_overrides {result.get('playground_config', {})}")  # fmt: skip
    where = "MuJoCo Playground's tasks" if len(pg) == len(result["tasks"]) else "brax's tasks"
    out = [f"# Our {name} beside brax's {peer.upper()} on {where} — {result['device']}", "",
           f"Backend `{result['backend']}`; {result['seeds']} seeds of ours ({result['seed_map']}), "
           f"{result['brax_seeds']} of brax's (one after another); the same env steps and settings "
           f"({source}). Return: each side's final evaluation on fresh episodes (ours: "
           f"{result['eval_episodes']} episodes; brax: 128) in the mode its column names — sampled actions "
           "(brax's default) or the mean action; ours also with the mean action; ± the std over seeds. Wall: "
           "compilation included; compile apart: from a side's second evaluation to its last, scaled to all its env "
           "steps, per seed (`training_wall_per_seed`; — where the record has no evaluation times). "
           "Ours against brax's: the difference of the means with its 95 % confidence "
           "interval (Welch's t) and Mann–Whitney's two-sided p, seeds per side; **ahead** / behind only where the "
           "interval excludes 0, else level (`benchmarks/stats.py`). Bold: ahead in the same mode; our wall per "
           "seed ≤ brax's."
           + (f" Merged from {len(result['sources'])} invocations (`--merge`; each one's provenance below)."
              if result.get("merged_from") else ""), "",
           "| task | env steps | brax return | our return, same mode | our return, mean action "
           "| ours − brax, same mode (95 % CI; Welch), Mann–Whitney p, seeds ours vs brax "
           "| brax wall per seed s | our wall per seed s | compile apart, brax / ours s | brax env steps/s "
           "| our env steps/s | ratio of the means |",
           "|---|---:|---:|---:|---:|---|---:|---:|---:|---:|---:|---:|"]  # fmt: skip
    words = {"stochastic": "sampled", "deterministic": "mean action"}
    for t in result["tasks"]:
        b, o = t["brax"], t["ours"]
        mode = eval_mode(b, "brax")
        same, mean = our_returns(o, mode), our_returns(o, "deterministic")
        rb, ro = np.mean(b["returns"]), np.mean(same) if same else float("nan")
        whole = not (b.get("cut") or o.get("cut"))  # a side cut short is not compared
        versus = stats.compare(same or [], b["returns"]) if whole else None
        won, fast = whole and versus["verdict"] == "ahead", whole and o["wall_per_seed_s"] <= b["wall_per_seed_s"]
        verdict = stats.words(versus) if versus else "not compared (a side cut short)"
        verdict = verdict.replace("ahead:", "**ahead**:", 1)
        cell = f"{ro:.1f} ± {np.std(same):.1f}" if same else "not measured"
        cut = f" (cut at {o['env_steps']:,} steps)" if o.get("cut") else ""
        cell += cut
        mean_cell = f"{np.mean(mean):.1f} ± {np.std(mean):.1f}{cut}" if mean else "not measured"
        wall = f"{o['wall_per_seed_s']:.0f}"
        short = len(b["returns"]) < result["brax_seeds"] and not np.isnan(rb)  # a killed run: the seeds it finished
        seeds_done = f" ({len(b['returns'])} of {result['brax_seeds']} seeds)" if short else ""
        seeds_done += f" (cut at {b['env_steps']:,} steps)" if b.get("cut") else ""
        mode_word = "" if np.isnan(rb) else f" ({words[mode]})"
        apart = " / ".join("—" if w is None else f"{w:.0f}" for w in map(training_wall_per_seed, (b, o)))
        out.append(f"| {t['task']} | {o['env_steps']:,} | {rb:.1f} ± {np.std(b['returns']):.1f}{mode_word}"
                   f"{seeds_done} | {'**' + cell + '**' if won else cell} | {mean_cell} | {verdict} "
                   f"| {b['wall_per_seed_s']:.0f} | {'**' + wall + '**' if fast else wall} | {apart} "
                   f"| {b['env_steps_per_s']:,.0f} | {o['env_steps_per_s']:,.0f} "
                   f"| {return_ratio(ro, rb):.2f} |")  # fmt: skip
    out.append("")
    if result.get("note"):
        out += [result["note"], ""]
    for t in result["tasks"]:
        if t["ours"].get("overrides"):
            given = " ".join(f"{k}={v}" for k, v in t["ours"]["overrides"].items())
            out += [f"Ours on {t['task']} with `--ours {given}` over the preset.", ""]
        if t["ours"].get("devices", 1) > 1:
            out += [f"Ours on {t['task']}: each seed's lanes spread over {t['ours']['devices']} devices.", ""]
    for t in result["tasks"]:
        out.append(f"![{t['task']}]({os.path.basename(result['figures'])}/{t['task'].replace(':', '-')}.png)")
    return "\n".join(out) + "\n"


def figure(task: dict[str, Any], out_dir: str) -> str | None:
    """Each side's evaluations (our records from before evaluations along training: the mean return of
    the training episodes that ended in each chunk), labelled with the mode they were measured in."""
    words = {"stochastic": "sampled actions", "deterministic": "mean action"}
    labels = {"ours": f"ours: evaluations, {words[eval_mode(task['ours'], 'ours')]}"
              if task["ours"].get("curve_kind") == "evaluation" else "ours: training episodes, sampled actions",
              "brax": f"brax: evaluations, {words[eval_mode(task['brax'], 'brax')]}"}  # fmt: skip
    curves = {
        labels[name]: [[{"env_steps": x, "episode_return": y}
                        for x, y in zip(task[name]["curve_steps"], seed, strict=True)]
                       for seed in task[name]["curves"]]
        for name in ("ours", "brax") if task.get(name, {}).get("curves")
    }  # fmt: skip
    name = task["task"].replace(":", "-")  # playground:<Name> → a file name every file system and copy takes
    return plots.plot_seed_bands(curves, "episode_return", out_dir, f"{name}.png", task["task"])


def main(argv: list[str] | None = None) -> dict[str, Any]:
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--algo", default="ppo", choices=list(ALGOS), help="ours: ppo (brax's PPO beside) or td3 / ddpg / "
                   "sac (brax's SAC beside)")  # fmt: skip
    p.add_argument("--tasks", nargs="+", default=None, metavar="TASK",
                   help=f"PPO: {', '.join(BRAX_PPO)} (default: all); TD3 / DDPG: {', '.join(BRAX_SAC)} (default: all)")
    p.add_argument("--seeds", type=positive, default=3)
    p.add_argument("--purpose", default="tune", choices=bench_seeds.PURPOSES,
                   help="both sides' seeds: the tuning range or the report range, which no tuning run draws "
                   "(benchmarks.seeds)")  # fmt: skip
    p.add_argument("--brax-seeds", type=nonnegative, default=0, help="brax's seeds (0: --seeds)")
    p.add_argument("--brax-first-seed", type=nonnegative, default=0,
                   help="brax's first seed in the purpose's range (its seeds split over invocations, e.g. two GPUs, "
                   "then --merge)")  # fmt: skip
    p.add_argument("--steps", type=nonnegative, default=0, help="env steps per seed (0: brax's budget of the task)")
    p.add_argument("--backend", default="mjx", help="brax physics backend (mjx, generalized, positional, spring)")
    p.add_argument("--env-config", nargs="*", default=[], metavar="KEY=VALUE",
                   help="playground:<Name> tasks: MuJoCo Playground's config_overrides (impl=jax unless given, e.g. "
                   "impl=warp)")  # fmt: skip
    p.add_argument("--eval-episodes", type=positive, default=128)
    p.add_argument("--evals", type=at_least(2), default=10,
                   help="evaluations of each side along training, the first before it (brax's num_evals; at "
                   "least 2); fewer cost less where they take much of a short run")  # fmt: skip
    p.add_argument("--eval-mode", default=None, choices=EVAL_MODES,
                   help="final evaluation of both sides: sampled actions (PPO's default, brax's) or the mean "
                   "action (TD3's and DDPG's default: they act deterministically); ours is also evaluated "
                   "with its mean action either way")  # fmt: skip
    p.add_argument("--num-envs", type=nonnegative, default=0,
                   help="envs of both trainers, batch scaled alike (0: the row's)")
    p.add_argument("--row", nargs="*", default=[], metavar="KEY=VALUE",
                   help="settings of both trainers in brax's terms over the task's row (e.g. min_replay_size=1024)")
    p.add_argument("--ours", nargs="*", default=[], metavar="KEY=VALUE",
                   help="our config's fields over the preset (PPOConfig / DDPGConfig), e.g. activation=swish "
                   "tanh_actions=true clip_actions=false")  # fmt: skip
    p.add_argument("--no-brax", action="store_true", help="ours only")
    p.add_argument("--no-ours", action="store_true", help="brax's only (e.g. on another GPU, then --merge)")
    p.add_argument("--merge", nargs="+", default=None, metavar="JSON",
                   help="write one report from results files of this benchmark (e.g. ours and brax's run on two "
                   "GPUs at once): per task, our side and brax's from the files that ran them")  # fmt: skip
    p.add_argument("--brax-from", nargs="+", default=[], metavar="JSON",
                   help="with --merge: brax's side alone from these results files (e.g. brax's SAC beside our TD3, "
                   "now beside our SAC); their own side of ours is left out")  # fmt: skip
    p.add_argument("--seed-map", default="loop", choices=["loop", "vmap"],
                   help="our seeds: one program called per seed, or one vmapped program (an accelerator's only: "
                   "XLA's CPU compiler stops with a floating point exception on the vmapped MJX program, "
                   "jax 0.10.2)")  # fmt: skip
    p.add_argument("--devices", type=nonnegative, default=1,
                   help="devices our lanes are spread over (0: all; more than 1 with --seed-map loop)")
    p.add_argument("--out", default=RESULTS)
    p.add_argument("--label", default="", help="appended to the results files' name (e.g. 5M)")
    p.add_argument("--note", default="", help="a paragraph written under the table (e.g. how to read it)")
    provenance.add_args(p)
    args = p.parse_args(argv)
    if args.brax_from and not args.merge:
        p.error("--brax-from: only with --merge (the files whose side of ours is merged)")
    if args.merge:
        return merge(args.merge, args.out, argv, args.label, args.note, args.brax_from)
    if args.no_brax and args.no_ours:
        p.error("--no-brax and --no-ours: nothing would run; give at most one")
    if not 0 <= args.devices <= jax.device_count():
        p.error(f"--devices {args.devices}: this machine has {jax.device_count()} (0: all of them)")
    if args.seed_map == "vmap" and not args.no_ours and jax.default_backend() == "cpu":
        p.error("--seed-map vmap: on the CPU, XLA stops with a floating-point exception compiling our trainer "
                "vmapped over seeds on brax's MJX envs (jax 0.10.2); use --seed-map loop")
    if args.seed_map == "vmap" and args.seeds > 1 and (args.devices or jax.device_count()) > 1:
        p.error(f"--seed-map vmap runs its {args.seeds} seeds on one device; add --devices 1 or --seed-map loop")
    args.eval_mode = args.eval_mode or default_eval_mode(args.algo)
    if args.evals < 2:
        p.error(f"--evals {args.evals}: at least 2 (one before training, one at its end)")
    table = ALGOS[args.algo][2]
    args.tasks = args.tasks or list(table)
    try:
        unknown = [t for t in args.tasks if not (playground_task(t, args.algo) if is_playground(t) else t in table)]
    except ValueError as e:  # MuJoCo Playground is not installed
        p.error(f"--tasks: {e}")
    if unknown:
        p.error(f"--tasks {unknown[0]!r}: no brax settings for --algo {args.algo}; valid: {', '.join(table)} or "
                f"{PLAYGROUND}<Name> of MuJoCo Playground's dm_control_suite")  # fmt: skip
    overrides = pairs(args.ours)
    try:  # a bad --ours field ends here with one line, before anything trains
        our_config(args.algo, args.tasks[0], 1, brax_row(args.tasks[0], args.num_envs, args.algo), 1, overrides)
    except ConfigError as e:
        p.error(f"--ours: {e}")
    from brax import envs as brax_envs

    brax_seeds = args.brax_seeds or args.seeds
    try:
        our_ids = bench_seeds.seed_ids(args.purpose, args.seeds)
        brax_ids = bench_seeds.seed_ids(args.purpose, brax_seeds, args.brax_first_seed)
    except ValueError as e:
        p.error(f"--seeds/--brax-first-seed: {e}")
    prov = provenance.record("benchmarks.brax_tasks", argv, allow_dirty=args.allow_dirty,
                             seeds=bench_seeds.record(args.purpose, our_ids, "ours: training key PRNGKey(seed), "
                                                      f"evaluation key fold_in(PRNGKey(seed), EVAL_KEY_OFFSET); brax: "
                                                      f"its seed argument {brax_ids[0]}..{brax_ids[-1]}"))  # fmt: skip
    stem = stem_of(args.out, device_label(), args.algo, args.label)
    env_config = pairs(args.env_config)
    result = {"benchmark": "brax_tasks", "algo": args.algo, "provenance": prov, "device": device_label(),
              "backend": args.backend, **({"note": args.note} if args.note else {}),
              **({"playground_config": {"impl": "jax", **env_config}} if any(map(is_playground, args.tasks)) else {}),
              "seeds": args.seeds, "seed_map": args.seed_map, "brax_seeds": brax_seeds,
              "eval_episodes": args.eval_episodes, "evals": args.evals,
              "figures": stem + "-figures", "tasks": []}  # fmt: skip
    os.makedirs(result["figures"], exist_ok=True)
    for task in args.tasks:
        env, theirs_env, wrap_env_fn = playground_envs(task, env_config) if is_playground(task) else (
            (brax_envs.get_environment(task, backend=args.backend),) * 2 + (None,))  # fmt: skip
        published = brax_row(task, args.num_envs, args.algo)
        steps = args.steps or int(published["num_timesteps"])
        settings = {**published, **pairs(args.row)}
        counts = brax_ppo_steps if args.algo == "ppo" else brax_sac_steps
        our_steps = counts(settings, steps, args.evals)  # brax's count of env steps
        row = {"task": task, "settings": settings, "sides": []}
        result["tasks"].append(row)
        if not args.no_ours:
            row["sides"].append("ours")  # before it runs: a run cut short keeps its evaluations so far

            def ours_so_far(record: dict[str, Any], row: dict[str, Any] = row) -> None:  # a killed run keeps it
                row["ours"] = record
                write(stem, result)

            row["ours"] = ours(env, task, settings, our_steps, args.seeds, args.eval_episodes, args.seed_map,
                               args.algo, args.eval_mode, overrides, args.evals, ours_so_far,
                               args.devices, our_ids)  # fmt: skip
            print(task, "ours", [round(r, 1) for r in row["ours"]["returns"]], f"{row['ours']['wall_s']:.0f} s",
                  flush=True)  # fmt: skip
        if not args.no_brax:
            row["sides"].append("brax")

            def partial(record: dict[str, Any], row: dict[str, Any] = row) -> None:  # a killed run keeps its seeds
                row["brax"] = record
                write(stem, result)

            theirs(theirs_env, settings, steps, brax_seeds, ALGOS[args.algo][1], partial, args.eval_mode,
                   brax_ids[0], args.evals, wrap_env_fn)
            print(task, "brax", [round(r, 1) for r in row["brax"]["returns"]], f"{row['brax']['wall_s']:.0f} s",
                  flush=True)  # fmt: skip
        write(stem, result, echo=task == args.tasks[-1])
    return result


def playground_envs(task: str, config_overrides: dict[str, Any]) -> tuple[Any, Any, Callable[..., Any]]:
    """``(ours, brax's, wrap_env_fn)`` of a ``playground:<Name>`` task: one Playground env object
    (``impl='jax'`` unless ``config_overrides`` say otherwise), ours through :class:`envs_mjx.playground.PlaygroundEnv`,
    brax's as it is with Playground's ``wrapper.wrap_for_brax_training``, as Playground's training scripts
    wrap it for brax's trainers."""
    from envs_mjx import playground

    ours_env = playground.load(task, **config_overrides)
    return ours_env, ours_env.env, playground.require().wrapper.wrap_for_brax_training


def missing(side: dict[str, Any]) -> dict[str, Any]:
    """A side that did not run: NaN returns, no curves, the other side's steps (for the table's columns)."""
    kept = {k: v for k, v in side.items() if k != "cut"}  # the other side's state is not this one's
    return {**kept, "returns": [float("nan")], "returns_deterministic": [float("nan")], "curves": [],
            "overrides": {}, "wall_s": float("nan"),
            "wall_per_seed_s": float("nan"), "env_steps_per_s": float("nan")}  # fmt: skip


def write(stem: str, result: dict[str, Any], earlier: list[dict[str, Any]] = (), echo: bool = False) -> str:
    """The figures of every task and ``stem.json`` / ``stem.md``; a side that did not run shows as NaN."""
    os.makedirs(result["figures"], exist_ok=True)
    shown = dict(result, tasks=[])
    for row in result["tasks"]:
        shown_row = dict(row)
        for side, other in (("ours", "brax"), ("brax", "ours")):
            if side not in row:
                shown_row[side] = missing(row[other])
        figure(shown_row, result["figures"])
        shown["tasks"].append(shown_row)
    return provenance.write(stem, result, to_markdown(shown), earlier=list(earlier), echo=echo)


def join_seeds(a: dict[str, Any], b: dict[str, Any]) -> dict[str, Any]:
    """brax's record of two invocations: the seeds of both when they are different seeds of one setting
    (``seed_ids`` disjoint, same evaluation mode and env steps), else ``b`` (the later file wins). A record
    without ``seed_ids`` ran seeds 0, 1, … (the only seeds before ``--brax-first-seed``)."""
    ids_a, ids_b = (r.get("seed_ids") or list(range(len(r["returns"]))) for r in (a, b))
    same = eval_mode(a, "brax") == eval_mode(b, "brax") and all(a[k] == b[k] for k in ("env_steps", "curve_steps"))
    if not (ids_a and ids_b and same and not set(ids_a) & set(ids_b)):
        return b
    wall, steps = a["wall_s"] + b["wall_s"], len(ids_a) * a["env_steps"] + len(ids_b) * b["env_steps"]
    joined = {**b, "returns": a["returns"] + b["returns"], "curves": a["curves"] + b["curves"],
              "seed_ids": ids_a + ids_b, "wall_s": wall, "wall_per_seed_s": wall / (len(ids_a) + len(ids_b)),
              "env_steps_per_s": steps / wall}  # fmt: skip
    if "curve_wall_s" in a and "curve_wall_s" in b:
        joined["curve_wall_s"] = a["curve_wall_s"] + b["curve_wall_s"]
    else:
        joined.pop("curve_wall_s", None)  # one invocation's times alone would speak for seeds it did not run
    return joined


def stem_of(out: str, device: str, algo: str, label: str = "") -> str:
    """``<out>/<device>-brax_tasks[-<algo> unless ppo][-<label>]``: the results files' path without suffix."""
    return f"{out}/{device}-brax_tasks" + ("" if algo == "ppo" else f"-{algo}") + (f"-{label}" if label else "")


def _brax_side_only(part: dict[str, Any]) -> dict[str, Any]:
    """A results file's record with its tasks' brax side alone (``--brax-from``)."""
    tasks = [{"task": t["task"], "settings": t["settings"], "sides": ["brax"], "brax": t["brax"]}
             for t in part["tasks"] if "brax" in t]  # fmt: skip
    return {**part, "tasks": tasks}


def merge(paths: list[str], out: str, argv: list[str] | None = None, label: str = "", note: str = "",
          brax_from: Sequence[str] = ()) -> dict[str, Any]:  # fmt: skip
    """One report of several results files of one algorithm: per task (in the order first seen), our side
    from the last file that ran ours, brax's joined over files of different seeds (:func:`join_seeds`);
    named after the device of the last file that ran ours (each invocation's device is in its provenance);
    their provenance records (a merged file's own sources first) come first in the new file's, then the
    merge's own. ``note``: a paragraph under the table (a part's note is not carried over). ``brax_from``:
    files whose brax side alone is taken (first), e.g. brax's SAC run beside another of our algorithms; their
    brax peer must be the one of ``paths``' algorithm."""
    parts = []
    for path in [*brax_from, *paths]:
        with open(path) as f:
            parts.append(json.load(f))
    algos = {part.get("algo", "ppo") for part in parts[len(brax_from):]}
    if len(algos) != 1:
        raise SystemExit(f"--merge: the files are of different algorithms ({', '.join(sorted(algos))}); give one's")
    peer = ALGOS[next(iter(algos))][1]
    for path, part in zip(brax_from, parts, strict=False):
        if ALGOS[part.get("algo", "ppo")][1] != peer:
            raise SystemExit(f"--brax-from {path}: its brax side is brax's {ALGOS[part.get('algo', 'ppo')][1].upper()}"
                             f", not the {peer.upper()} beside --merge's {next(iter(algos))}")  # fmt: skip
    parts[: len(brax_from)] = [_brax_side_only(part) for part in parts[: len(brax_from)]]
    paths = [*brax_from, *paths]
    first = parts[len(brax_from)]
    tasks: dict[str, dict[str, Any]] = {}
    for part in parts:
        for row in part["tasks"]:
            merged = tasks.setdefault(row["task"], {"task": row["task"], "settings": row["settings"], "sides": []})
            # the sides a row holds (files from before a killed side was listed: the records present)
            for side in row.get("sides") or [name for name in ("ours", "brax") if name in row]:
                joins = side == "brax" and side in merged
                merged[side] = join_seeds(merged[side], row[side]) if joins else row[side]
                merged["sides"] = sorted(set(merged["sides"]) | {side}, reverse=True)
    for part, path in zip(parts, paths, strict=True):
        part["provenance"].setdefault("note", f"merged from {os.path.basename(path)}")
    ran_ours, ran_brax = ([p for p in parts if any(side in (r.get("sides") or r) for r in p["tasks"])]
                          for side in ("ours", "brax"))  # a file's seeds count for the sides it ran
    named = (ran_ours or parts)[-1]  # the file is named after the device our side last ran on
    stem = stem_of(out, named["device"], first.get("algo", "ppo"), label)
    prov = provenance.record("benchmarks.brax_tasks", argv, device_info=named["provenance"]["device"],
                             seeds="as in the invocations above", allow_dirty=True,  # merges figures, measures none
                             note="this file merges the results files of the invocations above")  # fmt: skip
    first = {**{k: v for k, v in first.items() if k != "note"}, "seed_map": (ran_ours or parts)[0]["seed_map"],
             "device": named["device"]}
    sources = [source for p in parts for source in [*p.get("sources", []), p["provenance"]]]
    result = {**first, "tasks": list(tasks.values()), "figures": stem + "-figures", "merged_from": paths,
              "seeds": max(p["seeds"] for p in ran_ours or parts),
              "brax_seeds": max([p["brax_seeds"] for p in ran_brax]
                                + [len(t["brax"]["returns"]) for t in tasks.values() if "brax" in t] or [0]),
              "provenance": prov, "sources": sources, **({"note": note} if note else {})}  # fmt: skip
    write(stem, result, earlier=result["sources"], echo=True)
    return result


if __name__ == "__main__":
    main()
