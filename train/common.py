"""The run experience shared by every algorithm's command line (``python -m train.<algo>``).

Interface for an algorithm
--------------------------
An algorithm supplies a :class:`jaxrl_robot.types.Trainer` — pure functions that this module
jits and drives:

* ``init(key) -> state``: the whole train state, a pytree of arrays (params, optimiser
  states, normalisers, replay, env states, RNG key, counters);
* ``update(state) -> (state, metrics)``: one *chunk* of training iterations under
  ``lax.scan``; ``metrics`` is a dict of scalars. Keys containing ``"loss"`` are checked for
  NaN/inf. Episode statistics (``episode_return``, ``success``, ``extra_distance``, any env
  metric) are means over the episodes that finished in the chunk, NaN if none did;
* ``policy(state) -> obs -> action``: the deterministic action for evaluation;
* ``num_updates`` chunks make the run; ``env_steps_per_update`` env steps each.

The algorithm's command line is an :class:`AlgorithmCLI`: an ``Args`` dataclass that extends
:class:`RunOptions` (the options every algorithm shares) with the algorithm's hyper-parameters,
the preset that gives their defaults and how the trainer is built. :func:`cli_main` joins the
processes of a run over several hosts, parses (the preset's defaults for ``--env`` first;
``--resume DIR`` reloads the run's ``config.json``), builds and calls :func:`run` with a
:class:`RunSpec`. :func:`run`:

1. makes ``runs/<algo>-<env>-<time>/`` and writes ``config.json`` (the CLI's full config,
   enough to rebuild the run — ``--resume DIR`` reloads it with :func:`load_config`);
2. initialises or restores the state (orbax, ``checkpoints/<chunk>/``) — a restored run
   continues exactly where the checkpoint left it; each checkpoint's files are checked against
   the SHA-256 sums saved with it, a damaged newest one is skipped for the newest good one, and a
   ``config.json`` that no longer builds the saved state is an error naming the arrays that differ.
   The run directory is locked (``.lock``) while a process writes it: a second one stops at once;
3. calls the jitted ``update`` chunk after chunk, writing ``metrics.csv`` and TensorBoard
   events (``tb/``), drawing a progress bar (only on a terminal, not under CI), saving a
   checkpoint every ``checkpoint_every`` chunks and at the end; SIGINT (Ctrl-C) or SIGTERM stops
   it after the current chunk with a checkpoint (a second Ctrl-C at once), and ``--resume`` continues;
4. stops with :class:`NonFiniteLossError` (naming the metric and env step) when a loss turns
   NaN/inf, after saving the last good state as a checkpoint;
5. evaluates the final policy — reaching envs: success over ``eval_episodes`` test episodes
   from fresh random starts and goals (a key stream apart from training) and the mean extra
   distance; tracking envs: the test episode from ``t = 0`` and the per-axis error sums —
   prints a table, writes ``eval.json`` and draws the figures (``*.png``). The test-episode
   program is compiled in a background thread while training runs, so evaluation at the end
   costs only its run time. ``--evals N`` also evaluates during training, after N chunks spread
   evenly over the run (the last one the final evaluation), with the same program, one row each in
   ``evals.csv``; their time is kept off the training clock (``train_s``) and counted in
   ``eval.json``'s ``periodic_eval_s`` (:mod:`train.periodic`).

Several processes
-----------------
With ``--coordinator``/``--num-processes``/``--process-id``, ``$JAX_COORDINATOR_ADDRESS`` or a
cluster launch that JAX detects (SLURM, Open MPI, Kubernetes), :func:`cli_main` calls
``jaxrl_robot.parallel.initialize_multihost`` before any JAX computation; the lane mesh then
spans the devices of every process and every process runs the same program. Process 0 alone
chooses the run directory (its name is broadcast to the others), writes ``config.json``,
``metrics.csv``, TensorBoard events, the figures and ``eval.json``, and prints. Checkpoints are
orbax's multi-process checkpoints: every process writes its own shards of the state into the
same ``checkpoints/<chunk>/`` (so the run directory must be on a filesystem every host sees)
and every process restores its shards on ``--resume``. The final policy is evaluated by every
process on its own devices from its copy of the replicated parameters (identical results).
"""

from __future__ import annotations

import argparse
import contextlib
import dataclasses
import functools
import json
import math
import os
import re
import signal
import sys
import threading
import time
from collections.abc import Callable, Mapping, Sequence
from concurrent.futures import Future, ThreadPoolExecutor
from typing import Any, ClassVar

import jax
import jax.numpy as jnp
import numpy as np
import tyro
from brax.envs.base import Env
from jax.sharding import Mesh

from jaxrl_robot import parallel
from jaxrl_robot.checkpoint import (
    Checkpointer,
    CheckpointError,
    CheckpointMismatchError,
    CheckpointWriteError,
    DirectoryInUseError,
    DirectoryLock,
    Restored,
)
from jaxrl_robot.compilation import ProgramCache, compile_log, enable_persistent_cache, resolve_cache_dir
from jaxrl_robot.evaluation import (
    PRECISION_THRESHOLDS,
    precision_summary,
    run_test_episodes,
    summarize_episodes,
    tracking_error_sums,
)
from jaxrl_robot.logging import MetricsLogger, read_csv
from jaxrl_robot.plots import plot_tracking, plot_training_curves
from jaxrl_robot.types import Trainer, as_recurrent
from train import periodic
from train.presets import BRAX_PPO_TUNED, BRAX_SAC_TUNED, brax_sac_task, brax_task, resolve_preset

__all__ = [
    "AlgorithmCLI",
    "NonFiniteLossError",
    "PeerLostError",
    "RunDirError",
    "RunOptions",
    "RunSettings",
    "RunSpec",
    "check_command_line",
    "check_options",
    "cli_main",
    "env_overrides",
    "episode_length",
    "evaluate",
    "evaluate_state",
    "evaluation_key",
    "evaluation_title",
    "is_main_process",
    "is_tracking_env",
    "iterations_per_chunk",
    "lane_mesh",
    "load_config",
    "lock_run_dir",
    "make_env",
    "make_run_dir",
    "mismatch_error",
    "preparse",
    "restore_run",
    "run",
    "settings_of",
    "use_progress_bar",
]

EVAL_KEY_OFFSET = 1_000_003
"""Folded into the seed's key for test episodes, so their starts and goals are not training's."""


class RunDirError(ValueError):
    """The run directory cannot be created (``--out``); the message names the path and the reason."""


class NonFiniteLossError(RuntimeError):
    """A loss became NaN or inf; the message names the metric, the env step and the last good checkpoint."""


class PeerLostError(RuntimeError):
    """Another process of a run over several processes stopped responding; the message names it and
    the run directory to resume (:func:`jaxrl_robot.parallel.lost_peer`)."""


MAX_SEED = 2**32 - 1
"""The largest ``--seed`` (``+ --seeds - 1``): JAX's keys take 32-bit seeds (larger ones alias smaller ones)."""


@dataclasses.dataclass
class RunSettings:
    """How a run is driven, saved and evaluated: the part of :class:`RunOptions` that
    :func:`run` reads (through :class:`RunSpec`)."""

    seed: int = 0
    """Random seed of the run (training), 0 to 2**32 - 1; evaluation uses a separate stream derived from it."""
    seeds: int = 1
    """Train this many seeds (seed, seed + 1, …; at least 1) in one run on one device; each writes its metrics,
    figures and ``eval.json`` to ``<run dir>/seed<k>/`` as the run of ``--seed k`` would, with the
    ``config.json`` of that run. 1: one run, written to the run directory itself."""
    seed_map: str = "auto"
    """With --seeds > 1: vmap (one program over the seeds), loop (the same compiled program once per
    seed each chunk) or auto (loop on the CPU, where XLA:CPU hangs on some vmapped-seed programs; else vmap)."""
    out: str = "runs"
    """Parent folder of the run directory runs/<algo>-<env>-<time>/."""
    checkpoint_every: int = 10
    """Chunks between checkpoints, at least 1 (the last chunk is always saved)."""
    eval_episodes: int = 100
    """Test episodes of the final evaluation (reaching envs; racecar: laps per road), at least 1. A run
    that finishes is always evaluated; one stopped early by --stop-after-steps is not."""
    precision: bool = True
    """Reaching envs with a goal threshold (arm7): also report success at 5, 2 and 1 cm."""
    evals: int = 0
    """Evaluations during training, 0 or more, spread evenly over the run's chunks (after chunk ceil(i·C/N) of C
    for i = 1…N, at most one per chunk; the last is the final evaluation), each the final evaluation's program on
    --eval-episodes episodes, one row each in <run dir>/evals.csv (train/periodic.py). 0: the final one alone."""
    stop_after_steps: int = 0
    """Stop early, resumably, once this many env steps are done (0: run to the end)."""
    progress: bool | None = None
    """Show a progress bar (default: only on a terminal and not under CI)."""

    ranges: ClassVar[dict[str, tuple[int, int | None]]] = {
        "seed": (0, MAX_SEED), "seeds": (1, None), "checkpoint_every": (1, None), "eval_episodes": (1, None),
        "stop_after_steps": (0, None), "evals": (0, None),
    }  # fmt: skip
    """The allowed ``[low, high]`` (None: no upper bound) of every count among the options, checked by
    :func:`check_options` before anything is built; a subclass extends it with its own counts."""


