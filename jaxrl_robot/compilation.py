"""Compiling once: JAX's persistent compilation cache and a record of what a process compiled.

* :func:`resolve_cache_dir` / :func:`enable_persistent_cache` — where compiled programs are kept
  between processes (by default a per-user folder, ``$XDG_CACHE_HOME/jaxrl-robot/xla`` or
  ``~/.cache/jaxrl-robot/xla``), so that a second run of the same program skips XLA's compiler.
  A cached program is the executable XLA built before, so no result changes.
* :class:`CompileLog` — the count and seconds of every XLA compilation (or cache retrieval) and of
  tracing and lowering in this process, and the cache's hits and misses, from ``jax.monitoring``'s
  events; :meth:`CompileLog.since` gives what happened after a :meth:`CompileLog.mark`.

The cache must be enabled before the process's first compilation (JAX opens it once).
"""

from __future__ import annotations

import os
import threading
from dataclasses import dataclass, field
from typing import Any

import jax

__all__ = [
    "CACHE_ENV",
    "CompileLog",
    "compile_log",
    "default_cache_dir",
    "enable_persistent_cache",
    "resolve_cache_dir",
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

_BACKEND = "/jax/core/compile/backend_compile_duration"
_TRACE = "/jax/core/compile/jaxpr_trace_duration"
_LOWER = "/jax/core/compile/jaxpr_to_mlir_module_duration"
_REQUESTS = "/jax/compilation_cache/compile_requests_use_cache"
_HITS = "/jax/compilation_cache/cache_hits"


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


@dataclass
class _Counts:
    programs: int = 0
    backend_s: float = 0.0
    trace_s: float = 0.0
    lower_s: float = 0.0
    requests: int = 0
    hits: int = 0
    slowest: list[tuple[float, str]] = field(default_factory=list)


class CompileLog:
    """Counts of this process's compilations, from ``jax.monitoring`` listeners (registered once)."""

    SLOWEST = 8
    """How many of the slowest backend compilations :meth:`since` names."""

    def __init__(self) -> None:
        self._lock = threading.Lock()
        self._c = _Counts()
        jax.monitoring.register_event_duration_secs_listener(self._duration)
        jax.monitoring.register_event_listener(self._event)

    def _duration(self, event: str, duration: float, **kwargs: Any) -> None:
        with self._lock:
            if event == _BACKEND:
                self._c.programs += 1
                self._c.backend_s += duration
                self._c.slowest.append((duration, str(kwargs.get("fun_name", "?"))))
            elif event == _TRACE:
                self._c.trace_s += duration
            elif event == _LOWER:
                self._c.lower_s += duration

    def _event(self, event: str, **kwargs: Any) -> None:
        with self._lock:
            if event == _REQUESTS:
                self._c.requests += 1
            elif event == _HITS:
                self._c.hits += 1

    def mark(self) -> tuple[int, int, int, float, float, float]:
        """A point to measure from (:meth:`since`)."""
        with self._lock:
            c = self._c
            return (c.programs, c.requests, c.hits, c.backend_s, c.trace_s, c.lower_s)

    def since(self, mark: tuple[int, int, int, float, float, float] | None = None) -> dict[str, Any]:
        """What was compiled after ``mark`` (None: since the log began).

        Returns:
          ``programs`` (XLA compilations, cached ones included), ``compile_s`` (their seconds, cache
          retrievals included), ``trace_s`` and ``lower_s`` (tracing to jaxprs and lowering to MLIR),
          ``cache_requests``, ``cache_hits`` and ``cache_misses`` (programs looked up in the
          persistent cache, found, not found), ``cache_dir`` (None: off), and ``slowest``: the
          :data:`SLOWEST` longest compilations as ``{"name", "s"}``.
        """
        p0, r0, h0, b0, t0, l0 = mark or (0, 0, 0, 0.0, 0.0, 0.0)
        with self._lock:
            c = self._c
            slowest = sorted(c.slowest[p0:], reverse=True)[: self.SLOWEST]
            return {
                "programs": c.programs - p0,
                "compile_s": round(c.backend_s - b0, 3),
                "trace_s": round(c.trace_s - t0, 3),
                "lower_s": round(c.lower_s - l0, 3),
                "cache_requests": c.requests - r0,
                "cache_hits": c.hits - h0,
                "cache_misses": (c.requests - r0) - (c.hits - h0),
                "cache_dir": jax.config.jax_compilation_cache_dir,
                "slowest": [{"name": name, "s": round(s, 3)} for s, name in slowest],
            }


_LOG: CompileLog | None = None
_LOG_LOCK = threading.Lock()


def compile_log() -> CompileLog:
    """The process's :class:`CompileLog` (created, and its listeners registered, on first use)."""
    global _LOG
    with _LOG_LOCK:
        if _LOG is None:
            _LOG = CompileLog()
        return _LOG
