"""The run loop of every ``python -m train.<algo>``: :func:`run` of a :class:`~train.options.RunSpec`.

An algorithm supplies a :class:`jaxrl_robot.types.Trainer` — pure functions that this module jits and drives:

* ``init(key) -> state``: the whole train state, a pytree of arrays (params, optimiser
  states, normalisers, replay, env states, RNG key, counters);
* ``update(state) -> (state, metrics)``: one *chunk* of training iterations under
  ``lax.scan``; ``metrics`` is a dict of scalars. Keys containing ``"loss"`` are checked for
  NaN/inf. Episode statistics (``episode_return``, ``success``, ``extra_distance``, any env
  metric) are means over the episodes that finished in the chunk, NaN if none did;
* ``policy(state) -> obs -> action``: the deterministic action for evaluation;
* ``num_updates`` chunks make the run; ``env_steps_per_update`` env steps each.

:func:`run`:

1. makes ``runs/<algo>-<env>-<time>/`` and writes ``config.json`` (the CLI's full config,
   enough to rebuild the run — ``--resume DIR`` reloads it with :func:`train.rundir.load_config`);
2. initialises or restores the state (orbax, ``checkpoints/<chunk>/``) — a restored run
   continues exactly where the checkpoint left it; each checkpoint's files are checked against
   the SHA-256 sums saved with it, a damaged newest one is skipped for the newest good one, and a
   ``config.json`` that no longer builds the saved state is an error naming the arrays that differ.
   The run directory is locked (``.lock``) while a process writes it: a second one stops at once;
3. calls the jitted ``update`` chunk after chunk (:class:`~train.seeds.SeedProgram`: one seed or
   several), writing ``metrics.csv`` and TensorBoard events (``tb/``), drawing a progress bar (only on a
   terminal, not under CI), saving a checkpoint every ``checkpoint_every`` chunks and at the end; SIGINT
   (Ctrl-C) or SIGTERM stops it after the current chunk with a checkpoint (a second Ctrl-C at once), and
   ``--resume`` continues;
4. stops with :class:`NonFiniteLossError` (naming the metric and env step) when a loss turns
   NaN/inf, after saving the last good state as a checkpoint;
5. evaluates the final policy as the env asks (:mod:`jaxrl_robot.evaluation`) — reaching envs: success
   over ``eval_episodes`` test episodes from fresh random starts and goals (a key stream apart from
   training) and the mean extra distance; tracking envs: the test episode from ``t = 0`` and the per-axis
   error sums; racecar: laps on every road — prints a table, writes ``eval.json`` and draws the figures
   (``*.png``). The test-episode program is compiled in a background thread while training runs, so
   evaluation at the end costs only its run time (:mod:`train.evaluations`). ``--evals N`` also evaluates
   during training, after N chunks spread evenly over the run (the last one the final evaluation), with
   the same program, one row each in ``evals.csv``; their time is kept off the training clock
   (``train_s``) and counted in ``eval.json``'s ``periodic_eval_s`` (:mod:`train.periodic`).

With several processes (:mod:`train.hosts`) process 0 alone chooses the run directory (its name is
broadcast to the others), writes ``config.json``, ``metrics.csv``, TensorBoard events, the figures and
``eval.json``, and prints. Checkpoints are orbax's multi-process checkpoints: every process writes its
own shards of the state into the same ``checkpoints/<chunk>/`` (so the run directory must be on a
filesystem every host sees) and every process restores its shards on ``--resume``. The final policy is
evaluated by every process on its own devices from its copy of the replicated parameters (identical
results).
"""

from __future__ import annotations

import contextlib
import dataclasses
import math
import os
import signal
import time
from typing import Any

import jax

