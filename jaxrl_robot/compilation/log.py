"""A record of what this process compiled: :class:`CompileLog`, from ``jax.monitoring``'s events and
:class:`~jaxrl_robot.compilation.ProgramCache`'s lookups; :func:`compile_log` is the process's one."""

from __future__ import annotations

import threading
from dataclasses import dataclass, field
from typing import Any

import jax

__all__ = ["CompileLog", "compile_log"]

_BACKEND = "/jax/core/compile/backend_compile_duration"
_TRACE = "/jax/core/compile/jaxpr_trace_duration"
_LOWER = "/jax/core/compile/jaxpr_to_mlir_module_duration"
_REQUESTS = "/jax/compilation_cache/compile_requests_use_cache"
_HITS = "/jax/compilation_cache/cache_hits"


@dataclass
class _Counts:
    loaded: int = 0
    built: int = 0
    load_s: float = 0.0
    unsaved: int = 0
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

    def program(self, loaded: bool, seconds: float, saved: bool = True) -> None:
        """Record one :class:`ProgramCache` lookup: ``loaded`` from the folder (taking ``seconds``) or
        built (traced, lowered, compiled) and ``saved`` there or not."""
        with self._lock:
            if loaded:
                self._c.loaded += 1
                self._c.load_s += seconds
            else:
                self._c.built += 1
                self._c.unsaved += not saved

    def mark(self) -> tuple:
        """A point to measure from (:meth:`since`)."""
        with self._lock:
            c = self._c
            return (c.programs, c.requests, c.hits, c.backend_s, c.trace_s, c.lower_s, c.loaded, c.built,
                    c.load_s, c.unsaved)  # fmt: skip

    def since(self, mark: tuple | None = None) -> dict[str, Any]:
        """What was compiled after ``mark`` (None: since the log began).

        Returns:
          ``programs`` (XLA compilations, cached ones included), ``compile_s`` (their seconds, cache
          retrievals included), ``trace_s`` and ``lower_s`` (tracing to jaxprs and lowering to MLIR),
          ``cache_requests``, ``cache_hits`` and ``cache_misses`` (programs looked up in the
          persistent cache, found, not found), ``cache_dir`` (None: off), ``slowest``: the
          :data:`SLOWEST` longest compilations as ``{"name", "s"}``, and ``program_cache``: the
          whole programs :class:`ProgramCache` ``loaded`` (in ``load_s`` seconds, nothing traced) and
          ``built``, of which ``unsaved`` could not be kept.
        """
        p0, r0, h0, b0, t0, l0, n0, m0, s0, u0 = mark or (0, 0, 0, 0.0, 0.0, 0.0, 0, 0, 0.0, 0)
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
                "program_cache": {
                    "loaded": c.loaded - n0, "built": c.built - m0, "load_s": round(c.load_s - s0, 3),
                    "unsaved": c.unsaved - u0,
                },
            }  # fmt: skip


_LOG: CompileLog | None = None
_LOG_LOCK = threading.Lock()


def compile_log() -> CompileLog:
    """The process's :class:`CompileLog` (created, and its listeners registered, on first use)."""
    global _LOG
    with _LOG_LOCK:
        if _LOG is None:
            _LOG = CompileLog()
        return _LOG
