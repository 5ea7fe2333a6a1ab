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

Every error's message is one line.
"""

from __future__ import annotations

import contextlib
import errno
import fcntl
import hashlib
import json
import logging
import os
import re
import shutil
import threading
import time
from collections.abc import Iterator
from typing import Any, NamedTuple

import jax
import numpy as np
import orbax.checkpoint as ocp

__all__ = [
    "CHECKSUMS",
    "CheckpointDamagedError",
    "CheckpointError",
    "CheckpointMismatchError",
    "CheckpointWriteError",
    "Checkpointer",
    "DirectoryInUseError",
    "DirectoryLock",
    "Restored",
]

CHECKSUMS = "checksums.json"
"""File of a step folder listing ``{relative path: {"size", "sha256"}}`` of every other file in it."""

MAX_LISTED = 3
"""Differences named in a :class:`CheckpointMismatchError` (the rest are counted)."""

RENAMED = {"termination": "terminated"}
"""Names of state fields that earlier versions saved under another name (now -> then); a checkpoint
holding the old name restores into a state with the new one. ``terminated``: the termination of a
replay memory's rows before :class:`jaxrl_robot.types.Transition` became the one transition type."""


class CheckpointError(Exception):
    """A checkpoint cannot be written or read; the message is one line naming the folder or step."""


class CheckpointDamagedError(CheckpointError):
    """A checkpoint's files are missing, altered or unreadable (``step``, ``reason``)."""

    def __init__(self, step: int, reason: str, message: str | None = None):
        super().__init__(message or f"checkpoint {step} is damaged ({reason})")
        self.step, self.reason = step, reason


class CheckpointMismatchError(CheckpointError):
    """The state to restore into has other arrays than the checkpoint (``step``, ``differences``)."""

    def __init__(self, step: int, differences: list[str], message: str | None = None):
        self.step, self.differences = step, differences
        super().__init__(message or f"checkpoint {step} does not match the state: {self.listed()}")

    def listed(self) -> str:
        """The first :data:`MAX_LISTED` differences and how many more, in one line."""
        more = len(self.differences) - MAX_LISTED
        return "; ".join(self.differences[:MAX_LISTED]) + (f"; {more} more" if more > 0 else "")


class CheckpointWriteError(CheckpointError):
    """A save failed (disk full, quota, any ``OSError``); its partial files are removed, older steps kept."""


class DirectoryInUseError(CheckpointError):
    """Another process holds the :class:`DirectoryLock` of the directory."""


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
        with _held_error_logs():
            try:
                self._manager.save(step, args=args, force=True)
                self._manager.wait_until_finished()
                if jax.process_index() == 0:
                    _write_checksums(self._step_dir(step))
            except BaseException as e:
                with contextlib.suppress(Exception):
                    self._manager.wait_until_finished()
                _join_writer_threads()  # orbax's threads may still be writing the step
                self._discard(step, keep_folder=existed)
                code = _os_error_code(e)
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
        """Check the files of ``step`` against its :data:`CHECKSUMS`.

        Returns:
          True if they match, False if the step has no checksums (written by an earlier version).
        Raises:
          CheckpointDamagedError: a listed file is missing, of another size or another SHA-256.
        """
        folder = self._step_dir(step)
        path = os.path.join(folder, CHECKSUMS)
        if not os.path.isdir(folder):
            raise CheckpointDamagedError(step, f"no folder {folder}")
        if not os.path.exists(path):
            return False
        try:
            with open(path) as f:
                listed = json.load(f)["files"]
        except (OSError, ValueError, KeyError, TypeError) as e:
            raise CheckpointDamagedError(step, f"{CHECKSUMS} unreadable: {_short(e)}") from None
        for name, want in sorted(listed.items()):
            file = os.path.join(folder, name)
            if not os.path.isfile(file):
                raise CheckpointDamagedError(step, f"{name} is missing")
            size = os.path.getsize(file)
            if size != want["size"]:
                raise CheckpointDamagedError(step, f"{name} has {size} bytes, {want['size']} were written")
            if _sha256(file) != want["sha256"]:
                raise CheckpointDamagedError(step, f"{name} does not match its SHA-256")
        return True

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
            raise CheckpointDamagedError(step, f"metadata unreadable: {_short(e)}") from None
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
            device = jax.sharding.SingleDeviceSharding(jax.local_devices()[0])
            abstract = jax.tree.map(lambda m: jax.ShapeDtypeStruct(m.shape, m.dtype, sharding=device),
                                    self._saved_metadata(step))  # fmt: skip
        args = ocp.args.Composite(state=ocp.args.StandardRestore(abstract), record=ocp.args.JsonRestore())
        try:
            with _held_error_logs():
                out = self._manager.restore(step, args=args)
        except Exception as e:  # orbax / tensorstore: a file it could not read
            raise CheckpointDamagedError(step, _short(e)) from None
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
            with _held_error_logs():
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
                needs.append(f"checkpoint {max(earlier)} took {_megabytes(_folder_size(self._step_dir(max(earlier))))}")
            with contextlib.suppress(OSError):
                needs.append(f"{_megabytes(shutil.disk_usage(self.directory).free)} free")
            if needs:
                text += f" ({', '.join(needs)})"
        return text + "; the partial checkpoint is removed, earlier ones are intact"


