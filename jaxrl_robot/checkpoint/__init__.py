"""Orbax checkpoints of a whole train state plus a small JSON record per step, checksummed.

A checkpoint holds the complete state pytree (parameters, optimiser states, normalisers,
environment states, RNG key, counters), so restoring it continues a run exactly. Saves are
synchronous (the files are complete when ``save`` returns) and the newest ``max_to_keep``
are kept.

Trust:

* after a save, ``<step>/checksums.json`` lists the size and SHA-256 of every file of the
  step; :meth:`Checkpointer.restore` checks them first, so a truncated or altered file is
  reported as :class:`CheckpointDamagedError` instead of being loaded (checkpoints written
  before checksums existed restore unverified);
* :meth:`Checkpointer.restore_latest` falls back to the newest good checkpoint and sets the
  damaged newer ones aside in ``<directory>.damaged/`` (kept, not deleted);
* a state whose array shapes or dtypes differ from the checkpoint's is a
  :class:`CheckpointMismatchError` naming the paths;
* a save that fails (disk full, any ``OSError``) removes its partial files and raises
  :class:`CheckpointWriteError` naming the folder and the space the previous checkpoint took;
* :class:`DirectoryLock` keeps a second process from writing a run directory at the same time.

Every error's message is one line.  The checksums, the errors and the lock are
:mod:`jaxrl_robot.checkpoint.integrity`'s (re-exported here).
"""

from __future__ import annotations

import contextlib
import errno
import os
import shutil
from typing import Any, NamedTuple

import jax
import numpy as np
import orbax.checkpoint as ocp

from jaxrl_robot import parallel
from jaxrl_robot.checkpoint import integrity
from jaxrl_robot.checkpoint.integrity import (  # noqa: F401  (re-exported: integrity.__all__)
    CHECKSUMS,
    CheckpointDamagedError,
    CheckpointError,
    CheckpointMismatchError,
    CheckpointWriteError,
    DirectoryInUseError,
    DirectoryLock,
)

__all__ = ["Checkpointer", "Restored", *integrity.__all__]

RENAMED = {"termination": "terminated"}
"""Names of state fields that earlier versions saved under another name (now -> then); a checkpoint
holding the old name restores into a state with the new one. ``terminated``: the termination of a
replay memory's rows before :class:`jaxrl_robot.types.Transition` became the one transition type."""


class Restored(NamedTuple):
    """What :meth:`Checkpointer.restore_latest` found.

    Attributes:
      step: the checkpoint restored.
      state, record: as :meth:`Checkpointer.restore` returns them.
      note: one line for the user when something is worth saying (damaged newer checkpoints
        skipped, or a checkpoint without checksums), else None.
    """

    step: int
    state: Any
    record: dict[str, Any]
    note: str | None