from jaxrl_robot import parallel
from jaxrl_robot.checkpoint import Checkpointer
from jaxrl_robot.compilation import compile_log
from jaxrl_robot.evaluation import evaluation_key
from jaxrl_robot.logging import MetricsLogger, read_csv
from jaxrl_robot.plots import import_in_background, plot_training_curves
from train import periodic
from train.evaluations import RunEvaluations, compile_evaluation_async, evaluation_title, print_table
from train.hosts import is_main_process, local_view, say, to_host
from train.options import RunSpec, check_options
from train.progress import (
    STOP_SIGNALS,
    NonFiniteLossError,
    PeerLostError,
    Progress,
    process_age_s,
    progress_info,
    stop_on_signals,
    use_progress_bar,
)
from train.rundir import jsonable, lock_run_dir, make_run_dir, restore_run, write_json
from train.seeds import SeedProgram

__all__ = [
    "STOP_SIGNALS",
    "NonFiniteLossError",
    "PeerLostError",
    "RunSpec",
    "process_age_s",
    "run",
    "stop_on_signals",
    "use_progress_bar",
]


def run(spec: RunSpec) -> dict[str, Any]:
    """Train, log, checkpoint and evaluate as the module docstring describes, holding the run
    directory's lock (:func:`train.rundir.lock_run_dir`) throughout.

    Returns:
      ``{"run_dir", "finished", "env_steps", "wall_s", "compile_s", "eval"}`` (``eval`` only
      when the run finished).
    Raises:
      NonFiniteLossError: a loss became NaN/inf (the last good state is checkpointed first).
      DirectoryInUseError: another process writes the run directory.
      CheckpointMismatchError, CheckpointDamagedError: ``--resume`` found no checkpoint it can use
        (:func:`train.rundir.restore_run`).
      CheckpointWriteError: a checkpoint could not be written (disk full); earlier ones are kept.
      PeerLostError: another process of a run over several stopped responding.
      ValueError: a count of ``spec`` is out of range (:func:`train.options.check_options`).
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


@dataclasses.dataclass
class _Run:
    """A run in progress: what :func:`run` holds from its start to its report.

    ``chunk``: chunks done; ``stop_chunk``: the chunk it stops after; ``due``: the chunks evaluated during
    training (``--evals``); the clocks (``time.perf_counter`` seconds): ``t0`` the run's start in this process,
    ``t_loop`` the first chunk's start, ``eval_spent`` the evaluations during training so far, ``wall_before`` /
    ``train_before`` the wall and training seconds of the processes before a resume; ``last_saved``: the
    newest checkpoint's chunk (-1: none yet).
    """

    spec: RunSpec
    run_dir: str
    seeds: list[int]
    seed_dirs: list[str]
    program: SeedProgram
    ckpt: Checkpointer
    state: Any
    t0: float
    startup_s: float | None
    chunk: int = 0
    wall_before: float = 0.0
    train_before: float = 0.0
    loggers: list[MetricsLogger] = dataclasses.field(default_factory=list)
    eval_logs: list[periodic.EvalLog] = dataclasses.field(default_factory=list)
    eval_keys: list[jax.Array] = dataclasses.field(default_factory=list)
    evaluations: RunEvaluations | None = None
    due: tuple[int, ...] = ()
    stop_chunk: int = 0
    compile_s: float | None = None
    last_saved: int = -1
    t_loop: float = 0.0
    eval_spent: float = 0.0

    @property
    def steps_per(self) -> int:
        """Env steps of one chunk."""
        return self.spec.trainer.env_steps_per_update

    @property
    def resuming(self) -> bool:
        return self.spec.run_dir is not None

    def train_clock(self, t: float) -> float:
        """The training clock at ``time.perf_counter()`` ``t``: training's seconds, evaluations apart."""
        return self.train_before + t - self.t_loop - self.eval_spent

    def since_start(self, t: float) -> float | None:
        """Seconds from this process's start to ``time.perf_counter()`` ``t``, evaluations during training apart."""
        return None if self.startup_s is None else self.startup_s + t - self.t0 - self.eval_spent

    def save(self) -> None:
        """A checkpoint of the state after ``chunk``, its record with the clocks and the config."""
        c, wall = self.chunk, self.wall_before + time.perf_counter() - self.t0
        record = {"chunk": c, "env_steps": c * self.steps_per, "wall_s": wall,
                  "train_wall_s": self.train_clock(time.perf_counter()),
                  "config": jsonable(self.spec.config)}  # fmt: skip
        self.ckpt.save(c, self.state, record)
        self.last_saved = c