def settings_of(options: Any) -> dict[str, Any]:
    """The :class:`RunSettings` fields of ``options`` (a :class:`RunOptions`), as keywords."""
    return {f.name: getattr(options, f.name) for f in dataclasses.fields(RunSettings)}


@dataclasses.dataclass(kw_only=True)
class RunSpec(RunSettings):
    """What an algorithm's CLI hands to :func:`run`: the :class:`RunSettings` (``seed``, ``out``,
    ``checkpoint_every``, ``eval_episodes``, ``precision``, ``stop_after_steps``, ``progress``;
    ``progress=None`` decides by :func:`use_progress_bar`) and what the run is made of.

    Attributes:
      algo: algorithm name for the run directory (``"ppo"``).
      env_name: environment name for the run directory and reports.
      env: the unbatched environment (used for evaluation).
      trainer: the algorithm's :class:`~jaxrl_robot.types.Trainer`.
      config: JSON-able dict that rebuilds the run (saved as ``config.json``).
      run_dir: an existing run directory to resume (``None``: start a new run).
      episode_length: step limit of a test episode (0: ``env.episode_length``).
      compile_mark: :meth:`~jaxrl_robot.compilation.CompileLog.mark` taken when the command began:
        ``eval.json``'s ``compile`` counts the compilations since (None: since the process began).
      program_cache: where the run's programs (initialisation, chunk, evaluation) are kept between
        processes (:class:`~jaxrl_robot.compilation.ProgramCache`, keyed by ``config``); None: built here.
    """

    algo: str
    env_name: str
    env: Env
    trainer: Trainer
    config: dict[str, Any]
    run_dir: str | None = None
    episode_length: int = 0
    compile_mark: tuple | None = None
    program_cache: ProgramCache | None = None


def use_progress_bar() -> bool:
    """A bar only on an interactive terminal and not under CI."""
    return sys.stdout.isatty() and not os.environ.get("CI")


def is_main_process() -> bool:
    """Whether this is process 0 of the run (the only process of a one-process run)."""
    return jax.process_index() == 0


def _say(message: str) -> None:
    """Print on process 0 only."""
    if is_main_process():
        print(message, flush=True)


def _broadcast_text(text: str) -> str:
    """Process 0's ``text`` on every process (a collective: every process calls it)."""
    from jax.experimental import multihost_utils

    data = np.frombuffer(text.encode(), np.uint8) if is_main_process() else np.zeros(0, np.uint8)
    size = int(multihost_utils.broadcast_one_to_all(np.int32(data.size)))
    buf = data if is_main_process() else np.zeros(size, np.uint8)
    return bytes(np.asarray(multihost_utils.broadcast_one_to_all(buf), np.uint8)).decode()


def _local_view(tree: Any) -> Any:
    """``tree`` as arrays of this process: leaves every device holds whole → a copy on a local device,
    leaves split over several processes → None. With one process ``tree`` is returned as it is."""

    def local(x: Any) -> Any:
        if not isinstance(x, jax.Array) or x.is_fully_addressable:
            return x
        return x.addressable_data(0) if x.is_fully_replicated else None

    return jax.tree.map(local, tree)


def _to_host(tree: Any) -> Any:
    """Every leaf as a NumPy array of its global value, also for arrays that span several processes
    (split ones are gathered: a collective, so every process calls it)."""
    from jax.experimental import multihost_utils

    def fetch(x: Any) -> np.ndarray:
        if isinstance(x, jax.Array) and not x.is_fully_addressable and not x.is_fully_replicated:
            return np.asarray(multihost_utils.process_allgather(x, tiled=True))
        return np.asarray(x)

    return jax.tree.map(fetch, tree)


def process_age_s() -> float | None:
    """Seconds since this process started (Linux ``/proc``; None elsewhere): imports, device start and
    building the env and trainer, when called as a run begins."""
    try:
        with open("/proc/self/stat") as f:
            start_ticks = int(f.read().rsplit(")", 1)[1].split()[19])
        with open("/proc/uptime") as f:
            uptime = float(f.read().split()[0])
        return round(uptime - start_ticks / os.sysconf("SC_CLK_TCK"), 2)
    except (OSError, ValueError, IndexError):
        return None


def make_run_dir(out: str, algo: str, env_name: str) -> str:
    """Create ``out/<algo>-<env>-<YYYYmmdd-HHMMSS>`` (a numeric suffix if it exists).

    With several processes only process 0 creates it; every process gets its name.
    """
    if jax.process_count() > 1:
        return _broadcast_text(_new_run_dir(out, algo, env_name) if is_main_process() else "")
    return _new_run_dir(out, algo, env_name)


def _new_run_dir(out: str, algo: str, env_name: str) -> str:
    stamp = time.strftime("%Y%m%d-%H%M%S")
    base = os.path.join(out, f"{algo}-{env_name.replace(':', '_')}-{stamp}")
    path, i = base, 1
    while os.path.exists(path):
        path, i = f"{base}-{i}", i + 1
    try:
        os.makedirs(path)
    except OSError as e:
        raise RunDirError(f"--out {out!r}: cannot create the run directory {path!r} ({e.strerror or e})") from None
    return path


def load_config(run_dir: str) -> dict[str, Any]:
    """The ``config.json`` of a run directory (clear error if it is not one)."""
    path = os.path.join(run_dir, "config.json")
    if not os.path.isfile(path):
        raise FileNotFoundError(f"--resume {run_dir!r}: not a run directory (no config.json)")
    with open(path) as f:
        return json.load(f)


def _jsonable(x: Any) -> Any:
    if isinstance(x, dict):
        return {str(k): _jsonable(v) for k, v in x.items()}
    if isinstance(x, list | tuple):
        return [_jsonable(v) for v in x]
    if isinstance(x, np.generic | np.ndarray):
        return _jsonable(x.tolist())
    if isinstance(x, float) and not math.isfinite(x):
        return None
    return x


def _write_json(path: str, obj: Any) -> None:
    with open(path, "w") as f:
        json.dump(_jsonable(obj), f, indent=2, sort_keys=True)


def is_tracking_env(env: Env) -> bool:
    """Tracking envs (``scara``, ``unicycle``) expose ``axis_names`` and ``wrap_axes``."""
    return hasattr(env, "axis_names") and hasattr(env, "wrap_axes")


def evaluate(
    key: jax.Array,
    env: Env,
    policy: Callable,
    episodes: int,
    run_dir: str | None = None,
    episode_length: int = 0,
    episodes_fn: Callable[[jax.Array], dict[str, Any]] | None = None,
    precision: bool = False,
) -> dict[str, Any]:
    """Evaluate a deterministic policy; draws the tracking figures into ``run_dir`` if given.

    Tracking envs: ``envs_mjx.tracking.test_episode`` from ``t = 0`` → per-axis sums of
    |error| (plus means per step and the step count). Other envs: ``episodes`` test episodes
    → success rate, mean extra distance, mean return (whichever metrics the env has);
    ``episodes_fn(key)``, if given, is an already compiled :func:`final_episodes` of ``policy`` (with the
    same ``precision``): one program for both sets of episodes.
    With ``precision`` and an env whose config has ``goal_threshold`` (arm7): the same episodes
    again on the env with the smallest of ``PRECISION_THRESHOLDS`` and its own threshold, reported
    as ``success_5cm``, ``success_2cm``, ``success_1cm`` and the closest distance's median, 90th
    percentile and maximum (:func:`~jaxrl_robot.evaluation.precision_summary`).
    """
    if is_tracking_env(env):
        from envs_mjx import tracking

        policy = as_recurrent(policy)
        result = tracking.test_episode(env, policy.step, carry=policy.carry)
        axes = tuple(result["axis_names"])
        summary = tracking_summary(result, axes)
        if run_dir is not None:
            real = result["real_path"]
            ref = result["ref_path"]
            ok = np.isfinite(real[:, 0])
            plot_tracking(ref[ok], real[ok], result["abs_error"][: result["steps"]], run_dir, axes)
        return summary
    if is_racing_env(env):
        return race_evaluation(key, env, policy, episodes)
    if episodes_fn is None:
        strict = strict_env(env, precision)
        episodes_fn = jax.jit(functools.partial(
            final_episodes, env=env, strict=strict, policy=policy, episodes=episodes, episode_length=episode_length
        ))  # fmt: skip
    out = jax.device_get(episodes_fn(key))
    summary = summarize_episodes(out["episodes"])
    if "strict" in out:
        summary.update(precision_summary(out["strict"], PRECISION_THRESHOLDS))
    return {"kind": "episodes", **summary}


def tracking_summary(result: Mapping[str, Any], axes: tuple[str, ...]) -> dict[str, Any]:
    """:func:`evaluate`'s summary of a tracking env's test episode: ``result`` holds host values of
    ``envs_mjx.tracking.rollout`` (``abs_error [N, len(axes)]``, ``steps``, ``episode_return``)."""
    steps = int(result["steps"])
    summary = tracking_error_sums(np.asarray(result["abs_error"])[:steps], axes)
    summary["episode_return"] = float(result["episode_return"])
    return {"kind": "tracking", **summary}


