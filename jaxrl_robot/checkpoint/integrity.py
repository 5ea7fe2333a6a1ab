"""What keeps a run's checkpoints trustworthy: checksums, one-line errors, failed writes cleaned up, one writer.

* :func:`write_checksums` lists the size and SHA-256 of every file of a step in :data:`CHECKSUMS`;
  :func:`verify_checksums` checks them (:class:`CheckpointDamagedError` on a missing, truncated or altered file);
* the errors of :class:`~jaxrl_robot.checkpoint.Checkpointer`, each with a one-line message;
* a failed save's OS error found in orbax's and tensorstore's wrapping (:func:`os_error_code`,
  :func:`short_reason`), orbax's writer threads waited for and their logged tracebacks held back;
* :class:`DirectoryLock`: one process writes a run directory at a time.
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
import threading
import time
from collections.abc import Iterator
from typing import Any

__all__ = [
    "CHECKSUMS",
    "CheckpointDamagedError",
    "CheckpointError",
    "CheckpointMismatchError",
    "CheckpointWriteError",
    "DirectoryInUseError",
    "DirectoryLock",
]
"""The names :mod:`jaxrl_robot.checkpoint` re-exports; the functions below serve its ``Checkpointer``."""

CHECKSUMS = "checksums.json"
"""File of a step folder listing ``{relative path: {"size", "sha256"}}`` of every other file in it."""

MAX_LISTED = 3
"""Differences named in a :class:`CheckpointMismatchError` (the rest are counted)."""


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


def verify_checksums(step: int, folder: str) -> bool:
    """Check the files of the step folder ``folder`` against its :data:`CHECKSUMS`.

    Returns:
      True if they match, False if the step has no checksums (written by an earlier version).
    Raises:
      CheckpointDamagedError: a listed file is missing, of another size or another SHA-256.
    """
    path = os.path.join(folder, CHECKSUMS)
    if not os.path.isdir(folder):
        raise CheckpointDamagedError(step, f"no folder {folder}")
    if not os.path.exists(path):
        return False
    try:
        with open(path) as f:
            listed = json.load(f)["files"]
    except (OSError, ValueError, KeyError, TypeError) as e:
        raise CheckpointDamagedError(step, f"{CHECKSUMS} unreadable: {short_reason(e)}") from None
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


def _sha256(path: str) -> str:
    with open(path, "rb") as f:
        return hashlib.file_digest(f, "sha256").hexdigest()


def write_checksums(folder: str) -> None:
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


def folder_size(folder: str) -> int:
    """Bytes the files under ``folder`` take on disk (allocated blocks: a checkpoint has many small files)."""
    stats = [os.stat(os.path.join(r, n)) for r, _, names in os.walk(folder) for n in names]
    return sum(max(s.st_size, getattr(s, "st_blocks", 0) * 512) for s in stats)


def megabytes(n: int) -> str:
    return f"{n / 1e6:.1f} MB" if n >= 1e5 else f"{n / 1e3:.1f} kB"


_WHERE = re.compile(r' in OCDBT database at local file "[^"]*"')
_OS_CODE = re.compile(r"os_error_code='?(\d+)")


def os_error_code(e: BaseException) -> int | None:
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


def join_writer_threads(timeout: float = 60.0) -> None:
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


def short_reason(e: BaseException, limit: int = 160) -> str:
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
def held_error_logs() -> Iterator[list[logging.LogRecord]]:
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
