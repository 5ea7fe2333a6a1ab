"""A run's evaluations of its trained policy (:mod:`jaxrl_robot.evaluation` for one seed's train state): the
final evaluation's program compiled in a background thread while training runs (kept between processes by
the run's :class:`~jaxrl_robot.compilation.ProgramCache`), the same program for the evaluations during
training (``--evals``, :mod:`train.periodic`), the tracking figures and the printed table.
"""

from __future__ import annotations

import functools
from collections.abc import Callable
from concurrent.futures import Future
from typing import Any

import jax
import numpy as np

from jaxrl_robot.compilation import in_thread
from jaxrl_robot.evaluation import (
    evaluate,
    evaluation_kind,
    evaluation_program,
    summarize_evaluation,
    tracking_episode,
    tracking_summary,
)
from jaxrl_robot.plots import plot_tracking
from train.options import RunSpec

__all__ = [
    "RunEvaluations",
    "compile_evaluation_async",
    "compiled_program",
    "evaluate_state",
    "evaluation_title",
    "print_table",
]


def _program_of(spec: RunSpec) -> Callable[[jax.Array, Any], dict[str, Any]]:
    """``(key, state) -> arrays`` of one evaluation of a seed's state
    (:func:`~jaxrl_robot.evaluation.evaluation_program`)."""
    return evaluation_program(spec.env, spec.trainer.policy, spec.eval_episodes, spec.episode_length, spec.precision)


def compile_evaluation_async(
    spec: RunSpec, key: jax.Array, state: Any
) -> Future[Callable[[jax.Array, Any], Any]] | None:
    """Compile ``(key, state) -> final_episodes(...)`` of ``spec.trainer.policy(state)`` in a thread.

    Returns a future of the compiled function, or None for tracking and racing envs (their test episode
    is compiled when it runs). The thread overlaps XLA compilation with training. ``state`` is this
    process's view of the state (:func:`train.hosts.local_view`): the evaluation runs on local devices.
    """
    if evaluation_kind(spec.env) != "episodes":
        return None
    fn, cache = jax.jit(_program_of(spec)), spec.program_cache
    if cache is None:
        return in_thread("compile-eval", lambda: fn.lower(key, state).compile())
    return in_thread("compile-eval", cache.compile, "evaluation", fn, key, state)


def compiled_program(future: Future | None) -> Callable[..., Any] | None:
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


def evaluate_state(
    spec: RunSpec, key: jax.Array, state: Any, run_dir: str | None = None, compiled: Callable[..., Any] | None = None
) -> dict[str, Any]:
    """The final evaluation (:func:`jaxrl_robot.evaluation.evaluate`) of one seed's ``state``:
    ``spec.trainer.policy(state)`` on ``spec.env`` over ``spec.eval_episodes`` episodes; ``compiled``:
    :func:`compile_evaluation_async`'s program (``(key, state=…) -> episodes``, None: compiled here); a tracking
    env's figures drawn into ``run_dir`` if given."""
    policy = spec.trainer.policy(state)
    if run_dir is not None and evaluation_kind(spec.env) == "tracking":
        result = tracking_episode(spec.env, policy)
        summary = tracking_summary(result, tuple(result["axis_names"]))
        draw_tracking(result, run_dir)
        return summary
    return evaluate(
        key, spec.env, policy, spec.eval_episodes, spec.episode_length,
        episodes_fn=None if compiled is None else functools.partial(compiled, state=state), precision=spec.precision,
    )  # fmt: skip


def draw_tracking(result: dict[str, Any], run_dir: str) -> None:
    """The reference and real paths and the errors of a tracking env's test episode
    (:func:`~jaxrl_robot.evaluation.tracking_episode`'s ``result``) as figures in ``run_dir``."""
    real, ref = result["real_path"], result["ref_path"]
    ok = np.isfinite(real[:, 0])
    plot_tracking(ref[ok], real[ok], result["abs_error"][: result["steps"]], run_dir, tuple(result["axis_names"]))


class RunEvaluations:
    """A run's evaluation programs, each compiled once: the final evaluation's (``future`` of
    :func:`compile_evaluation_async`, None for tracking and racing envs), which the evaluations during training
    (``--evals``) run too, and for tracking and racing envs one program over ``(key, state)`` compiled at its
    first call (their final evaluation compiles its own as it runs)."""

    def __init__(self, spec: RunSpec, future: Future | None):
        self._spec, self._future = spec, future
        self._final: Callable[..., Any] | None = None
        self._waited = False
        self._during: Callable[[jax.Array, Any], dict[str, Any]] | None = None

    def final(self) -> Callable[..., Any] | None:
        """The final evaluation's compiled program (:func:`compiled_program`, waited for at the first call)."""
        if not self._waited:
            self._final, self._waited = compiled_program(self._future), True
        return self._final

    def final_summary(self, key: jax.Array, state: Any, run_dir: str | None) -> dict[str, Any]:
        """The final evaluation of one seed's ``state`` with ``key`` (:func:`evaluate_state`; figures into
        ``run_dir`` if given)."""
        return evaluate_state(self._spec, key, state, run_dir, self.final())

    def during(self, key: jax.Array, state: Any) -> dict[str, Any]:
        """One evaluation during training of one seed's ``state`` with ``key``: the final evaluation's summary."""
        if self._during is None:
            self._during = self._episodes() if evaluation_kind(self._spec.env) == "episodes" else self._other()
        return self._during(key, state)

    def _other(self) -> Callable[[jax.Array, Any], dict[str, Any]]:
        """A tracking or racing env's ``(key, state) -> summary``: one jitted program (a tracking env's test
        episode from ``t = 0`` takes no key)."""
        spec, program = self._spec, jax.jit(_program_of(self._spec))
        return lambda k, s: summarize_evaluation(spec.env, jax.device_get(program(k, s)), spec.eval_episodes)

    def _episodes(self) -> Callable[[jax.Array, Any], dict[str, Any]]:
        """:func:`evaluate_state` with the final evaluation's program (one compiled here where that failed)."""
        spec, compiled = self._spec, self.final()
        if compiled is None:
            fn = jax.jit(_program_of(spec))
            compiled = lambda k, state: fn(k, state)  # noqa: E731
        return lambda k, s: evaluate_state(spec, k, s, None, compiled)


def evaluation_title(algo: str, env_name: str, seed: int | None = None) -> str:
    """The title of the evaluation table: ``"ppo on arm7: evaluation"`` (``seed``: one seed of several)."""
    return f"{algo} on {env_name}" + ("" if seed is None else f", seed {seed}") + ": evaluation"


def print_table(title: str, rows: dict[str, Any]) -> None:
    """``rows`` as a two-column table (metric, value; floats to 4 significant digits) under ``title``."""
    from rich.console import Console
    from rich.table import Table

    table = Table(title=title)
    table.add_column("metric")
    table.add_column("value", justify="right")
    for k, v in rows.items():
        table.add_row(k, f"{v:.4g}" if isinstance(v, float) else str(v))
    Console(force_terminal=False, soft_wrap=True, width=100).print(table)