def strict_env(env: Env, precision: bool) -> Env | None:
    """With ``precision``, ``env`` (a reaching env with ``config.goal_threshold``) at the smallest of
    ``PRECISION_THRESHOLDS`` and its own threshold (``env`` itself where that is its own), else None."""
    own = getattr(getattr(env, "config", None), "goal_threshold", None)
    if not precision or own is None:
        return None
    strict = min(PRECISION_THRESHOLDS + (own,))
    return env if strict == own else type(env)(env.config, goal_threshold=strict)


def final_episodes(
    key: jax.Array, env: Env, strict: Env | None, policy: Callable, episodes: int, episode_length: int = 0
) -> dict[str, Any]:
    """The final evaluation's episodes in one program: ``{"episodes": …}`` of ``env`` and, with a
    ``strict`` env (:func:`strict_env`), ``{"strict": …}``: the same starts and goals to its threshold
    (``run_test_episodes`` outputs, ``[episodes]`` each; the same episodes where ``strict`` is ``env``)."""
    limit = episode_length or None
    out = {"episodes": run_test_episodes(key, env, policy, episodes, limit)}
    if strict is not None:
        out["strict"] = out["episodes"] if strict is env else run_test_episodes(key, strict, policy, episodes, limit)
    return out


def is_racing_env(env: Env) -> bool:
    """Whether ``env`` is ``racecar`` (evaluated by laps on every road)."""
    from envs_mjx.racecar import RaceCar

    return isinstance(env, RaceCar)


def race_evaluation(key: jax.Array, env: Env, policy: Callable, laps: int) -> dict[str, Any]:
    """``laps`` one-lap test episodes on each road (thesis Tables 6.2-6.3) with the deterministic ``policy``:
    ``<road>/<outcome>`` counts (success, collision, out_of_track, stalled), ``<road>/overtakes`` (mean),
    ``<road>/speed_kmh``, ``<road>/rank`` and ``success_rate`` over every lap
    (:func:`envs_mjx.racecar.make_lap_test`)."""
    from envs_mjx.racecar import make_lap_test

    test = make_lap_test(env, laps)
    return race_summary(jax.device_get(jax.jit(lambda k: test(lambda e, s: policy(s.obs), k))(key)), laps)


def race_summary(result: Mapping[str, Any], laps: int) -> dict[str, Any]:
    """:func:`race_evaluation`'s summary of the host arrays of a lap test (``envs_mjx.racecar.make_lap_test``)."""
    from envs_mjx.racecar import lap_summary

    roads = lap_summary(result)
    flat: dict[str, Any] = {"kind": "racing", "laps_per_road": laps}
    flat["success_rate"] = sum(r["success"] for r in roads.values()) / (laps * len(roads))
    for road, row in roads.items():
        flat.update({f"{road}/{k}": v for k, v in row.items() if k != "laps"})
    return flat


def compile_evaluation_async(
    spec: RunSpec, key: jax.Array, state: Any
) -> Future[Callable[[jax.Array, Any], Any]] | None:
    """Compile ``(key, state) -> final_episodes(...)`` of ``spec.trainer.policy(state)`` in a thread.

    Returns a future of the compiled function, or None for tracking envs (their test episode
    is compiled when it runs). The thread overlaps XLA compilation with training. ``state`` is
    this process's view of the state (:func:`_local_view`): the evaluation runs on local devices.
    """
    if is_tracking_env(spec.env) or is_racing_env(spec.env):
        return None
    policy_of, env, n, limit = spec.trainer.policy, spec.env, spec.eval_episodes, spec.episode_length
    strict = strict_env(env, spec.precision)

    def evaluation(k: jax.Array, s: Any) -> dict[str, Any]:
        return final_episodes(k, env, strict, policy_of(s), n, limit)

    fn, cache = jax.jit(evaluation), spec.program_cache
    executor = ThreadPoolExecutor(max_workers=1, thread_name_prefix="compile-eval")
    if cache is None:
        future = executor.submit(lambda: fn.lower(key, state).compile())
    else:
        future = executor.submit(cache.compile, "evaluation", fn, key, state)
    executor.shutdown(wait=False)
    return future


def _compiled_episodes(future: Future | None) -> Callable[..., Any] | None:
    """The background-compiled evaluation, ``(key, state=…) -> episodes``; None if it failed (then
    compiled in line)."""
    if future is None:
        return None
    try:
        compiled = future.result()
    except Exception as e:  # compilation is retried in line by ``evaluate``
        print(f"background compilation of the evaluation failed ({type(e).__name__}: {e}); compiling now", flush=True)
        return None
    return lambda k, state: compiled(k, state)


def evaluation_during_training(spec: RunSpec) -> Callable[[jax.Array, Any], dict[str, Any]] | None:
    """``(key, state) -> summary`` (:func:`evaluate`'s) of one seed's state for the evaluations during training
    (``--evals``) of a tracking or racing env, whose final evaluation compiles its own program as it runs: one
    program over ``(key, state)``, compiled at its first call and run by every such evaluation (a tracking env's
    test episode from ``t = 0`` takes no key). None for other envs: theirs run the final evaluation's program
    (:func:`compile_evaluation_async`)."""
    env, policy_of = spec.env, spec.trainer.policy
    if is_tracking_env(env):
        from envs_mjx import tracking

        def episode(k: jax.Array, s: Any) -> dict[str, jax.Array]:
            policy = as_recurrent(policy_of(s))
            return tracking.rollout(env, policy.step, carry=policy.carry)

        axes, program = tuple(env.axis_names), jax.jit(episode)
        return lambda k, s: tracking_summary(jax.device_get(program(k, s)), axes)
    if is_racing_env(env):
        from envs_mjx.racecar import make_lap_test

        laps = spec.eval_episodes
        test = make_lap_test(env, laps)
        program = jax.jit(lambda k, s: test(lambda e, st: policy_of(s)(st.obs), k))
        return lambda k, s: race_summary(jax.device_get(program(k, s)), laps)
    return None


class _RunEvaluations:
    """A run's evaluation programs, each compiled once: the final evaluation's (``future`` of
    :func:`compile_evaluation_async`, None for tracking and racing envs), which the evaluations during training
    (``--evals``) run too, and for tracking and racing envs :func:`evaluation_during_training`'s."""

    def __init__(self, spec: RunSpec, future: Future | None):
        self._spec, self._future = spec, future
        self._final: Callable[..., Any] | None = None
        self._waited = False
        self._during: Callable[[jax.Array, Any], dict[str, Any]] | None = None

    def final(self) -> Callable[..., Any] | None:
        """The final evaluation's compiled program (:func:`_compiled_episodes`, waited for at the first call)."""
        if not self._waited:
            self._final, self._waited = _compiled_episodes(self._future), True
        return self._final

    def during(self, key: jax.Array, state: Any) -> dict[str, Any]:
        """One evaluation during training of one seed's ``state`` with ``key``: :func:`evaluate`'s summary."""
        if self._during is None:
            self._during = evaluation_during_training(self._spec) or self._episodes()
        return self._during(key, state)

    def _episodes(self) -> Callable[[jax.Array, Any], dict[str, Any]]:
        """:func:`evaluate_state` with the final evaluation's program (one compiled here where that failed)."""
        spec, compiled = self._spec, self.final()
        if compiled is None:
            strict = strict_env(spec.env, spec.precision)
            fn = jax.jit(lambda k, s: final_episodes(k, spec.env, strict, spec.trainer.policy(s), spec.eval_episodes,
                                                     spec.episode_length))  # fmt: skip
            compiled = lambda k, state: fn(k, state)  # noqa: E731
        return lambda k, s: evaluate_state(spec, k, s, None, compiled)


def evaluation_key(seed: int) -> jax.Array:
    """The key of the final evaluation of the run of ``--seed seed`` (a stream apart from training's)."""
    return jax.random.fold_in(jax.random.PRNGKey(seed), EVAL_KEY_OFFSET)


def evaluate_state(
    spec: RunSpec, key: jax.Array, state: Any, run_dir: str | None = None, compiled: Callable[..., Any] | None = None
) -> dict[str, Any]:
    """The final evaluation (:func:`evaluate`) of one seed's ``state``: ``spec.trainer.policy(state)`` on
    ``spec.env`` over ``spec.eval_episodes`` episodes; ``compiled``: :func:`compile_evaluation_async`'s program
    (``(key, state=…) -> episodes``, None: compiled here); tracking figures drawn into ``run_dir`` if given."""
    return evaluate(
        key, spec.env, spec.trainer.policy(state), spec.eval_episodes, run_dir, spec.episode_length,
        episodes_fn=None if compiled is None else functools.partial(compiled, state=state), precision=spec.precision,
    )  # fmt: skip


def evaluation_title(algo: str, env_name: str, seed: int | None = None) -> str:
    """The title of the evaluation table: ``"ppo on arm7: evaluation"`` (``seed``: one seed of several)."""
    return f"{algo} on {env_name}" + ("" if seed is None else f", seed {seed}") + ": evaluation"