class Checkpointer:
    """Save and restore ``(state, record)`` pairs under ``directory/<step>/``.

    ``record`` is a JSON-able dict (counters, wall time) saved beside the state. The newest
    ``max_to_keep`` steps are kept (None: all); older ones are deleted once a new step is complete,
    checksums included.
    """

    def __init__(self, directory: str, max_to_keep: int | None = 3):
        self.directory = os.path.abspath(directory)
        self.max_to_keep = max_to_keep
        # orbax keeps every step: the oldest are deleted here, once a new step has its checksums
        options = ocp.CheckpointManagerOptions(max_to_keep=None, create=True, enable_async_checkpointing=False)
        handlers = {"state": ocp.StandardCheckpointHandler(), "record": ocp.JsonCheckpointHandler()}
        self._manager = ocp.CheckpointManager(self.directory, options=options, item_handlers=handlers)

    def save(self, step: int, state: Any, record: dict[str, Any]) -> None:
        """Write the checkpoint of ``step`` and its :data:`CHECKSUMS` (a step is saved once).

        Zero-size arrays (e.g. empty fields of MJX's ``Data``) are stored as ``None``: orbax
        cannot write them, and :meth:`restore` takes them back from ``target``.

        Raises:
          CheckpointWriteError: writing failed with an ``OSError`` (disk full, quota, permissions);
            the partial step is removed, earlier steps are untouched.
        """
        step = int(step)
        state = jax.tree.map(lambda x: x if np.size(x) else None, state)
        args = ocp.args.Composite(state=ocp.args.StandardSave(state), record=ocp.args.JsonSave(record))
        existed = os.path.exists(self._step_dir(step))  # then a failure must not remove it
        with integrity.held_error_logs():
            try:
                self._manager.save(step, args=args, force=True)
                self._manager.wait_until_finished()
                if jax.process_index() == 0:
                    integrity.write_checksums(self._step_dir(step))
            except BaseException as e:
                with contextlib.suppress(Exception):
                    self._manager.wait_until_finished()
                integrity.join_writer_threads()  # orbax's threads may still be writing the step
                self._discard(step, keep_folder=existed)
                code = integrity.os_error_code(e)
                if code is None:
                    raise
                raise CheckpointWriteError(self._write_failure(step, code)) from None
        steps = sorted(self._manager.all_steps())
        for old in steps[: max(len(steps) - self.max_to_keep, 0)] if self.max_to_keep else ():
            self._manager.delete(old)  # only now: a failed save above leaves every earlier step

    def latest_step(self) -> int | None:
        """The newest saved step, or None."""
        return self._manager.latest_step()

    def all_steps(self) -> list[int]:
        """The saved steps, oldest first."""
        return sorted(self._manager.all_steps())

    def verify(self, step: int) -> bool:
        """Check the files of ``step`` against its :data:`CHECKSUMS` (:func:`~.integrity.verify_checksums`):
        True if they match, False if the step has none (an earlier version wrote it).

        Raises:
          CheckpointDamagedError: a listed file is missing, of another size or another SHA-256.
        """
        return integrity.verify_checksums(step, self._step_dir(step))

    def differences(self, step: int, target: Any) -> list[str]:
        """How the arrays of ``target`` differ from those saved at ``step``, by path (empty: they match).

        One line per path: another shape or dtype, an array only in the checkpoint or only in ``target``.
        Zero-size leaves of ``target`` are not saved and so not compared.
        """
        saved = {_names(p): m for p, m in jax.tree_util.tree_flatten_with_path(self._saved_metadata(step))[0]}
        now = {_as_saved(_names(p), saved): x for p, x in jax.tree_util.tree_flatten_with_path(target)[0]}
        out = []
        for path, x in now.items():
            m, name = saved.get(path), ".".join(path) or "state"
            if m is None:
                if np.size(x):
                    out.append(f"{name} {_shape_text(x)} is not in the checkpoint")
                continue
            have, want = _shape_dtype(m), _shape_dtype(x)
            if have[0] != want[0]:
                out.append(f"{name} has shape {have[0]} saved, {want[0]} now")
            elif have[1] != want[1]:
                out.append(f"{name} has dtype {have[1]} saved, {want[1]} now")
        out += [f"{'.'.join(p)} {_shape_text(m)} is saved but not in the state now" for p, m in saved.items()
                if p not in now]  # fmt: skip
        return out

    def _saved_metadata(self, step: int) -> Any:
        """The saved state's tree of orbax ``ArrayMetadata`` (``shape``, ``dtype``), None for zero-size leaves."""
        try:
            tree = self._manager.item_metadata(int(step))["state"]
            tree = getattr(tree, "tree", tree)
        except Exception as e:  # the metadata file is unreadable
            raise CheckpointDamagedError(step, f"metadata unreadable: {integrity.short_reason(e)}") from None
        if tree is None:
            raise CheckpointDamagedError(step, "no metadata of the state")
        return tree

    def restore(self, step: int, target: Any = None) -> tuple[Any, dict[str, Any]]:
        """Restore ``step`` into the structure, shapes and shardings of ``target`` (a state).

        Without ``target`` the state comes back as saved, nested dicts of arrays, on this process's
        first device (wherever it was saved).  The files are checked against their checksums first
        (:meth:`verify`), then the arrays against ``target``.

        Raises:
          CheckpointDamagedError: a file is missing, altered or unreadable.
          CheckpointMismatchError: ``target`` has other arrays (shapes, dtypes, paths) than the checkpoint.
        """
        step = int(step)
        self.verify(step)
        return self._restore(step, target)

    def _restore(self, step: int, target: Any) -> tuple[Any, dict[str, Any]]:
        """:meth:`restore` without the checksums."""
        if target is not None:
            differences = self.differences(step, target)
            if differences:
                raise CheckpointMismatchError(step, differences)
            abstract = jax.tree.map(lambda x: ocp.utils.to_shape_dtype_struct(x) if np.size(x) else None, target)
            abstract = _under_saved_names(abstract, self._saved_metadata(step))
        else:  # onto this process's first device: the saved shardings may name devices this machine lacks
            device = parallel.local_sharding()
            abstract = jax.tree.map(lambda m: jax.ShapeDtypeStruct(m.shape, m.dtype, sharding=device),
                                    self._saved_metadata(step))  # fmt: skip
        args = ocp.args.Composite(state=ocp.args.StandardRestore(abstract), record=ocp.args.JsonRestore())
        try:
            with integrity.held_error_logs():
                out = self._manager.restore(step, args=args)
        except Exception as e:  # orbax / tensorstore: a file it could not read
            raise CheckpointDamagedError(step, integrity.short_reason(e)) from None
        state = out["state"]
        if target is not None:
            saved = {_names(p): v for p, v in jax.tree_util.tree_flatten_with_path(state)[0]}
            paths, treedef = jax.tree_util.tree_flatten_with_path(target)
            state = jax.tree.unflatten(treedef, [saved[_as_saved(_names(p), saved)] if np.size(t) else t
                                                 for p, t in paths])  # fmt: skip
        return state, dict(out["record"] or {})

    def read_record(self, step: int) -> dict[str, Any]:
        """The record saved with ``step`` alone (not the state); ``{}`` if it cannot be read."""
        try:
            with integrity.held_error_logs():
                out = self._manager.restore(int(step), args=ocp.args.Composite(record=ocp.args.JsonRestore()))
        except Exception:  # a damaged record: nothing to tell
            return {}
        return dict(out["record"] or {})

    def restore_latest(self, target: Any = None, set_aside: bool = True) -> Restored | None:
        """Restore the newest checkpoint that is not damaged (None: there is no checkpoint).

        Damaged newer checkpoints are moved to ``<directory>.damaged/<step>`` (by process 0) once a
        good one is restored, so that the run can write those steps again; ``note`` says which.
        With ``set_aside=False`` nothing is moved (a reader that does not continue the run).

        Raises:
          CheckpointDamagedError: every checkpoint is damaged (nothing is moved).
          CheckpointMismatchError: the newest readable checkpoint does not fit ``target``.
        """
        steps = sorted(self._manager.all_steps(), reverse=True)
        damaged: list[CheckpointDamagedError] = []
        for step in steps:
            try:
                verified = self.verify(step)
                state, record = self._restore(step, target)
            except CheckpointDamagedError as e:
                damaged.append(e)
                continue
            unverified = f"checkpoint {step} has no {CHECKSUMS} (an earlier version wrote it): restored unverified"
            note = None if verified else unverified
            if damaged:
                note = "; ".join(str(e) for e in damaged) + f"; resuming from {step}"
                note += "" if verified else f" (unverified: it has no {CHECKSUMS})"
                if not set_aside:
                    return Restored(step, state, record, note)
                if jax.process_index() == 0:
                    for e in damaged:
                        self._set_aside(e.step)
                if jax.process_count() > 1:  # every process sees them gone before it reloads the steps
                    from jax.experimental import multihost_utils

                    multihost_utils.sync_global_devices("jaxrl_robot.checkpoint: damaged steps set aside")
                self._manager.reload()
            return Restored(step, state, record, note)
        if damaged:
            listed = "; ".join(str(e) for e in damaged)
            message = f"no usable checkpoint in {self.directory}: {listed}"
            raise CheckpointDamagedError(damaged[-1].step, damaged[-1].reason, message)
        return None

    def close(self) -> None:
        self._manager.close()

    # ---- internals ------------------------------------------------------------------------------

    def _step_dir(self, step: int) -> str:
        return os.path.join(self.directory, str(int(step)))

    def _discard(self, step: int, keep_folder: bool = False) -> None:
        """Remove what a failed save of ``step`` left: orbax's temporary folders and, unless ``keep_folder``
        (it was there before the save), the step's folder."""
        if jax.process_index() == 0:
            prefix = f"{int(step)}."
            for name in os.listdir(self.directory) if os.path.isdir(self.directory) else ():
                if (name == str(int(step)) and not keep_folder) or (name.startswith(prefix) and "tmp" in name):
                    shutil.rmtree(os.path.join(self.directory, name), ignore_errors=True)
        with contextlib.suppress(Exception):
            self._manager.reload()

    def _set_aside(self, step: int) -> None:
        """Move the damaged folder of ``step`` to ``<directory>.damaged/<step>`` (``-1``, ``-2``… if taken)."""
        aside = self.directory + ".damaged"
        os.makedirs(aside, exist_ok=True)
        path, i = os.path.join(aside, str(step)), 1
        while os.path.exists(path):
            path, i = os.path.join(aside, f"{step}-{i}"), i + 1
        os.replace(self._step_dir(step), path)

    def _write_failure(self, step: int, code: int) -> str:
        """The one-line message of a failed save: the folder, the OS's reason and the space needed."""
        reason = os.strerror(code) if code else "an OS error"
        text = f"cannot write checkpoint {step} to {self.directory}: {reason}"
        if code in (errno.ENOSPC, errno.EDQUOT):
            earlier = [s for s in self._manager.all_steps() if s != step]
            needs = []
            if earlier:
                took = integrity.folder_size(self._step_dir(max(earlier)))
                needs.append(f"checkpoint {max(earlier)} took {integrity.megabytes(took)}")
            with contextlib.suppress(OSError):
                needs.append(f"{integrity.megabytes(shutil.disk_usage(self.directory).free)} free")
            if needs:
                text += f" ({', '.join(needs)})"
        return text + "; the partial checkpoint is removed, earlier ones are intact"


