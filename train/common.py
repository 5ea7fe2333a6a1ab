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

The CLI then calls :func:`run` with a :class:`RunSpec`. :func:`run`:

1. makes ``runs/<algo>-<env>-<time>/`` and writes ``config.json`` (the CLI's full config,
   enough to rebuild the run — ``--resume DIR`` reloads it with :func:`load_config`);
2. initialises or restores the state (orbax, ``checkpoints/<chunk>/``) — a restored run
   continues exactly where the checkpoint left it;
3. calls the jitted ``update`` chunk after chunk, writing ``metrics.csv`` and TensorBoard
   events (``tb/``), drawing a progress bar (only on a terminal, not under CI), saving a
   checkpoint every ``checkpoint_every`` chunks and at the end;
4. stops with :class:`NonFiniteLossError` (naming the metric and env step) when a loss turns
   NaN/inf, after saving the last good state as a checkpoint;
5. evaluates the final policy — reaching envs: success over ``eval_episodes`` test episodes
   from fresh random starts and goals (a key stream apart from training) and the mean extra
   distance; tracking envs: the test episode from ``t = 0`` and the per-axis error sums —
   prints a table, writes ``eval.json`` and draws the figures (``*.png``). The test-episode
   program is compiled in a background thread while training runs, so evaluation at the end
   costs only its run time.