def _print_table(title: str, rows: dict[str, Any]) -> None:
    from rich.console import Console
    from rich.table import Table

    table = Table(title=title)
    table.add_column("metric")
    table.add_column("value", justify="right")
    for k, v in rows.items():
        table.add_row(k, f"{v:.4g}" if isinstance(v, float) else str(v))
    Console(force_terminal=False, soft_wrap=True, width=100).print(table)


class _Progress:
    """A rich progress bar, or nothing."""

    def __init__(self, enabled: bool, total: int, done: int):
        self.enabled = enabled
        if not enabled:
            return
        from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeRemainingColumn

        self._bar = Progress(
            TextColumn("[bold]train"),
            BarColumn(),
            MofNCompleteColumn(),
            TextColumn("steps"),
            TimeRemainingColumn(),
            TextColumn("{task.fields[info]}"),
        )
        self._bar.start()
        self._task = self._bar.add_task("train", total=total, completed=done, info="compiling…")

    def update(self, done: int, info: str) -> None:
        if self.enabled:
            self._bar.update(self._task, completed=done, info=info)

    def close(self) -> None:
        if self.enabled:
            self._bar.stop()


def _progress_info(metrics: dict[str, float], sps: float) -> str:
    parts = [f"{sps:,.0f} steps/s"]
    for key, label in (("episode_return", "return"), ("success", "success"), ("pos_error", "tracking error")):
        v = metrics.get(key)
        if v is not None and math.isfinite(v):
            parts.append(f"{label} {v:.3g}")
    return "  ".join(parts)


STOP_SIGNALS = (signal.SIGINT, signal.SIGTERM)
"""Signals that stop a run after its current chunk, checkpointed (:func:`stop_on_signals`)."""


@contextlib.contextmanager
def stop_on_signals(enabled: bool = True):
    """While the block runs, SIGINT (Ctrl-C) and SIGTERM ask the run to stop after its current chunk;
    yields a dict whose ``"signal"`` holds the first such signal's number (0 while none came).  A second
    SIGINT interrupts at once.  Only in the main thread (where Python runs signal handlers) and when
    ``enabled`` (not across several processes, which must stop together); the previous handlers come back
    at the end of the block."""
    got = {"signal": 0}
    if not enabled or threading.current_thread() is not threading.main_thread():
        yield got
        return

    def handler(signum: int, frame: Any) -> None:
        got["signal"] = got["signal"] or signum
        signal.signal(signal.SIGINT, signal.default_int_handler)  # a second Ctrl-C: at once

    previous = {s: signal.getsignal(s) for s in STOP_SIGNALS}
    for s in STOP_SIGNALS:
        signal.signal(s, handler)
    try:
        yield got
    finally:
        for s, h in previous.items():
            signal.signal(s, h)


def run(spec: RunSpec) -> dict[str, Any]:
    """Train, log, checkpoint and evaluate as the module docstring describes, holding the run
    directory's lock (:func:`lock_run_dir`) throughout.

    Returns:
      ``{"run_dir", "finished", "env_steps", "wall_s", "compile_s", "eval"}`` (``eval`` only
      when the run finished).
    Raises:
      NonFiniteLossError: a loss became NaN/inf (the last good state is checkpointed first).
      DirectoryInUseError: another process writes the run directory.
      CheckpointMismatchError, CheckpointDamagedError: ``--resume`` found no checkpoint it can use
        (:func:`restore_run`).
      CheckpointWriteError: a checkpoint could not be written (disk full); earlier ones are kept.
      PeerLostError: another process of a run over several stopped responding.
      ValueError: a count of ``spec`` is out of range (:func:`check_options`).
    """
    check_options(spec)
    run_dir = spec.run_dir if spec.run_dir is not None else make_run_dir(spec.out, spec.algo, spec.env_name)
    parallel.set_peer_loss_note(f"the run can be resumed with --resume {run_dir}")
    lock = lock_run_dir(run_dir)
    try:
        return _run_locked(spec, run_dir)
    except Exception as e:
        lost = parallel.lost_peer(e)
        if lost is None:
            raise
        raise PeerLostError(f"{lost}; the run can be resumed with --resume {run_dir}") from e
    finally:
        if lock is not None:
            lock.release()


def lock_run_dir(run_dir: str) -> DirectoryLock | None:
    """Process 0's :class:`~jaxrl_robot.checkpoint.DirectoryLock` of ``run_dir`` (None on the others).

    Raises:
      DirectoryInUseError: on every process, when another process holds the lock.
    """
    lock, taken = None, ""
    if is_main_process():
        try:
            lock = DirectoryLock(run_dir).acquire()
        except DirectoryInUseError as e:
            taken = str(e)
    if jax.process_count() > 1:
        taken = _broadcast_text(taken)
    if taken:
        raise DirectoryInUseError(taken)
    return lock


def restore_run(ckpt: Checkpointer, state: Any, run_dir: str, config: dict[str, Any]) -> Restored | None:
    """The newest good checkpoint of ``run_dir`` restored into ``state``'s structure (None: none yet);
    prints (process 0, stderr) which damaged ones it skipped, or that it is unverified.

    Raises:
      CheckpointMismatchError: ``config`` (from ``config.json``) no longer builds the saved state; the
        message names the arrays that differ and the fields changed since the checkpoint was written.
      CheckpointDamagedError: every checkpoint is damaged.
    """
    try:
        restored = ckpt.restore_latest(state)
    except CheckpointMismatchError as e:
        raise mismatch_error(ckpt, e, f"--resume {run_dir}", config) from None
    if restored is not None and restored.note and is_main_process():
        print(restored.note, file=sys.stderr, flush=True)
    return restored


def mismatch_error(
    ckpt: Checkpointer, e: CheckpointMismatchError, where: str, config: dict[str, Any]
) -> CheckpointMismatchError:
    """``e`` (``config`` no longer builds the state saved at ``e.step``) as one line: ``where``, the arrays
    that differ and the fields of ``config`` changed since the checkpoint was written (its record's config)."""
    saved = _jsonable(ckpt.read_record(e.step).get("config") or {})
    changed = _changed_fields(saved, _jsonable(config)) if saved else []
    hint = f" (config.json changed since: {'; '.join(changed[:3])})" if changed else ""
    message = f"{where}: config.json does not match checkpoint {e.step}: {e.listed()}{hint}"
    return CheckpointMismatchError(e.step, e.differences, message)


def _changed_fields(saved: dict[str, Any], now: dict[str, Any], prefix: str = "") -> list[str]:
    """``"ppo.num_envs 16 then, 32 now"`` for each field that differs between two configs (nested dicts),
    leaving out the options a resumed run takes from its command line."""
    out = []
    for key in sorted(set(saved) | set(now)):
        a, b = saved.get(key), now.get(key)
        if key in ("resume", *COMMAND_LINE_FIELDS):
            continue
        if isinstance(a, dict) and isinstance(b, dict):
            out += _changed_fields(a, b, f"{prefix}{key}.")
        elif a != b:
            out.append(f"{prefix}{key} {a} then, {b} now")
    return out