def _names(path: tuple) -> tuple:
    """A key path as plain names, so a dataclass field and the dict key it was saved under match."""
    return tuple(str(getattr(k, "name", getattr(k, "key", getattr(k, "idx", k)))) for k in path)


def _as_saved(path: tuple, saved: Any) -> tuple:
    """``path`` (plain names) as a checkpoint holds it (``saved``: its paths, a set or a dict's keys):
    itself, or with the :data:`RENAMED` fields under their old names where only those are saved."""
    if path in saved:
        return path
    old = tuple(RENAMED.get(name, name) for name in path)
    return old if old in saved else path


def _under_saved_names(abstract: Any, metadata: Any) -> Any:
    """``abstract`` (the target's tree) as nested dicts of the saved tree ``metadata`` where a field is
    saved under its old name (:data:`RENAMED`), so that orbax finds every array; else unchanged."""
    saved = {_names(p) for p, _ in jax.tree_util.tree_flatten_with_path(metadata)[0]}
    flat = [(_names(p), x) for p, x in jax.tree_util.tree_flatten_with_path(abstract)[0]]
    if all(_as_saved(path, saved) == path for path, _ in flat):
        return abstract
    leaves = {_as_saved(path, saved): x for path, x in flat}
    return jax.tree_util.tree_map_with_path(lambda p, _: leaves[_names(p)], metadata)


def _shape_dtype(x: Any) -> tuple[tuple[int, ...], str]:
    """``((16, 20), "float32")``: the shape and dtype of an array, a scalar or an orbax ``ArrayMetadata``."""
    shape, dtype = getattr(x, "shape", None), getattr(x, "dtype", None)
    return tuple(np.shape(x) if shape is None else shape), str(np.result_type(x) if dtype is None else dtype)


def _shape_text(x: Any) -> str:
    """``(16, 20) float32``."""
    shape, dtype = _shape_dtype(x)
    return f"{shape} {dtype}"