def _run_locked(spec: RunSpec, run_dir: str) -> dict[str, Any]:
    """:func:`run` in ``run_dir`` (made or given), whose lock this process holds."""
    r = _start(spec, run_dir)
    _open_logs(r)
    bar = _plan(r)
    signum = _train(r, bar)
    return _finish(r, signum)


def _start(spec: RunSpec, run_dir: str) -> _Run:
    """``config.json`` written (a new run), the initial state of every seed, restored from the newest good
    checkpoint on ``--resume``."""
    if spec.run_dir is None and is_main_process():
        write_json(os.path.join(run_dir, "config.json"), spec.config)
    say(f"run directory: {run_dir}")
    t0, startup_s = time.perf_counter(), process_age_s()
    seeds = [spec.seed + i for i in range(spec.seeds)]
    program = SeedProgram.of(spec.trainer, len(seeds), spec.seed_map, spec.program_cache)
    if spec.run_dir is None:  # a new run (a resumed one's chunk is compiled for the restored state)
        program.compile_ahead(seeds)
    state = program.init(seeds)
    seed_dirs = [os.path.join(run_dir, f"seed{k}") for k in seeds] if len(seeds) > 1 else [run_dir]
    ckpt = Checkpointer(os.path.join(run_dir, "checkpoints"))
    r = _Run(spec, run_dir, seeds, seed_dirs, program, ckpt, state, t0, startup_s)
    if r.resuming:
        restored = restore_run(ckpt, state, run_dir, spec.config)
        if restored is None:  # stopped before its first checkpoint: the saved config, from the start
            say(f"--resume {run_dir}: no checkpoint yet; starting this run from the beginning with its saved config")
        else:
            r.state, record = restored.state, restored.record
            r.chunk, r.wall_before = int(record["chunk"]), float(record.get("wall_s", 0.0))
            r.train_before = float(record.get("train_wall_s", r.wall_before))
            say(f"resumed at chunk {r.chunk} ({r.chunk * r.steps_per} env steps)")
    return r


def _open_logs(r: _Run) -> None:
    """Process 0: each seed's folder, its ``config.json`` (one seed of several, as the run of ``--seed k``) and
    its metrics logger (a resumed run's rows after its checkpoint dropped)."""
    if not is_main_process():
        return
    several = len(r.seeds) > 1
    for k, d in zip(r.seeds, r.seed_dirs, strict=True):
        os.makedirs(d, exist_ok=True)
        if several and not r.resuming:  # the config of this seed's run alone (--seed k)
            args = {**r.spec.config.get("args", {}), "seed": k, "seeds": 1}
            write_json(os.path.join(d, "config.json"), {**r.spec.config, "args": args})
        r.loggers.append(MetricsLogger(d, keep_until_step=r.chunk * r.steps_per if r.resuming else None))


def _plan(r: _Run) -> Progress:
    """Where the run stops, its evaluations (the final one's program compiled in the background when one is
    due before the stop, ``evals.csv``) and its progress bar."""
    spec, updates = r.spec, r.spec.trainer.num_updates
    r.stop_chunk = updates
    if spec.stop_after_steps > 0:
        r.stop_chunk = min(r.stop_chunk, max(r.chunk + 1, math.ceil(spec.stop_after_steps / r.steps_per)))
    show = is_main_process() and (use_progress_bar() if spec.progress is None else spec.progress)
    bar = Progress(show, updates * r.steps_per, r.chunk * r.steps_per)
    r.eval_keys = [evaluation_key(k) for k in r.seeds]
    r.due = periodic.eval_chunks(spec.evals, updates)  # --evals: the chunks evaluated during training
    will_evaluate = r.stop_chunk >= updates and r.chunk < r.stop_chunk
    will_evaluate = will_evaluate or any(r.chunk < c <= r.stop_chunk for c in r.due)
    future = None
    if will_evaluate:
        future = compile_evaluation_async(spec, r.eval_keys[0], r.program.view(local_view(r.state), 0))
    r.evaluations = RunEvaluations(spec, future)
    keep = periodic.kept_chunk(r.chunk, updates) if r.resuming else None
    r.eval_logs = [periodic.EvalLog(d, keep) for d in r.seed_dirs] if is_main_process() and r.due else []
    r.last_saved = r.chunk if r.resuming else -1
    return bar