def _run_locked(spec: RunSpec, run_dir: str) -> dict[str, Any]:
    """:func:`run` in ``run_dir`` (made or given), whose lock this process holds."""
    trainer = spec.trainer
    main = is_main_process()
    resuming = spec.run_dir is not None
    if not resuming and main:
        _write_json(os.path.join(run_dir, "config.json"), spec.config)
    _say(f"run directory: {run_dir}")

    t0 = time.perf_counter()
    startup_s = process_age_s()
    seeds = [spec.seed + i for i in range(spec.seeds)]
    several = len(seeds) > 1
    program = SeedProgram.of(trainer, len(seeds), spec.seed_map, spec.program_cache)
    state = program.init(seeds)
    seed_dirs = [os.path.join(run_dir, f"seed{k}") for k in seeds] if several else [run_dir]
    ckpt = Checkpointer(os.path.join(run_dir, "checkpoints"))
    chunk, wall_before, train_before = 0, 0.0, 0.0
    if resuming:
        restored = restore_run(ckpt, state, run_dir, spec.config)
        if restored is None:  # stopped before its first checkpoint: the saved config, from the start
            _say(f"--resume {run_dir}: no checkpoint yet; starting this run from the beginning with its saved config")
        else:
            state, record = restored.state, restored.record
            chunk, wall_before = int(record["chunk"]), float(record.get("wall_s", 0.0))
            train_before = float(record.get("train_wall_s", wall_before))
            _say(f"resumed at chunk {chunk} ({chunk * trainer.env_steps_per_update} env steps)")
    steps_per = trainer.env_steps_per_update
    loggers = []
    if main:
        for k, d in zip(seeds, seed_dirs, strict=True):
            os.makedirs(d, exist_ok=True)
            if several and not resuming:  # the config of this seed's run alone (--seed k)
                args = {**spec.config.get("args", {}), "seed": k, "seeds": 1}
                _write_json(os.path.join(d, "config.json"), {**spec.config, "args": args})
            loggers.append(MetricsLogger(d, keep_until_step=chunk * steps_per if resuming else None))
    total_steps = trainer.num_updates * steps_per
    stop_chunk = trainer.num_updates
    if spec.stop_after_steps > 0:
        stop_chunk = min(stop_chunk, max(chunk + 1, math.ceil(spec.stop_after_steps / steps_per)))
    show = main and (use_progress_bar() if spec.progress is None else spec.progress)
    bar = _Progress(show, total_steps, chunk * steps_per)
    eval_keys = [evaluation_key(k) for k in seeds]
    due = periodic.eval_chunks(spec.evals, trainer.num_updates)  # --evals: the chunks evaluated during training
    will_evaluate = stop_chunk >= trainer.num_updates and chunk < stop_chunk
    will_evaluate = will_evaluate or any(chunk < c <= stop_chunk for c in due)
    eval_future = (
        compile_evaluation_async(spec, eval_keys[0], program.view(_local_view(state), 0)) if will_evaluate else None
    )
    evaluations = _RunEvaluations(spec, eval_future)
    keep = periodic.kept_chunk(chunk, trainer.num_updates) if resuming else None
    eval_logs = [periodic.EvalLog(d, keep) for d in seed_dirs] if main and due else []
    eval_spent = 0.0  # seconds of evaluations during training, kept off the training clock

    def train_clock(t: float) -> float:
        """The training clock at ``time.perf_counter()`` ``t``: training's seconds, evaluations apart."""
        return train_before + t - t_loop - eval_spent

    def record(c: int, wall: float) -> dict[str, Any]:
        train_wall = train_clock(time.perf_counter())
        return {"chunk": c, "env_steps": c * steps_per, "wall_s": wall, "train_wall_s": train_wall,
                "config": _jsonable(spec.config)}  # fmt: skip

    def evaluate_during(c: int, s: Any) -> None:
        """Every seed's evaluation after chunk ``c`` (state ``s``), a row each in ``evals.csv`` (process 0)."""
        nonlocal eval_spent
        t = time.perf_counter()
        clock, since_start = train_clock(t), None if startup_s is None else startup_s + t - t0 - eval_spent
        local = _local_view(s)
        for i, key in enumerate(eval_keys):
            t_seed = time.perf_counter()
            summary = evaluations.during(periodic.key_at(key, c, trainer.num_updates), program.view(local, i))
            clocks = {"train_wall_s": clock, "process_s": since_start, "eval_s": time.perf_counter() - t_seed,
                      "startup_s": startup_s, "first_chunk_s": compile_s}  # fmt: skip
            for log in eval_logs[i : i + 1]:  # none off process 0
                log.add(periodic.row_of(c, c * steps_per, clocks, summary))
        eval_spent += time.perf_counter() - t

    compile_s, last_saved = None, chunk if resuming else -1
    t_loop = time.perf_counter()
    with contextlib.ExitStack() as stack:
        interrupt = stack.enter_context(stop_on_signals(jax.process_count() == 1))
        stack.callback(bar.close)
        for logger in loggers:
            stack.callback(logger.close)
        while chunk < stop_chunk:
            t_chunk = time.perf_counter()
            new_state, metrics = program.update(state)
            per_seed = program.per_seed(_to_host(metrics))
            dt = time.perf_counter() - t_chunk
            if compile_s is None:
                compile_s = dt
            bad = [(k, i) for i, m in enumerate(per_seed) for k, v in m.items() if "loss" in k and not math.isfinite(v)]
            if bad:
                if last_saved != chunk:
                    ckpt.save(chunk, state, record(chunk, wall_before + time.perf_counter() - t0))
                name, i = bad[0]
                raise NonFiniteLossError(
                    f"{name} is {per_seed[i][name]}" + (f" (seed {seeds[i]})" if several else "")
                    + f" after env step {(chunk + 1) * steps_per} (chunk {chunk + 1}); last good checkpoint: "
                    f"{ckpt.directory}/{chunk} at env step {chunk * steps_per}"
                )  # fmt: skip
            state, chunk = new_state, chunk + 1
            sps = steps_per * len(seeds) / max(dt, 1e-9)
            for logger, m in zip(loggers, per_seed, strict=False):  # no loggers off process 0
                logger.write(chunk * steps_per, {**m, "steps_per_s": sps})
            bar.update(chunk * steps_per, _progress_info(per_seed[0], sps))
            if chunk in due and chunk < trainer.num_updates:  # before its checkpoint (the final one: below)
                evaluate_during(chunk, state)
            if interrupt["signal"] and chunk < stop_chunk:
                stop_chunk = chunk  # saved just below, then the loop ends
            if chunk % spec.checkpoint_every == 0 or chunk == stop_chunk:
                ckpt.save(chunk, state, record(chunk, wall_before + time.perf_counter() - t0))
                last_saved = chunk
    jax.block_until_ready(state)
    train_s = time.perf_counter() - t_loop - eval_spent
    result: dict[str, Any] = {
        "run_dir": run_dir,
        "finished": chunk >= trainer.num_updates,
        "env_steps": chunk * steps_per,
        "compile_s": compile_s,
        "startup_s": startup_s,
        "train_s": train_s,
        "periodic_eval_s": eval_spent,
    }
    for logger, d in zip(loggers, seed_dirs, strict=False):  # no loggers off process 0
        plot_training_curves(read_csv(logger.path), d)
    if interrupt["signal"] and not result["finished"]:  # on the last chunk the run ends as it would anyway
        result["interrupted"] = int(interrupt["signal"])
        _say(f"{signal.Signals(interrupt['signal']).name}: stopped after chunk {chunk}, checkpoint saved")
    if not result["finished"]:
        result["wall_s"] = wall_before + time.perf_counter() - t0
        _say(f"stopped at {result['env_steps']} env steps; continue with --resume {run_dir}")
        ckpt.close()
        return result
    t_eval = time.perf_counter()
    local_state = _local_view(state)
    compiled = evaluations.final()
    summaries = []
    for i, (key, d) in enumerate(zip(eval_keys, seed_dirs, strict=True)):
        t_seed = time.perf_counter()
        summaries.append(evaluate_state(spec, key, program.view(local_state, i), d if main else None, compiled))
        since_start = None if startup_s is None else startup_s + t_eval - t0 - eval_spent
        clocks = {"train_wall_s": train_before + train_s, "process_s": since_start, "startup_s": startup_s,
                  "eval_s": time.perf_counter() - t_seed, "first_chunk_s": compile_s}  # fmt: skip
        for log in eval_logs[i : i + 1]:  # --evals: the final evaluation is the last row
            log.add(periodic.row_of(chunk, chunk * steps_per, clocks, summaries[-1]))
    result["eval_s"] = time.perf_counter() - t_eval
    result["compile"] = compile_log().since(spec.compile_mark)
    result["wall_s"] = wall_before + time.perf_counter() - t0
    if several:
        result["seeds"] = [
            {"seed": k, "run_dir": d, "eval": e} for k, d, e in zip(seeds, seed_dirs, summaries, strict=True)
        ]
    else:
        result["eval"] = summaries[0]
    if main:
        shared = {k: v for k, v in result.items() if k not in ("eval", "seeds")}
        for k, d, summary in zip(seeds, seed_dirs, summaries, strict=True):
            _write_json(os.path.join(d, "eval.json"), {**summary, **shared, **({"seed": k} if several else {})})
            title = evaluation_title(spec.algo, spec.env_name, k if several else None)
            _print_table(title, {**summary, "env_steps": result["env_steps"], "wall_s": round(result["wall_s"], 1)})
    ckpt.close()
    return result


SEED_MAPS = ("auto", "vmap", "loop")
"""How ``--seeds`` > 1 runs (:class:`SeedProgram`)."""


def resolve_seed_map(seed_map: str) -> str:
    """``'vmap'`` or ``'loop'``: ``seed_map``, with ``'auto'`` → ``'loop'`` on the CPU backend, else ``'vmap'``.

    Raises:
      ValueError: ``seed_map`` is not one of :data:`SEED_MAPS`.
    """
    if seed_map not in SEED_MAPS:
        raise ValueError(f"--seed-map {seed_map!r} is not a seed map; valid: {', '.join(SEED_MAPS)}")
    if seed_map == "auto":
        return "loop" if jax.default_backend() == "cpu" else "vmap"
    return seed_map