class DirectoryLock:
    """An exclusive ``flock`` on ``directory/.lock`` while a process writes ``directory``.

    The kernel releases the lock when its process ends in any way (``kill -9`` included), so a
    stale lock file never blocks. The file holds the holder's pid, for the message of a second writer.
    Use as a context manager, or :meth:`acquire` / :meth:`release`.
    """

    NAME = ".lock"

    def __init__(self, directory: str):
        self.directory = directory
        self.path = os.path.join(directory, self.NAME)
        self._fd: int | None = None

    def acquire(self) -> DirectoryLock:
        """Take the lock.

        Raises:
          DirectoryInUseError: another process (or another ``DirectoryLock`` here) holds it.
        """
        fd = os.open(self.path, os.O_RDWR | os.O_CREAT, 0o644)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
        except OSError as e:
            holder = os.pread(fd, 32, 0).decode(errors="replace").strip() or "unknown"
            os.close(fd)
            if e.errno not in (errno.EWOULDBLOCK, errno.EAGAIN, errno.EACCES):
                raise
            raise DirectoryInUseError(
                f"run directory {self.directory} is in use by another process (pid {holder})"
            ) from None
        os.ftruncate(fd, 0)
        os.pwrite(fd, f"{os.getpid()}\n".encode(), 0)
        self._fd = fd
        return self

    def release(self) -> None:
        """Give the lock back (closing the file releases it); no-op if not held."""
        if self._fd is not None:
            os.close(self._fd)
            self._fd = None

    def __enter__(self) -> DirectoryLock:
        return self.acquire()

    def __exit__(self, *exc: Any) -> None:
        self.release()


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


def _sha256(path: str) -> str:
    with open(path, "rb") as f:
        return hashlib.file_digest(f, "sha256").hexdigest()


def _write_checksums(folder: str) -> None:
    """Write :data:`CHECKSUMS` of every file under ``folder`` (atomically: a temporary file renamed)."""
    files = {}
    for root, _, names in os.walk(folder):
        for name in names:
            path = os.path.join(root, name)
            rel = os.path.relpath(path, folder)
            if rel != CHECKSUMS:
                files[rel] = {"size": os.path.getsize(path), "sha256": _sha256(path)}
    tmp = os.path.join(folder, CHECKSUMS + ".tmp")
    with open(tmp, "w") as f:
        json.dump({"algorithm": "sha256", "files": dict(sorted(files.items()))}, f, indent=1)
        f.flush()
        os.fsync(f.fileno())
    os.replace(tmp, os.path.join(folder, CHECKSUMS))


def _folder_size(folder: str) -> int:
    """Bytes the files under ``folder`` take on disk (allocated blocks: a checkpoint has many small files)."""
    stats = [os.stat(os.path.join(r, n)) for r, _, names in os.walk(folder) for n in names]
    return sum(max(s.st_size, getattr(s, "st_blocks", 0) * 512) for s in stats)


def _megabytes(n: int) -> str:
    return f"{n / 1e6:.1f} MB" if n >= 1e5 else f"{n / 1e3:.1f} kB"


_WHERE = re.compile(r' in OCDBT database at local file "[^"]*"')
_OS_CODE = re.compile(r"os_error_code='?(\d+)")


def _os_error_code(e: BaseException) -> int | None:
    """The errno of an ``OSError`` in ``e``'s chain, or of a tensorstore error (``os_error_code='28'``)
    that orbax raises as ``ValueError``; 0 for an ``OSError`` without one; None if it is no OS error."""
    seen = set()
    while e is not None and id(e) not in seen:
        seen.add(id(e))
        if isinstance(e, OSError):
            return e.errno or 0
        match = _OS_CODE.search(str(e))
        if match:
            return int(match.group(1))
        e = e.__cause__ or e.__context__
    return None


def _join_writer_threads(timeout: float = 60.0) -> None:
    """Wait (up to ``timeout`` s in all) for orbax's writer threads that a failed save leaves running:
    until they end they may still create files of the step."""
    try:
        from orbax.checkpoint._src.futures.future import _SignalingThread as writer
    except ImportError:  # another orbax: nothing known to wait for
        return
    deadline = time.monotonic() + timeout
    for thread in threading.enumerate():
        if isinstance(thread, writer) and thread is not threading.current_thread():
            thread.join(max(0.0, deadline - time.monotonic()))


def _short(e: BaseException, limit: int = 160) -> str:
    """The first line of the message of the first cause of ``e`` (tensorstore's reason under orbax's
    wrapping), at most ``limit`` characters."""
    seen = {id(e)}
    while (e.__cause__ or e.__context__) is not None and id(e.__cause__ or e.__context__) not in seen:
        e = e.__cause__ or e.__context__
        seen.add(id(e))
    text = (str(e).strip().splitlines() or [type(e).__name__])[0]
    text = _WHERE.sub("", text)  # the checkpoint's own path: the message names the step already
    return text if len(text) <= limit else text[: limit // 2 - 2] + " … " + text[-(limit // 2 - 1) :]


@contextlib.contextmanager
def _held_error_logs() -> Iterator[list[logging.LogRecord]]:
    """Hold back the ERROR records orbax's worker threads log (absl) while the block runs.

    Orbax logs a failure's traceback from its thread and then raises it; the caller turns the raised
    error into one line.  The held records are logged when the block ends normally, dropped when it raises.
    """
    logger = logging.getLogger("absl")
    held: list[logging.LogRecord] = []

    def keep(record: logging.LogRecord) -> bool:
        if record.levelno >= logging.ERROR:
            held.append(record)
            return False
        return True

    logger.addFilter(keep)
    try:
        yield held
    finally:
        logger.removeFilter(keep)
    for record in held:
        logger.handle(record)