def _train(r: _Run, bar: Progress) -> int:
    """Chunks until ``stop_chunk`` (or a stop signal: after the chunk it came in), each logged, checkpointed
    every ``checkpoint_every`` and at the stop; the signal's number (0: none)."""
    r.t_loop = time.perf_counter()
    with contextlib.ExitStack() as stack:
        interrupt = stack.enter_context(stop_on_signals(jax.process_count() == 1))
        stack.callback(bar.close)
        for logger in r.loggers:
            stack.callback(logger.close)
        while r.chunk < r.stop_chunk:
            _chunk(r, bar)
            if interrupt["signal"] and r.chunk < r.stop_chunk:
                r.stop_chunk = r.chunk  # saved just below, then the loop ends
            if r.chunk % r.spec.checkpoint_every == 0 or r.chunk == r.stop_chunk:
                r.save()
    jax.block_until_ready(r.state)
    return interrupt["signal"]


def _chunk(r: _Run, bar: Progress) -> None:
    """One chunk: its losses checked, its metrics logged, the bar moved, an evaluation if one is due."""
    t_chunk = time.perf_counter()
    new_state, metrics = r.program.update(r.state)
    per_seed = r.program.per_seed(to_host(metrics))
    dt = time.perf_counter() - t_chunk
    if r.compile_s is None:
        r.compile_s = dt
        if r.loggers and jax.default_backend() != "cpu":  # pyplot imported while an accelerator runs the
            import_in_background()  # chunks (on the CPU backend the cores run them: it would only slow them)
    _check_losses(r, per_seed)
    r.state, r.chunk = new_state, r.chunk + 1
    sps = r.steps_per * len(r.seeds) / max(dt, 1e-9)
    for logger, m in zip(r.loggers, per_seed, strict=False):  # no loggers off process 0
        logger.write(r.chunk * r.steps_per, {**m, "steps_per_s": sps})
    bar.update(r.chunk * r.steps_per, progress_info(per_seed[0], sps))
    if r.chunk in r.due and r.chunk < r.spec.trainer.num_updates:  # before its checkpoint (the final one: later)
        _evaluate_during(r)


def _check_losses(r: _Run, per_seed: list[dict[str, float]]) -> None:
    """Raise :class:`NonFiniteLossError` when a loss of the chunk after ``r.chunk`` is NaN/inf, the state
    before it checkpointed first."""
    bad = [(k, i) for i, m in enumerate(per_seed) for k, v in m.items() if "loss" in k and not math.isfinite(v)]
    if not bad:
        return
    if r.last_saved != r.chunk:
        r.save()
    name, i = bad[0]
    chunk, steps = r.chunk, r.steps_per
    raise NonFiniteLossError(
        f"{name} is {per_seed[i][name]}" + (f" (seed {r.seeds[i]})" if len(r.seeds) > 1 else "")
        + f" after env step {(chunk + 1) * steps} (chunk {chunk + 1}); last good checkpoint: "
        f"{r.ckpt.directory}/{chunk} at env step {chunk * steps}"
    )  # fmt: skip