@dataclasses.dataclass(frozen=True)
class SeedProgram:
    """How the seeds of a run are trained: ``init(seeds) -> state``, ``update(state) -> (state,
    metrics)`` (jitted), ``view(tree, i)`` (seed ``i``'s part of a state) and ``per_seed(host
    metrics) -> [dict of floats]`` (one per seed).

    One seed: the trainer's own functions.  ``vmap``: one program over a leading seed axis of every
    leaf.  ``loop``: a tuple of the seeds' states, each chunk the same compiled ``update`` once per
    seed (XLA:CPU of jax 0.10 hangs running some vmapped-seed programs, e.g. PPO on arm7).  ``auto``:
    ``loop`` on the CPU backend, else ``vmap``.  Seed ``k``'s keys are those of a run with ``--seed k``
    in every mode.
    """

    init: Callable[[Sequence[int]], Any]
    update: Callable[[Any], tuple[Any, Any]]
    view: Callable[[Any, int], Any]
    per_seed: Callable[[Any], list[dict[str, float]]]

    @staticmethod
    def of(trainer: Trainer, n: int, seed_map: str = "auto", cache: ProgramCache | None = None) -> SeedProgram:
        """The program of ``n`` seeds of ``trainer`` under ``seed_map`` (one of :data:`SEED_MAPS`); its
        initialisation and chunk taken from ``cache`` when there (None: ``jax.jit``)."""
        mapping = resolve_seed_map(seed_map)
        floats = lambda m: {k: float(v) for k, v in m.items()}  # noqa: E731
        jit = jax.jit if cache is None else (lambda fn: cache.jit(getattr(fn, "__name__", "program"), fn))  # noqa: E731
        update = jit(trainer.update)
        if n == 1:
            init_one = jit(trainer.init)
            init = lambda seeds: init_one(jax.random.PRNGKey(seeds[0]))  # noqa: E731
            return SeedProgram(init, update, lambda tree, i: tree, lambda m: [floats(m)])
        if mapping == "loop":
            init_one = jit(trainer.init)

            def update_all(states: tuple) -> tuple[tuple, tuple]:
                out = [update(s) for s in states]
                return tuple(o[0] for o in out), tuple(o[1] for o in out)

            return SeedProgram(lambda seeds: tuple(init_one(jax.random.PRNGKey(k)) for k in seeds), update_all,
                               lambda tree, i: tree[i], lambda ms: [floats(m) for m in ms])  # fmt: skip

        init_vmapped = jit(jax.vmap(trainer.init))

        def init_all(seeds: Sequence[int]) -> Any:
            return init_vmapped(jnp.stack([jax.random.PRNGKey(k) for k in seeds]))

        return SeedProgram(init_all, jit(jax.vmap(trainer.update)),
                           lambda tree, i: jax.tree.map(lambda x: x[i], tree),
                           lambda m: [{k: float(v[i]) for k, v in m.items()} for i in range(n)])  # fmt: skip


# ---- the command line ---------------------------------------------------------------------------


@dataclasses.dataclass
class RunOptions(RunSettings):
    """The options of a run that every ``python -m train.<algo>`` shares (its ``Args`` extends this):
    the :class:`RunSettings` and the ones below."""

    env: str = "arm7"
    """Environment: a registered name (envs_mjx.names()), brax:<name> for brax's own envs or playground:<Name> for
    MuJoCo Playground's (pip install -e ".[playground]"; --env-config KEY=VALUE are its config_overrides, impl
    jax unless impl=warp)."""
    preset: str = "auto"
    """Hyper-parameter preset: auto (fast on a GPU, else cpu; brax on brax's tasks of PPO, DDPG and TD3, playground
    on MuJoCo Playground's dm_control_suite), thesis, cpu, fast, brax or playground (PPO, DDPG, TD3). PPO, A2C and
    A3C presets run arm7 in kinematic mode under thesis and cpu (--env-config overrides)."""
    reward: str | None = None
    """Reward function of the env (arm7: sparse, shaped, ordinary, path); None keeps the env's default."""
    env_config: tuple[str, ...] = ()
    """Further env settings as KEY=VALUE (e.g. mode=kinematic, trajectory=ellipse, obs=no_goal; playground:<Name>:
    Playground's config_overrides, e.g. impl=warp, episode_length=500)."""
    resume: str | None = None
    """Continue the run in this directory (its config.json is used; other flags are ignored).
    --stop-after-steps, --progress and the process options apply as given."""
    chunks: int = 50
    """Reporting chunks per run, at least 1: metrics, progress and checkpoints happen between chunks."""
    devices: int = 0
    """Devices to spread the lanes over, 0 to the device count (0: all devices, of every process in a run
    over several)."""
    coordinator: str | None = None
    """HOST:PORT of process 0 in a run over several processes (jax.distributed).
    None: $JAX_COORDINATOR_ADDRESS, else a detected SLURM / Open MPI / Kubernetes launch, else one process."""
    num_processes: int | None = None
    """Processes of a run over several processes (None: from the launcher's environment)."""
    process_id: int | None = None
    """This process's index, 0 to num_processes - 1 (None: from the launcher's environment)."""
    compile_cache: str = "auto"
    """Folder of JAX's persistent compilation cache, so that a second run skips compiling: auto
    ($JAXRL_ROBOT_COMPILE_CACHE, else $JAX_COMPILATION_CACHE_DIR, else ~/.cache/jaxrl-robot/xla), a
    folder, or off (also --no-compile-cache). Not saved in config.json."""

    ranges: ClassVar[dict[str, tuple[int, int | None]]] = {
        **RunSettings.ranges, "chunks": (1, None), "devices": (0, None), "num_processes": (1, None),
        "process_id": (0, None),
    }  # fmt: skip


PROCESS_FIELDS = ("coordinator", "num_processes", "process_id")
"""Where the run's processes are: always from the command line, never saved in ``config.json``."""

MACHINE_FIELDS = ("compile_cache",)
"""Options of this machine rather than of the run: taken from the command line, never saved in ``config.json``."""

COMMAND_LINE_FIELDS = ("stop_after_steps", "progress", *PROCESS_FIELDS, *MACHINE_FIELDS)
"""Options a resumed run takes from its command line instead of its ``config.json``."""

BRAX_PREFIX = "brax:"
PLAYGROUND_PREFIX = "playground:"


def parse_value(text: str) -> Any:
    """A ``--env-config`` value: JSON where it parses (lists become tuples), else the text."""
    try:
        value = json.loads(text)
    except json.JSONDecodeError:
        return text
    return tuple(value) if isinstance(value, list) else value


def env_overrides(args: Any) -> dict[str, Any]:
    """Env settings from ``--reward`` and ``--env-config KEY=VALUE``."""
    out: dict[str, Any] = {}
    if args.reward is not None:
        out["reward"] = args.reward
    for item in args.env_config or ():
        if "=" not in item:
            raise ValueError(f"--env-config {item!r}: expected KEY=VALUE")
        k, v = item.split("=", 1)
        out[k.strip().replace("-", "_")] = parse_value(v.strip())
    return out


def env_record(name: str, env: Any) -> dict[str, Any]:
    """``config.json``'s record of the env a run built: its name and every field of its config (the env's
    defaults with the preset's and the command line's settings over them; None for an env without a config
    dataclass, e.g. brax's), so that a run's setting can be read back whole."""
    config = getattr(env, "config", None)
    return {"name": name, "config": dataclasses.asdict(config) if dataclasses.is_dataclass(config) else None}


def check_backend_devices(overrides: Mapping[str, Any], devices: int) -> None:
    """Raise ``ValueError`` (one line, naming ``--devices``) when the env's physics runs on MuJoCo Warp
    (``impl=warp``) and the lanes would be spread over several devices: a Warp data shares some fields by
    all its lanes, which splitting the lanes over devices does not keep."""
    if str(overrides.get("impl", "jax")) == "warp" and devices > 1:
        raise ValueError(f"--env-config impl=warp runs its lanes on one device; add --devices 1 (the lanes "
                         f"would be spread over {devices})")  # fmt: skip


def make_env(name: str, overrides: dict[str, Any]) -> Env:
    """An unbatched env: ``envs_mjx.make(name, **overrides)``, ``brax.envs.get_environment`` (``brax:<name>``)
    or MuJoCo Playground's (``playground:<Name>``: ``envs_mjx.playground.load``, the overrides its
    ``config_overrides``, ``impl`` defaulting to ``jax``).

    Raises:
      ValueError: an unknown name (the message lists the valid ones), bad overrides, or ``playground:``
        without MuJoCo Playground installed (``PlaygroundMissingError``, naming the extra).
    """
    import envs_mjx

    if name.startswith(PLAYGROUND_PREFIX):
        from envs_mjx import playground

        playground.require(f"--env {name}")
        return playground.load(name, **overrides)
    if name.startswith(BRAX_PREFIX):
        from brax import envs as brax_envs

        bname = name[len(BRAX_PREFIX) :]
        if bname not in brax_envs._envs:
            raise ValueError(f"unknown brax environment {bname!r}; valid: {', '.join(sorted(brax_envs._envs))}")
        return brax_envs.get_environment(bname, **overrides)
    if name not in envs_mjx.names():
        raise ValueError(f"unknown environment {name!r}; valid names: {', '.join(envs_mjx.names())} "
                         f"(or {BRAX_PREFIX}<name>, {PLAYGROUND_PREFIX}<Name>)")
    return envs_mjx.make(name, **overrides)


def episode_length(env: Env, cfg_len: int = 0) -> int:
    """The configured time limit, else the env's ``episode_length``, else 1000 (brax's default)."""
    return int(cfg_len or getattr(env, "episode_length", 0) or 1000)