"""

from __future__ import annotations

import dataclasses
import json
import math
import os
import sys
import time
from collections.abc import Callable
from concurrent.futures import Future, ThreadPoolExecutor
from typing import Any

import jax
import numpy as np
from brax.envs.base import Env

from jaxrl_robot.checkpoint import Checkpointer
from jaxrl_robot.evaluation import run_test_episodes, summarize_episodes, tracking_error_sums
from jaxrl_robot.logging import MetricsLogger, read_csv
from jaxrl_robot.plots import plot_tracking, plot_training_curves
from jaxrl_robot.types import Trainer

__all__ = [
    "NonFiniteLossError",
    "RunSpec",
    "evaluate",
    "is_tracking_env",
    "load_config",
    "make_run_dir",
    "run",
    "use_progress_bar",
]

EVAL_KEY_OFFSET = 1_000_003
"""Folded into the seed's key for test episodes, so their starts and goals are not training's."""


class NonFiniteLossError(RuntimeError):
    """A loss became NaN or inf; the message names the metric, the env step and the last good checkpoint."""


@dataclasses.dataclass
class RunSpec:
    """What an algorithm's CLI hands to :func:`run`.

    Attributes:
      algo: algorithm name for the run directory (``"ppo"``).
      env_name: environment name for the run directory and reports.
      env: the unbatched environment (used for evaluation).
      trainer: the algorithm's :class:`~jaxrl_robot.types.Trainer`.
      config: JSON-able dict that rebuilds the run (saved as ``config.json``).
      seed: training seed; ``PRNGKey(seed)`` goes to ``trainer.init``.
      out: parent folder of new run directories.
      run_dir: an existing run directory to resume (``None``: start a new run).
      checkpoint_every: chunks between checkpoints (the last chunk is always saved).
      eval_episodes: test episodes for reaching envs.
      episode_length: step limit of a test episode (0: ``env.episode_length``).
      stop_after_steps: stop (resumably) once this many env steps are done; 0 runs to the end.
      progress: draw a progress bar; ``None`` decides by :func:`use_progress_bar`.
    """

    algo: str
    env_name: str
    env: Env
    trainer: Trainer
    config: dict[str, Any]
    seed: int = 0
    out: str = "runs"
    run_dir: str | None = None
    checkpoint_every: int = 10
    eval_episodes: int = 100
    episode_length: int = 0
    stop_after_steps: int = 0
    progress: bool | None = None


def use_progress_bar() -> bool:
    """A bar only on an interactive terminal and not under CI."""
    return sys.stdout.isatty() and not os.environ.get("CI")


def make_run_dir(out: str, algo: str, env_name: str) -> str:
    """Create ``out/<algo>-<env>-<YYYYmmdd-HHMMSS>`` (a numeric suffix if it exists)."""
    stamp = time.strftime("%Y%m%d-%H%M%S")
    base = os.path.join(out, f"{algo}-{env_name.replace(':', '_')}-{stamp}")
    path, i = base, 1
    while os.path.exists(path):
        path, i = f"{base}-{i}", i + 1
    os.makedirs(path)
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
) -> dict[str, Any]:
    """Evaluate a deterministic policy; draws the tracking figures into ``run_dir`` if given.

    Tracking envs: ``envs_mjx.tracking.test_episode`` from ``t = 0`` → per-axis sums of
    |error| (plus means per step and the step count). Other envs: ``episodes`` test episodes
    → success rate, mean extra distance, mean return (whichever metrics the env has);
    ``episodes_fn(key)``, if given, is an already compiled ``run_test_episodes`` of ``policy``.
    """
    if is_tracking_env(env):
        from envs_mjx import tracking

        result = tracking.test_episode(env, policy)
        axes = tuple(result["axis_names"])
        summary = tracking_error_sums(result["abs_error"][: result["steps"]], axes)
        summary["episode_return"] = result["episode_return"]
        if run_dir is not None:
            real = result["real_path"]
            ref = result["ref_path"]
            ok = np.isfinite(real[:, 0])
            plot_tracking(ref[ok], real[ok], result["abs_error"][: result["steps"]], run_dir, axes)
        return {"kind": "tracking", **summary}
    if episodes_fn is None:
        episodes_fn = jax.jit(lambda k: run_test_episodes(k, env, policy, episodes, episode_length or None))
    summary = summarize_episodes(jax.device_get(episodes_fn(key)))
    return {"kind": "episodes", **summary}


def compile_evaluation_async(
    spec: RunSpec, key: jax.Array, state: Any
) -> Future[Callable[[jax.Array, Any], Any]] | None:
    """Compile ``(key, state) -> run_test_episodes(...)`` of ``spec.trainer.policy(state)`` in a thread.

    Returns a future of the compiled function, or None for tracking envs (their test episode
    is compiled when it runs). The thread overlaps XLA compilation with training.
    """
    if is_tracking_env(spec.env):
        return None
    policy_of, env, n, limit = spec.trainer.policy, spec.env, spec.eval_episodes, spec.episode_length or None
    fn = jax.jit(lambda k, s: run_test_episodes(k, env, policy_of(s), n, limit))
    executor = ThreadPoolExecutor(max_workers=1, thread_name_prefix="compile-eval")
    future = executor.submit(lambda: fn.lower(key, state).compile())
    executor.shutdown(wait=False)
    return future


def _compiled_episodes(future: Future | None, state: Any) -> Callable[[jax.Array], Any] | None:
    """The background-compiled evaluation bound to ``state``; None if it failed (then compiled in line)."""
    if future is None:
        return None
    try:
        compiled = future.result()
    except Exception as e:  # compilation is retried in line by ``evaluate``
        print(f"background compilation of the evaluation failed ({type(e).__name__}: {e}); compiling now", flush=True)
        return None
    return lambda k: compiled(k, state)


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


def run(spec: RunSpec) -> dict[str, Any]:
    """Train, log, checkpoint and evaluate as the module docstring describes.

    Returns:
      ``{"run_dir", "finished", "env_steps", "wall_s", "compile_s", "eval"}`` (``eval`` only
      when the run finished).
    Raises:
      NonFiniteLossError: a loss became NaN/inf (the last good state is checkpointed first).
    """
    trainer = spec.trainer
    resuming = spec.run_dir is not None
    run_dir = spec.run_dir if resuming else make_run_dir(spec.out, spec.algo, spec.env_name)
    if not resuming:
        _write_json(os.path.join(run_dir, "config.json"), spec.config)
    print(f"run directory: {run_dir}", flush=True)

    t0 = time.perf_counter()
    state = jax.jit(trainer.init)(jax.random.PRNGKey(spec.seed))
    ckpt = Checkpointer(os.path.join(run_dir, "checkpoints"))
    chunk, wall_before = 0, 0.0
    if resuming:
        step = ckpt.latest_step()
        if step is None:
            raise FileNotFoundError(f"--resume {run_dir!r}: no checkpoint to resume from")
        state, record = ckpt.restore(step, state)
        chunk, wall_before = int(record["chunk"]), float(record.get("wall_s", 0.0))
        print(f"resumed at chunk {chunk} ({chunk * trainer.env_steps_per_update} env steps)", flush=True)
    steps_per = trainer.env_steps_per_update
    logger = MetricsLogger(run_dir, keep_until_step=chunk * steps_per if resuming else None)
    update = jax.jit(trainer.update)
    total_steps = trainer.num_updates * steps_per
    stop_chunk = trainer.num_updates
    if spec.stop_after_steps > 0:
        stop_chunk = min(stop_chunk, max(chunk + 1, math.ceil(spec.stop_after_steps / steps_per)))
    show = use_progress_bar() if spec.progress is None else spec.progress
    bar = _Progress(show, total_steps, chunk * steps_per)
    eval_key = jax.random.fold_in(jax.random.PRNGKey(spec.seed), EVAL_KEY_OFFSET)
    will_evaluate = stop_chunk >= trainer.num_updates and chunk < stop_chunk
    eval_future = compile_evaluation_async(spec, eval_key, state) if will_evaluate else None

    def record(c: int, wall: float) -> dict[str, Any]:
        return {"chunk": c, "env_steps": c * steps_per, "wall_s": wall}

    compile_s, last_saved = None, chunk if resuming else -1
    t_loop = time.perf_counter()
    try:
        while chunk < stop_chunk:
            t_chunk = time.perf_counter()
            new_state, metrics = update(state)
            metrics = {k: float(v) for k, v in jax.device_get(metrics).items()}
            dt = time.perf_counter() - t_chunk
            if compile_s is None:
                compile_s = dt
            bad = [k for k, v in metrics.items() if "loss" in k and not math.isfinite(v)]
            if bad:
                if last_saved != chunk:
                    ckpt.save(chunk, state, record(chunk, wall_before + time.perf_counter() - t0))
                raise NonFiniteLossError(
                    f"{bad[0]} is {metrics[bad[0]]} after env step {(chunk + 1) * steps_per} "
                    f"(chunk {chunk + 1}); last good checkpoint: {ckpt.directory}/{chunk} "
                    f"at env step {chunk * steps_per}"
                )
            state, chunk = new_state, chunk + 1
            sps = steps_per / max(dt, 1e-9)
            logger.write(chunk * steps_per, {**metrics, "steps_per_s": sps})
            bar.update(chunk * steps_per, _progress_info(metrics, sps))
            if chunk % max(spec.checkpoint_every, 1) == 0 or chunk == stop_chunk:
                ckpt.save(chunk, state, record(chunk, wall_before + time.perf_counter() - t0))
                last_saved = chunk
    finally:
        bar.close()
        logger.close()
    jax.block_until_ready(state)
    train_s = time.perf_counter() - t_loop
    result: dict[str, Any] = {
        "run_dir": run_dir,
        "finished": chunk >= trainer.num_updates,
        "env_steps": chunk * steps_per,
        "compile_s": compile_s,
        "train_s": train_s,
    }
    rows = read_csv(logger.path)
    plot_training_curves(rows, run_dir)
    if not result["finished"]:
        result["wall_s"] = wall_before + time.perf_counter() - t0
        print(f"stopped at {result['env_steps']} env steps; continue with --resume {run_dir}", flush=True)
        ckpt.close()
        return result
    t_eval = time.perf_counter()
    summary = evaluate(
        eval_key,
        spec.env,
        trainer.policy(state),
        spec.eval_episodes,
        run_dir,
        spec.episode_length,
        episodes_fn=_compiled_episodes(eval_future, state),
    )
    result["eval_s"] = time.perf_counter() - t_eval
    result["wall_s"] = wall_before + time.perf_counter() - t0
    result["eval"] = summary
    _write_json(os.path.join(run_dir, "eval.json"), {**summary, **{k: v for k, v in result.items() if k != "eval"}})
    title = f"{spec.algo} on {spec.env_name}: evaluation"
    _print_table(title, {**summary, "env_steps": result["env_steps"], "wall_s": round(result["wall_s"], 1)})
    ckpt.close()
    return result


def cli_main(
    algo: str,
    parse: Callable[[], Any],
    build: Callable[[Any], tuple[Env, Trainer, dict[str, Any]]],
    after: Callable[[dict[str, Any]], Any] | None = None,
) -> int:
    """The body of every ``python -m train.<algo>``: parse, build, :func:`run`; the exit code.

    Args:
      algo: the algorithm's name (run-directory prefix and the config section holding
        ``episode_length``).
      parse: returns the parsed arguments (fields ``env``, ``seed``, ``out``, ``resume``,
        ``checkpoint_every``, ``eval_episodes``, ``stop_after_steps``, ``progress``).
      build: ``args -> (env, trainer, config)``.
      after: optional hook called with :func:`run`'s result (e.g. extra figures).
    Returns:
      0 on a finished run (or one stopped on purpose), 1 after a non-finite loss or an
      unfinished run, 2 on bad input (the message names the field and the valid values).
    """
    from envs_mjx.config import ConfigError

    try:
        args = parse()
        env, trainer, config = build(args)
    except (ConfigError, ValueError, FileNotFoundError) as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    spec = RunSpec(
        algo=algo,
        env_name=args.env,
        env=env,
        trainer=trainer,
        config=config,
        seed=args.seed,
        out=args.out,
        run_dir=args.resume,
        checkpoint_every=args.checkpoint_every,
        eval_episodes=args.eval_episodes,
        episode_length=int(config[algo]["episode_length"]),
        stop_after_steps=args.stop_after_steps,
        progress=args.progress,
    )
    try:
        result = run(spec)
    except NonFiniteLossError as e:
        print(f"error: {e}", file=sys.stderr)
        return 1
    if after is not None:
        after(result)
    return 0 if result.get("finished") or args.stop_after_steps else 1
