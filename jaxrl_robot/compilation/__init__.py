"""Compiling once: JAX's persistent compilation cache and a record of what a process compiled.

* :func:`resolve_cache_dir` / :func:`enable_persistent_cache` — where compiled programs are kept
  between processes (by default a per-user folder, ``$XDG_CACHE_HOME/jaxrl-robot/xla`` or
  ``~/.cache/jaxrl-robot/xla``), so that a second run of the same program skips XLA's compiler.
  A cached program is the executable XLA built before, so no result changes.
* :class:`ProgramCache` — whole compiled programs (executables) kept in ``<cache folder>/programs`` under a
  key the caller states (the run's settings, this project's source files, the installed versions, the
  devices and the arguments' shapes, dtypes and shardings), so that a second process finds its program
  *before* tracing it: JAX's persistent cache skips only XLA's compiler, while tracing and lowering a
  trainer's chunk cost seconds to tens of seconds of their own.
* :class:`CompileLog` — the count and seconds of every XLA compilation (or cache retrieval) and of
  tracing and lowering in this process, and the caches' hits and misses, from ``jax.monitoring``'s
  events and :class:`ProgramCache`; :meth:`CompileLog.since` gives what happened after a :meth:`CompileLog.mark`.

The cache must be enabled before the process's first compilation (JAX opens it once).  :class:`CompileLog`
lives in :mod:`jaxrl_robot.compilation.log`, :class:`ProgramCache` in :mod:`jaxrl_robot.compilation.programs`
(both re-exported here).
"""

from __future__ import annotations

import os

import jax

from jaxrl_robot.compilation.log import CompileLog, compile_log
from jaxrl_robot.compilation.programs import CachedJit, ProgramCache, code_fingerprint, in_thread, signature
from jaxrl_robot.compilation.programs import _files_digest as _files_digest

__all__ = [
    "CACHE_ENV",
    "CachedJit",
    "CompileLog",
    "ProgramCache",
    "code_fingerprint",
    "compile_log",
    "default_cache_dir",
    "enable_persistent_cache",
    "in_thread",
    "resolve_cache_dir",
    "signature",
]

CACHE_ENV = "JAXRL_ROBOT_COMPILE_CACHE"
"""Environment variable naming the cache folder (``off`` disables it), read when no option is given."""

OFF = ("off", "none", "no", "false", "0")
"""Spellings of "no persistent cache" for ``--compile-cache`` and :data:`CACHE_ENV`."""

MIN_COMPILE_S = 0.1
"""Programs that compile faster than this are not cached: a run's few large programs (its chunk, its
evaluation, its initialisation) are what a second run saves, while caching every small one would fill
the folder with entries that JAX's size limit scans on every write (unless JAX's own variable is set)."""

DEFAULT_MAX_BYTES = 8 << 30
"""Size limit of the cache folder (least recently used entries go first) unless JAX's own is set."""


def default_cache_dir() -> str:
    """The per-user cache folder: ``$XDG_CACHE_HOME/jaxrl-robot/xla``, else ``~/.cache/jaxrl-robot/xla``."""
    root = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    return os.path.join(root, "jaxrl-robot", "xla")


def resolve_cache_dir(option: str | None = None) -> str | None:
    """The cache folder a run uses, or None for no persistent cache.

    ``option`` (``--compile-cache``) first: a folder, ``auto`` (or None) for the default, ``off``
    for none. With ``auto``: :data:`CACHE_ENV` if set, else JAX's ``JAX_COMPILATION_CACHE_DIR``
    if set, else :func:`default_cache_dir`.
    """
    if option is not None and option.strip().lower() in OFF:
        return None
    if option not in (None, "", "auto"):
        return os.path.abspath(os.path.expanduser(option))
    env = os.environ.get(CACHE_ENV)
    if env is not None and env.strip():
        return None if env.strip().lower() in OFF else os.path.abspath(os.path.expanduser(env))
    return os.environ.get("JAX_COMPILATION_CACHE_DIR") or default_cache_dir()


def enable_persistent_cache(path: str | None) -> str | None:
    """Point JAX's persistent compilation cache at ``path`` (None: leave the cache off).

    Every program that took :data:`MIN_COMPILE_S` or longer to compile is cached (unless
    ``JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS`` is set), within :data:`DEFAULT_MAX_BYTES` (unless
    ``JAX_COMPILATION_CACHE_MAX_SIZE`` is set). A folder that cannot be created or written leaves
    the cache off with a one-line warning on stderr.

    Returns:
      the folder in use, or None.
    """
    if path is None:
        return None
    try:
        os.makedirs(path, exist_ok=True)
        if not os.access(path, os.W_OK | os.X_OK):
            raise PermissionError("not writable")
    except OSError as e:
        import sys

        print(f"warning: compile cache {path!r} unusable ({getattr(e, 'strerror', None) or e}); "
              "compiling without it (--compile-cache DIR or --no-compile-cache)", file=sys.stderr)  # fmt: skip
        return None
    jax.config.update("jax_compilation_cache_dir", path)
    if "JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS" not in os.environ:
        jax.config.update("jax_persistent_cache_min_compile_time_secs", MIN_COMPILE_S)
    if "JAX_PERSISTENT_CACHE_MIN_ENTRY_SIZE_BYTES" not in os.environ:
        jax.config.update("jax_persistent_cache_min_entry_size_bytes", 0)
    if "JAX_COMPILATION_CACHE_MAX_SIZE" not in os.environ:
        jax.config.update("jax_compilation_cache_max_size", DEFAULT_MAX_BYTES)
    return path