def iterations_per_chunk(total_iterations: int, chunks: int) -> int:
    """Iterations per reporting chunk so that ``chunks`` (>= 1) chunks cover ``total_iterations`` (at least 1)."""
    if chunks < 1:
        raise ValueError(f"--chunks {chunks} is out of range; allowed >= 1")
    return max(1, -(-total_iterations // chunks))


def lane_mesh(devices: int) -> Mesh:
    """The lane mesh of ``--devices`` (0: every device); a run over several processes uses all of them."""
    if not 0 <= devices <= jax.device_count():
        raise ValueError(f"--devices {devices} is out of range; allowed [0, {jax.device_count()}] (0: every device)")
    if jax.process_count() > 1 and devices not in (0, jax.device_count()):
        raise ValueError(
            f"--devices {devices}: a run over {jax.process_count()} processes spreads its lanes over all "
            f"{jax.device_count()} devices (--devices 0)"
        )
    return parallel.lane_mesh(devices or None)


def _none_or(text: str | None, convert: Callable[[str], Any] = str) -> Any:
    """A pre-parsed value: tyro's ``None`` spelling as None; a value ``convert`` rejects as None (tyro reports it)."""
    if text is None or text == "None":
        return None
    try:
        return convert(text)
    except ValueError:
        return None


def preparse(argv: Sequence[str], extra: Sequence[str] = ()) -> argparse.Namespace:
    """The options read ahead of the full parse, which the defaults and the processes depend on.

    ``env``, ``preset``, ``resume``, ``reward``, ``env_config``, the process options
    (:data:`PROCESS_FIELDS`) and the ``str | None`` options named in ``extra``; other flags are
    left to tyro (which also checks these).
    """
    pre = argparse.ArgumentParser(add_help=False, allow_abbrev=False)
    pre.add_argument("--env", default="arm7")
    pre.add_argument("--preset", default="auto")
    pre.add_argument("--env-config", dest="env_config", nargs="*", default=())
    for name in ("resume", "reward", *PROCESS_FIELDS, *extra):
        pre.add_argument("--" + name.replace("_", "-"), dest=name, default=None)
    known, _ = pre.parse_known_args(list(argv))
    known.env_config = tuple(known.env_config)
    for name in ("resume", "reward", "coordinator", *extra):
        setattr(known, name, _none_or(getattr(known, name)))
    for name in ("num_processes", "process_id"):
        setattr(known, name, _none_or(getattr(known, name), int))
    return known


def flag(name: str) -> str:
    """The command-line flag of an option or a config field: ``eval_episodes`` -> ``--eval-episodes``."""
    return "--" + name.replace("_", "-")


def check_options(options: Any, ranges: Mapping[str, tuple[int, int | None]] | None = None) -> None:
    """Check the counts of ``options`` (a :class:`RunOptions`, or any object with some of its attributes;
    None: not given) against ``ranges`` (default ``options.ranges``, :attr:`RunSettings.ranges`), and that
    ``--process-id`` is below ``--num-processes`` and ``--seed + --seeds - 1`` at most :data:`MAX_SEED`.

    Raises:
      ValueError: the first value out of range, naming its flag and the allowed range
        (``--eval-episodes -5 is out of range; allowed >= 1``).
    """
    ranges = type(options).ranges if ranges is None else ranges
    for name, (low, high) in ranges.items():
        value = getattr(options, name, None)
        if value is not None and (value < low or (high is not None and value > high)):
            allowed = f">= {low}" if high is None else f"[{low}, {high}]"
            raise ValueError(f"{flag(name)} {value} is out of range; allowed {allowed}")
    count, index = getattr(options, "num_processes", None), getattr(options, "process_id", None)
    if count is not None and index is not None and index >= count:
        raise ValueError(f"--process-id {index} is out of range; allowed [0, {count - 1}] (--num-processes {count})")
    seed, seeds = getattr(options, "seed", None), getattr(options, "seeds", None)
    if seed is not None and seeds is not None and seed + seeds - 1 > MAX_SEED:
        raise ValueError(f"--seed {seed} with --seeds {seeds} is out of range; allowed seed + seeds - 1 <= {MAX_SEED}")


def check_command_line(argv: Sequence[str], ranges: Mapping[str, tuple[int, int | None]]) -> None:
    """:func:`check_options` on the counts of ``ranges`` as ``argv`` gives them (``--name VALUE`` or
    ``--name=VALUE``, with ``-`` or ``_``), before anything is built; values that are no integers and
    flags without a value are left to tyro, which reports them.

    Raises:
      ValueError: as :func:`check_options`.
    """
    pre = argparse.ArgumentParser(add_help=False, allow_abbrev=False, exit_on_error=False)
    for name in ranges:
        pre.add_argument(*dict.fromkeys((flag(name), "--" + name)), dest=name, default=None)
    try:
        known, _ = pre.parse_known_args(list(argv))
    except argparse.ArgumentError:
        return
    check_options(argparse.Namespace(**{k: _none_or(v, int) for k, v in vars(known).items()}), ranges)


def _tuples(x: Any) -> Any:
    """JSON lists back to tuples (the configs' sequence fields are tuples), recursively."""
    if isinstance(x, dict):
        return {k: _tuples(v) for k, v in x.items()}
    if isinstance(x, list | tuple):
        return tuple(_tuples(v) for v in x)
    return x


@dataclasses.dataclass(frozen=True)
class AlgorithmCLI:
    """The command line ``python -m train.<name>`` of one algorithm: what the algorithm declares.

    :meth:`parse`, :meth:`build` and :meth:`main` (= :func:`cli_main`) do the rest the same way for
    every algorithm.

    Attributes:
      name: the algorithm (``"ppo"``): run-directory prefix, the ``config.json`` section of its
        hyper-parameters and the field of ``args_type`` that holds them.
      args_type: a :class:`RunOptions` subclass adding the field ``name`` (``config_type``,
        ``Annotated[..., tyro.conf.OmitArgPrefixes]``, with a default) and any options of its own.
      config_type: the hyper-parameter dataclass (with ``replace``, ``validate`` and ``episode_length``).
      preset: ``(args, env) -> config``: the defaults of the (resolved) ``args.preset`` for ``env``,
        the env as the run builds it from ``args``.
      make_trainer: ``(args, env, config, mesh) -> (trainer, iterations per chunk)``; ``config`` is
        validated, its ``episode_length`` set; ``mesh`` is :func:`lane_mesh` of ``--devices``, over
        which the trainer spreads its lanes.
      env_settings: ``args -> env overrides`` for :func:`make_env` (default :func:`env_overrides`).
      env_fields: options of ``args_type`` beyond ``RunOptions`` that ``env_settings`` reads.
      preset_fields: ``str`` choice fields of ``config_type`` that select a variant of the preset
        (e.g. PPO's ``policy``): read ahead and set in the config of the ``args`` the preset gets.
      after: called on process 0 with :func:`run`'s result (e.g. extra figures).
    """

    name: str
    args_type: type
    config_type: type
    preset: Callable[[Any, Env], Any]
    make_trainer: Callable[[Any, Env, Any, Mesh], tuple[Trainer, int]]
    env_settings: Callable[[Any], dict[str, Any]] = env_overrides
    env_fields: tuple[str, ...] = ()
    preset_fields: tuple[str, ...] = ()
    after: Callable[[dict[str, Any]], Any] | None = None

    def args(self, config: Any = None, **options: Any) -> Any:
        """An ``args_type`` with ``config`` (default: ``config_type()``) and ``options``."""
        return self.args_type(**{self.name: self.config_type() if config is None else config}, **options)

    def parse(self, argv: Sequence[str] | None = None) -> Any:
        """Parse the command line: the preset's defaults for ``--env`` (and its env settings) first,
        then every flag; with ``--resume DIR`` the arguments saved in that run (:meth:`args_from_saved`)."""
        argv = cache_flags(sys.argv[1:] if argv is None else argv)
        if not _asks_for_help(argv):
            check_command_line(argv, self.args_type.ranges)  # before the preset's env is built
        known = preparse(argv, (*self.env_fields, *self.preset_fields))
        if known.resume:
            preset, config = known.preset, self.config_type()
        else:
            preset = resolve_preset(known.preset, known.env, self.name)
            if known.preset == "auto" and preset == "playground" and not _asks_for_help(argv):
                fn = "brax_ppo_config" if self.name == "ppo" else "brax_sac_config"
                print(f"preset: playground (MuJoCo Playground's {fn} for {known.env}; train/presets.py "
                      f"playground_{'ppo' if self.name == 'ppo' else 'sac_ddpg'}_config)", file=sys.stderr)
            if known.preset == "auto" and preset == "brax" and not any(a in ("-h", "--help") for a in argv):
                if self.name == "ppo":
                    source = ("brax's published PPO settings", "BRAX_PPO")
                    if brax_task(known.env) in BRAX_PPO_TUNED:
                        source = (f"{source[0]} with our tuned fields over them", f"{source[1]}, BRAX_PPO_TUNED")
                else:
                    source = ("brax's SAC lanes and memory with TD3's own update settings", "BRAX_SAC, TD3_OWN")
                    if brax_sac_task(known.env) in BRAX_SAC_TUNED:
                        source = (f"{source[0]} and our tuned entries over them", f"{source[1]}, BRAX_SAC_TUNED")
                print(f"preset: brax ({source[0]} for {known.env}; train/presets.py {source[1]})", file=sys.stderr)
            fields = ("env", "reward", "env_config", *self.env_fields)
            variant = {k: getattr(known, k) for k in self.preset_fields if getattr(known, k) is not None}
            ahead = self.args(self.config_type(**variant), preset=preset, **{k: getattr(known, k) for k in fields})
            config = self.preset(ahead, make_env(known.env, self.env_settings(ahead)))
        default = self.args(config, env=known.env, preset=preset)
        args = tyro.cli(self.args_type, args=argv, default=default, prog=f"python -m train.{self.name}")
        args = dataclasses.replace(args, preset=resolve_preset(args.preset, args.env, self.name))
        return self.check(self.args_from_saved(args.resume, args) if args.resume else args)

    def check(self, args: Any) -> Any:
        """``args``, once its counts (:func:`check_options`) and its hyper-parameters (:meth:`validate`)
        are found in range.

        Raises:
          ValueError: as :func:`check_options`, or ``ConfigError`` as :meth:`validate`; for a resumed run
            the message begins ``--resume DIR: config.json:``.
        """
        try:
            check_options(args)
        except ValueError as e:
            raise ValueError(f"--resume {args.resume}: config.json: {e}" if args.resume else str(e)) from None
        self.validate(args)
        return args

    def validate(self, args: Any, config: Any = None) -> None:
        """``config.validate()`` (default: ``args``'s config), before the env is built.

        Raises:
          ConfigError: the first invalid field, its flag in front (``--clip-eps: clip_eps=2.0 is out of
            range; allowed (0, 1)``); for a resumed run ``--resume DIR: config.json: clip_eps=2.0 …``.
        """
        from envs_mjx.config import ConfigError

        config = getattr(args, self.name) if config is None else config
        try:
            config.validate()
        except ConfigError as e:
            if args.resume:
                raise ConfigError(f"--resume {args.resume}: config.json: {e}") from None
            name = re.match(r"[a-z_][a-z0-9_]*", str(e))
            fields = {f.name for f in dataclasses.fields(config)}
            raise ConfigError(f"{flag(name[0])}: {e}" if name and name[0] in fields else str(e)) from None

    def args_from_saved(self, run_dir: str, current: Any) -> Any:
        """The arguments saved in ``run_dir/config.json``, resuming that run; the options of
        :data:`COMMAND_LINE_FIELDS` come from ``current`` (this command line)."""
        saved = load_config(run_dir)
        if saved.get("algo", self.name) != self.name or self.name not in saved:
            raise ValueError(f"--resume {run_dir!r}: a {saved.get('algo')!r} run, not {self.name!r}")
        options = dict(_tuples(saved.get("args", {})))
        options.update({k: getattr(current, k) for k in COMMAND_LINE_FIELDS}, resume=run_dir)
        unknown = set(options) - {f.name for f in dataclasses.fields(self.args_type)} - {self.name}
        if unknown:
            raise ValueError(f"--resume {run_dir!r}: config.json has unknown options {', '.join(sorted(unknown))}")
        return self.args(self.config_type(**_tuples(saved[self.name])), **options)

    def build(self, args: Any) -> tuple[Env, Trainer, dict[str, Any]]:
        """``(env, trainer, config dict)`` for ``args`` (a fresh run or a resumed one), checked (:meth:`check`)
        before the env is built."""
        cfg = getattr(self.check(args), self.name)
        mesh = lane_mesh(args.devices)
        if resolve_seed_map(args.seed_map) == "vmap" and args.seeds > 1 and mesh.devices.size > 1:
            raise ValueError(f"--seeds {args.seeds} vmapped runs on one device; add --devices 1 (the lanes would "
                             f"be spread over {mesh.devices.size}) or --seed-map loop")  # fmt: skip
        overrides = self.env_settings(args)
        check_backend_devices(overrides, mesh.devices.size)
        env = make_env(args.env, overrides)
        if not cfg.episode_length:
            cfg = cfg.replace(episode_length=episode_length(env))
            self.validate(args, cfg)
        trainer, per_chunk = self.make_trainer(args, env, cfg, mesh)
        options = dataclasses.asdict(args)
        config = {
            "algo": self.name,
            "args": {
                k: v for k, v in options.items() if k != self.name and k not in (*PROCESS_FIELDS, *MACHINE_FIELDS)
            },
            self.name: dataclasses.asdict(cfg),
            "iterations_per_chunk": per_chunk,
            "devices": mesh.shape[parallel.LANES],
            "processes": jax.process_count(),
            "env": env_record(args.env, env),
        }
        return env, trainer, config

    def main(self, argv: Sequence[str] | None = None) -> int:
        """Entry point of ``python -m train.<name>``; the exit code (:func:`cli_main`)."""
        return cli_main(self, argv)


RUN_ONLY_FIELDS = ("seed", "out", "resume", "checkpoint_every", "stop_after_steps", "progress", "evals")
"""Options of ``config.json``'s ``args`` that never change a compiled program (the seed enters as an argument)."""


def program_context(config: dict[str, Any]) -> dict[str, Any]:
    """What of a run's ``config`` keys its :class:`~jaxrl_robot.compilation.ProgramCache`: all of it but
    :data:`RUN_ONLY_FIELDS`, so that runs with other seeds or folders share programs."""
    args = {k: v for k, v in config.get("args", {}).items() if k not in RUN_ONLY_FIELDS}
    return _jsonable({**config, "args": args})


def exit_process(code: int) -> None:
    """End a ``python -m train.<algo>`` process with ``code`` once its output is flushed. A run of one process
    leaves at once (``os._exit``): its files are closed by then, and the interpreter's teardown of XLA's
    clients and compiled programs would add seconds (4–5 s on a CPU) to every command. A process of a run
    over several exits normally, through ``jax.distributed``'s shutdown."""
    import logging

    sys.stdout.flush()
    sys.stderr.flush()
    if jax.process_count() == 1:
        logging.shutdown()
        os._exit(code)
    sys.exit(code)


def cache_flags(argv: Sequence[str]) -> list[str]:
    """``argv`` with ``--no-compile-cache`` spelled ``--compile-cache off`` (the field tyro parses)."""
    return [x for a in argv for x in (("--compile-cache", "off") if a == "--no-compile-cache" else (a,))]


def _asks_for_help(argv: Sequence[str]) -> bool:
    return "-h" in argv or "--help" in argv


def cli_main(cli: AlgorithmCLI, argv: Sequence[str] | None = None) -> int:
    """The body of every ``python -m train.<algo>``: join the processes, parse, build, :func:`run`.

    The process options (``--coordinator``, ``--num-processes``, ``--process-id``, or the
    launcher's environment) go to ``parallel.initialize_multihost`` before any JAX computation.

    Returns:
      0 on a finished run (or one stopped on purpose), 1 after a non-finite loss, an unfinished run
      or a checkpoint that could not be written (disk full; the earlier ones are kept), 2 on bad input
      (the message names the field and the valid values; the options' counts are checked before any env
      is built, the config before the run's env and before anything is compiled), a run directory another
      process writes, or a ``--resume`` with no usable checkpoint or a ``config.json`` that no longer fits
      the checkpoint, 128 + the signal's number after SIGINT / SIGTERM stopped it (checkpointed;
      ``--resume`` continues).
      In a run over several processes whose peer stopped responding, the process ends at once with 1
      after one line on stderr (:func:`jaxrl_robot.parallel.exit_at_once`: a normal exit would wait
      for the lost peer in ``jax.distributed.shutdown`` and then abort).
    """
    from envs_mjx.config import ConfigError

    argv = cache_flags(sys.argv[1:] if argv is None else argv)
    cache_dir = None
    log = compile_log()
    mark = log.mark()
    try:
        if not _asks_for_help(argv):
            check_command_line(argv, cli.args_type.ranges)
            known = preparse(argv, ("compile_cache",))
            cache_dir = enable_persistent_cache(resolve_cache_dir(known.compile_cache))
            parallel.initialize_multihost(known.coordinator, known.num_processes, known.process_id)
        args = cli.parse(argv)
        env, trainer, config = cli.build(args)
        programs = None if _asks_for_help(argv) else ProgramCache.under(cache_dir, program_context(config))
    except (ConfigError, ValueError, FileNotFoundError) as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    spec = RunSpec(
        algo=cli.name,
        env_name=args.env,
        env=env,
        trainer=trainer,
        config=config,
        run_dir=args.resume,
        episode_length=int(config[cli.name]["episode_length"]),
        compile_mark=mark,
        program_cache=programs,
        **settings_of(args),
    )
    try:
        result = run(spec)
    except RunDirError as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    except (NonFiniteLossError, CheckpointWriteError) as e:
        print(f"error: {e}", file=sys.stderr)
        return 1
    except CheckpointError as e:  # the run directory is in use, or no checkpoint of it can be resumed
        print(f"error: {e}", file=sys.stderr)
        return 2
    except PeerLostError as e:
        parallel.exit_at_once(1, f"error: {e}")
    except Exception as e:
        lost = parallel.lost_peer(e)  # before the run directory was chosen
        if lost is None:
            raise
        parallel.exit_at_once(1, f"error: {lost} as the run began; start it again")
    if cli.after is not None and is_main_process():
        for one in result.get("seeds", [result]):
            cli.after({**result, **one})
    if result.get("interrupted"):
        return 128 + result["interrupted"]  # the shell's code for a run ended by that signal
    return 0 if result.get("finished") or args.stop_after_steps else 1