def _evaluate_during(r: _Run) -> None:
    """Every seed's evaluation after chunk ``r.chunk``, a row each in ``evals.csv`` (process 0)."""
    c, updates = r.chunk, r.spec.trainer.num_updates
    t = time.perf_counter()
    clock, since_start = r.train_clock(t), r.since_start(t)
    local = local_view(r.state)
    for i, key in enumerate(r.eval_keys):
        t_seed = time.perf_counter()
        summary = r.evaluations.during(periodic.key_at(key, c, updates), r.program.view(local, i))
        clocks = {"train_wall_s": clock, "process_s": since_start, "eval_s": time.perf_counter() - t_seed,
                  "startup_s": r.startup_s, "first_chunk_s": r.compile_s}  # fmt: skip
        for log in r.eval_logs[i : i + 1]:  # none off process 0
            log.add(periodic.row_of(c, c * r.steps_per, clocks, summary))
    r.eval_spent += time.perf_counter() - t


def _finish(r: _Run, signum: int) -> dict[str, Any]:
    """The run's result: its figures drawn; stopped early, how to continue; finished, its final evaluation."""
    train_s = time.perf_counter() - r.t_loop - r.eval_spent
    finished = r.chunk >= r.spec.trainer.num_updates
    result: dict[str, Any] = {
        "run_dir": r.run_dir,
        "finished": finished,
        "env_steps": r.chunk * r.steps_per,
        "compile_s": r.compile_s,
        "startup_s": r.startup_s,
        "train_s": train_s,
        "periodic_eval_s": r.eval_spent,
    }
    for logger, d in zip(r.loggers, r.seed_dirs, strict=False):  # no loggers off process 0
        plot_training_curves(read_csv(logger.path), d)
    if signum and not finished:  # on the last chunk the run ends as it would anyway
        result["interrupted"] = int(signum)
        say(f"{signal.Signals(signum).name}: stopped after chunk {r.chunk}, checkpoint saved")
    if not finished:
        result["wall_s"] = r.wall_before + time.perf_counter() - r.t0
        say(f"stopped at {result['env_steps']} env steps; continue with --resume {r.run_dir}")
    else:
        _final_evaluation(r, result)
    r.ckpt.close()
    return result


def _final_evaluation(r: _Run, result: dict[str, Any]) -> None:
    """Every seed's final evaluation into ``result`` (``eval``, or ``seeds`` of several), with its clocks; on
    process 0 its ``eval.json``, its table and the last row of ``evals.csv``."""
    t_eval = time.perf_counter()
    local_state = local_view(r.state)
    r.evaluations.final()  # the background compilation waited for before the seeds' clocks start
    main, several, summaries = is_main_process(), len(r.seeds) > 1, []
    for i, (key, d) in enumerate(zip(r.eval_keys, r.seed_dirs, strict=True)):
        t_seed = time.perf_counter()
        summaries.append(r.evaluations.final_summary(key, r.program.view(local_state, i), d if main else None))
        clocks = {"train_wall_s": r.train_before + result["train_s"], "process_s": r.since_start(t_eval),
                  "startup_s": r.startup_s, "eval_s": time.perf_counter() - t_seed,
                  "first_chunk_s": r.compile_s}  # fmt: skip
        for log in r.eval_logs[i : i + 1]:  # --evals: the final evaluation is the last row
            log.add(periodic.row_of(r.chunk, r.chunk * r.steps_per, clocks, summaries[-1]))
    result["eval_s"] = time.perf_counter() - t_eval
    result["compile"] = compile_log().since(r.spec.compile_mark)
    result["wall_s"] = r.wall_before + time.perf_counter() - r.t0
    if several:
        result["seeds"] = [
            {"seed": k, "run_dir": d, "eval": e} for k, d, e in zip(r.seeds, r.seed_dirs, summaries, strict=True)
        ]
    else:
        result["eval"] = summaries[0]
    if main:
        shared = {k: v for k, v in result.items() if k not in ("eval", "seeds")}
        for k, d, summary in zip(r.seeds, r.seed_dirs, summaries, strict=True):
            write_json(os.path.join(d, "eval.json"), {**summary, **shared, **({"seed": k} if several else {})})
            title = evaluation_title(r.spec.algo, r.spec.env_name, k if several else None)
            print_table(title, {**summary, "env_steps": result["env_steps"], "wall_s": round(result["wall_s"], 1)})
