"""Evaluations during training (``--evals N`` of every ``python -m train.<algo>``): when they happen, their
keys, and the ``evals.csv`` they write.

A run of ``C`` chunks with ``--evals N`` evaluates after chunks ``ceil(i · C / N)`` for ``i = 1 … N`` (each
chunk at most once, so ``N > C`` evaluates after every chunk; :func:`eval_chunks`); the last is chunk ``C``,
whose evaluation *is* the run's final evaluation (``eval.json``). Each evaluation is the final evaluation's
program on ``--eval-episodes`` episodes of the state after that chunk, with the key :func:`key_at`:
``fold_in(evaluation_key(seed), chunk)`` before the last chunk, the final evaluation's own key
``evaluation_key(seed)`` at it (tracking envs run their one test episode from ``t = 0``, which takes no key).

Each evaluation adds one row to ``<run dir>/evals.csv`` (``seed<k>/evals.csv`` with ``--seeds`` > 1):
``chunk``, ``env_steps``, ``train_wall_s`` (the training clock: seconds of training so far, the first chunk's
compilation included and every evaluation left out, summed over the processes of a resumed run),
``process_s`` (seconds from this process's start to the evaluation, evaluations before it left out; empty
where the start is unknown), ``eval_s`` (this evaluation's seconds), ``startup_s`` and ``first_chunk_s`` (this
process's: from its start to the run's, and its first chunk, compilation included; ``eval.json``'s
``startup_s`` and ``compile_s``), then every number of the evaluation's summary (``success_rate``,
``success_5cm``, ``mean_return``, a tracking env's per-axis error sums, …).
"""

from __future__ import annotations

import csv
import os
from collections.abc import Mapping
from typing import Any

import jax

__all__ = ["EVALS_FILE", "FIRST_COLUMNS", "EvalLog", "eval_chunks", "key_at", "kept_chunk", "read_evals", "row_of"]

EVALS_FILE = "evals.csv"
FIRST_COLUMNS = ("chunk", "env_steps", "train_wall_s", "process_s", "eval_s", "startup_s", "first_chunk_s")
"""The columns of ``evals.csv`` before the evaluation's summary."""


def eval_chunks(evals: int, chunks: int) -> tuple[int, ...]:
    """The chunks after which a run of ``chunks`` chunks evaluates with ``--evals evals``, ascending:
    ``ceil(i · chunks / evals)`` for ``i = 1 … evals``, each once; ``()`` for ``evals = 0``.

    >>> eval_chunks(3, 50), eval_chunks(3, 4), eval_chunks(9, 3)
    ((17, 34, 50), (2, 3, 4), (1, 2, 3))
    """
    if evals <= 0 or chunks <= 0:
        return ()
    return tuple(sorted({-(-i * chunks // evals) for i in range(1, evals + 1)}))


def key_at(eval_key: jax.Array, chunk: int, last_chunk: int) -> jax.Array:
    """The key of the evaluation after ``chunk`` of a run of ``last_chunk`` chunks whose final evaluation
    uses ``eval_key`` (``jaxrl_robot.evaluation.evaluation_key(seed)``): ``fold_in(eval_key, chunk)`` before the last
    chunk, ``eval_key`` itself at it (that evaluation is the final one)."""
    return eval_key if chunk == last_chunk else jax.random.fold_in(eval_key, chunk)


def kept_chunk(resumed_chunk: int, last_chunk: int) -> int:
    """The last chunk whose row a run resumed at ``resumed_chunk`` keeps: rows after it are evaluated again
    (an evaluation comes before its chunk's checkpoint, so a checkpoint's chunk has its row), and so is the
    last chunk's, written after the final evaluation, which a resumed finished run runs again."""
    return min(resumed_chunk, last_chunk - 1)


def row_of(chunk: int, env_steps: int, clocks: Mapping[str, Any], summary: Mapping[str, Any]) -> dict[str, Any]:
    """One row of ``evals.csv``: ``chunk``, ``env_steps``, the seconds of ``clocks`` (the other
    :data:`FIRST_COLUMNS`; None or missing: empty), then the numbers of ``summary`` (an evaluation's summary;
    text such as ``kind`` left out)."""
    row: dict[str, Any] = {"chunk": int(chunk), "env_steps": int(env_steps)}
    for k in FIRST_COLUMNS[2:]:
        v = clocks.get(k)
        row[k] = "" if v is None else round(float(v), 3)
    for k, v in summary.items():
        if isinstance(v, int | float) and k not in row:
            row[k] = v
    return row


def read_evals(path: str) -> list[dict[str, str]]:
    """The rows of an ``evals.csv`` as dicts of strings, in file order."""
    with open(path, newline="") as f:
        return list(csv.DictReader(f))


class EvalLog:
    """``<directory>/evals.csv``, rewritten whole (to a temporary file, then renamed) at every row, so that
    a run stopped at any moment leaves a complete file.

    Opened for a resumed run (``keep_through`` given), it keeps the existing rows of chunks up to
    ``keep_through`` (:func:`kept_chunk`) and drops the others, so the resumed run repeats none; a file
    that cannot be read is kept beside as ``evals.csv.unreadable`` (one line on stderr) and started anew.
    """

    def __init__(self, directory: str, keep_through: int | None = None):
        self.path = os.path.join(directory, EVALS_FILE)
        self.rows: list[dict[str, Any]] = []
        if keep_through is not None and os.path.exists(self.path):
            try:
                self.rows = [r for r in read_evals(self.path) if int(float(r["chunk"])) <= keep_through]
            except (OSError, KeyError, TypeError, ValueError, csv.Error) as e:
                os.replace(self.path, self.path + ".unreadable")
                print(f"{self.path}: unreadable ({type(e).__name__}: {e}); kept as {EVALS_FILE}.unreadable, "
                      "the rows of this run start anew", flush=True)  # fmt: skip
            self._write()

    def add(self, row: Mapping[str, Any]) -> None:
        """Append ``row`` (:func:`row_of`) and rewrite the file."""
        self.rows.append(dict(row))
        self._write()

    def _write(self) -> None:
        columns = list(FIRST_COLUMNS)
        for row in self.rows:
            columns += [k for k in row if k not in columns]
        tmp = self.path + ".tmp"
        with open(tmp, "w", newline="") as f:
            writer = csv.DictWriter(f, fieldnames=columns, restval="")
            writer.writeheader()
            writer.writerows(self.rows)
        os.replace(tmp, self.path)
