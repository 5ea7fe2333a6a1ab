"""The run directory ``runs/<algo>-<env>-<time>/``: made (process 0 chooses its name), locked while a process
writes it, its ``config.json`` written and read back, and its newest good checkpoint restored on ``--resume``
(a ``config.json`` that no longer builds the saved state is one line naming the arrays and fields that differ).
"""

from __future__ import annotations

import json
import math
import os
import sys
import time
from typing import Any

import jax
import numpy as np

from jaxrl_robot.checkpoint import (
    Checkpointer,
    CheckpointMismatchError,
    DirectoryInUseError,
    DirectoryLock,
    Restored,
)
from train.hosts import broadcast_text, is_main_process
from train.options import COMMAND_LINE_FIELDS

__all__ = [
    "RunDirError",
    "jsonable",
    "load_config",
    "lock_run_dir",
    "make_run_dir",
    "mismatch_error",
    "restore_run",
    "write_json",
]


class RunDirError(ValueError):
    """The run directory cannot be created (``--out``); the message names the path and the reason."""


def make_run_dir(out: str, algo: str, env_name: str) -> str:
    """Create ``out/<algo>-<env>-<YYYYmmdd-HHMMSS>`` (a numeric suffix if it exists).

    With several processes only process 0 creates it; every process gets its name.
    """
    if jax.process_count() > 1:
        return broadcast_text(_new_run_dir(out, algo, env_name) if is_main_process() else "")
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


def jsonable(x: Any) -> Any:
    """``x`` with NumPy values as Python ones, tuples as lists, non-finite floats as None (JSON's null)."""
    if isinstance(x, dict):
        return {str(k): jsonable(v) for k, v in x.items()}
    if isinstance(x, list | tuple):
        return [jsonable(v) for v in x]
    if isinstance(x, np.generic | np.ndarray):
        return jsonable(x.tolist())
    if isinstance(x, float) and not math.isfinite(x):
        return None
    return x


def write_json(path: str, obj: Any) -> None:
    """``obj`` (:func:`jsonable`) into the file ``path``, indented, keys sorted."""
    with open(path, "w") as f:
        json.dump(jsonable(obj), f, indent=2, sort_keys=True)


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
        taken = broadcast_text(taken)
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
    saved = jsonable(ckpt.read_record(e.step).get("config") or {})
    changed = _changed_fields(saved, jsonable(config)) if saved else []
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
