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

The cache must be enabled before the process's first compilation (JAX opens it once).
"""

from __future__ import annotations

import contextlib
import functools
import hashlib
import json
import os
import pickle
import re
import sys
import threading
import time
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from importlib import metadata
from typing import Any

import jax

__all__ = [
    "CACHE_ENV",
    "CompileLog",
    "ProgramCache",
    "code_fingerprint",
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

PROGRAMS = "programs"
"""Subfolder of the cache folder holding :class:`ProgramCache`'s executables."""

PROGRAMS_MAX_BYTES = 4 << 30
"""Size limit of the programs folder: the least recently used executables go first beyond it."""

FINGERPRINTED = ("jaxrl_robot", "envs_mjx", "train")
"""Packages whose files (code, models, assets) are part of every :class:`ProgramCache` key."""

VERSIONED = ("jax", "jaxlib", "mujoco", "mujoco-mjx", "brax", "flax", "optax", "numpy", "playground", "warp-lang")
"""Installed distributions whose versions are part of every :class:`ProgramCache` key."""

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


# ---- whole programs ----------------------------------------------------------------------------
def _files_digest(root: str) -> str:
    """SHA-256 over the relative paths and contents of every file under ``root`` (bytecode caches apart)."""
    h = hashlib.sha256()
    for folder, dirs, files in sorted(os.walk(root)):
        dirs[:] = sorted(d for d in dirs if d != "__pycache__")
        for name in sorted(files):
            if name.endswith((".pyc", ".pyo")):
                continue
            path = os.path.join(folder, name)
            h.update(os.path.relpath(path, root).encode() + b"\0")
            with open(path, "rb") as f:
                h.update(f.read())
    return h.hexdigest()


@functools.cache
def code_fingerprint(packages: tuple[str, ...] = FINGERPRINTED) -> str:
    """A digest of the files of ``packages`` (those imported; others are left out): any edit of this
    project's code, models or assets changes it, and with it every :class:`ProgramCache` key."""
    import importlib.util

    h = hashlib.sha256()
    for name in packages:
        spec = importlib.util.find_spec(name)
        if spec is None or not spec.submodule_search_locations:
            continue
        for root in spec.submodule_search_locations:
            h.update(name.encode() + b":" + _files_digest(root).encode())
    return h.hexdigest()


def _version(name: str) -> str | None:
    try:
        return metadata.version(name)
    except metadata.PackageNotFoundError:
        return None


@functools.cache
def _process_context() -> str:
    """What besides the run decides a compiled program: versions, JAX's settings, XLA's flags, the devices."""
    settings = ("jax_enable_x64", "jax_default_matmul_precision", "jax_default_prng_impl", "jax_threefry_partitionable")
    return json.dumps({
        "code": code_fingerprint(),
        "versions": {n: _version(n) for n in VERSIONED},
        "python": sys.version.split()[0],
        "jax_config": {k: str(getattr(jax.config, k, None)) for k in settings},
        "env": {k: os.environ.get(k) for k in ("XLA_FLAGS", "LIBTPU_INIT_ARGS")},
        "devices": [(d.id, d.platform, d.device_kind, d.process_index) for d in jax.devices()],
    }, sort_keys=True)  # fmt: skip


def signature(args: Any) -> str:
    """The structure, shapes, dtypes and shardings of ``args``: the part of a call that picks its
    :class:`ProgramCache` program (weak types apart: those programs take and give plain arrays)."""

    def leaf(x: Any) -> str:
        sharding = getattr(x, "sharding", None)
        where = ""
        if sharding is not None:
            where = f"{sharding}@{sorted(d.id for d in sharding.device_set)}"
        return f"{getattr(x, 'shape', ())}:{getattr(x, 'dtype', type(x).__name__)}:{where}"

    leaves, tree = jax.tree.flatten(args)
    return _ADDRESS.sub("", str(tree)) + "|" + ";".join(leaf(x) for x in leaves)


_ADDRESS = re.compile(r" at 0x[0-9a-fA-F]+")
"""Object addresses in a tree's text (e.g. MJX's static contact tables print as ``<… object at 0x7f…>``)."""


def _call_key(args: Any) -> tuple:
    """A hashable key of ``args``'s structure, shapes, dtypes and shardings, as :func:`signature` but by
    value (a tree's static parts compare by content), for looking a program up within a process."""
    leaves, tree = jax.tree.flatten(args)
    return tree, tuple((getattr(x, "shape", ()), str(getattr(x, "dtype", type(x).__name__)),
                        getattr(x, "sharding", None)) for x in leaves)  # fmt: skip


class ProgramCache:
    """Traced and lowered programs kept on disk under ``folder`` (as ``jax.export`` modules), found again by a
    key of ``context`` (what built the function: a run's settings, as JSON-able data), this process's
    :func:`_process_context` (this project's files, the installed versions, JAX's settings, the devices), the
    program's name and its arguments' :func:`signature`.

    A program found there is not traced or lowered again: it is compiled from its module, and the module is
    the same in every process, so JAX's persistent cache (when on) returns XLA's executable of an earlier
    run. The key cannot see what the function closes over except through ``context``: use it only for
    functions that ``context`` determines (as the training CLIs' programs are determined by their
    ``config.json`` less the seed, which enters as an argument). A damaged file is removed and the program
    built again; a program ``jax.export`` cannot keep (host callbacks, custom calls without a stability
    guarantee) and a folder that cannot be written leave it unsaved (counted in :class:`CompileLog`).
    """

    SUFFIX = ".jaxexport"

    def __init__(self, folder: str, context: Mapping[str, Any], max_bytes: int = PROGRAMS_MAX_BYTES):
        self.folder = folder
        self.max_bytes = max_bytes
        self._context = hashlib.sha256((json.dumps(context, sort_keys=True, default=str) + "\0"
                                        + _process_context()).encode()).hexdigest()  # fmt: skip
        self._lock = threading.Lock()
        self._warned = False

    @staticmethod
    def under(cache_dir: str | None, context: Mapping[str, Any]) -> ProgramCache | None:
        """The cache in ``<cache_dir>/programs`` (None when ``cache_dir`` is None or in a run over several
        processes, whose programs are built by every process together)."""
        if cache_dir is None or jax.process_count() > 1:
            return None
        return ProgramCache(os.path.join(cache_dir, PROGRAMS), context)

    def path(self, name: str, args: tuple) -> str:
        """The file of program ``name`` called with ``args``."""
        key = hashlib.sha256(f"{self._context}|{name}|{signature(args)}".encode()).hexdigest()[:40]
        safe = "".join(c if c.isalnum() or c in "-_" else "_" for c in name)[:40]
        return os.path.join(self.folder, f"{safe}-{key}{self.SUFFIX}")

    def compile(self, name: str, fn: Callable, *args: Any) -> Callable:
        """``fn`` compiled for ``args``, as a function of arguments like ``args``: its module loaded from the
        folder when there, else traced and lowered (``jax.export``) and saved; then compiled."""
        path = self.path(name, args)
        leaves, in_tree = jax.tree.flatten(args)
        t0 = time.perf_counter()
        found = self._load(path)
        if found is not None:
            exported, out_tree = found
            compile_log().program(True, time.perf_counter() - t0)
        else:
            try:
                blob, out_tree = _export(fn, in_tree, leaves)
            except Exception as e:  # not exportable: compiled as jax.jit would, every time
                first = str(e).strip().splitlines()[0] if str(e).strip() else ""
                self._warn(f"program {name!r} is not kept between runs ({type(e).__name__}: {first})"[:300])
                compile_log().program(False, 0.0, saved=False)
                return jax.jit(fn).lower(*args).compile()
            compile_log().program(False, 0.0, self._save(path, blob, out_tree))
            exported = _deserialize(blob)  # the module a later run loads, so that both compile the same
        compiled = jax.jit(_named(exported.call, name)).lower(*leaves).compile()
        return lambda *a: jax.tree.unflatten(out_tree, compiled(*jax.tree.leaves(a)))

    def jit(self, name: str, fn: Callable) -> Callable:
        """A function like ``jax.jit(fn)`` whose program for each argument signature comes from
        :meth:`compile` (looked up once per signature in this process)."""
        programs: dict[tuple, Callable] = {}

        def call(*args: Any) -> Any:
            key = _call_key(args)
            program = programs.get(key)
            if program is None:
                program = programs[key] = self.compile(name, fn, *args)
            return program(*args)

        return call

    def _load(self, path: str) -> tuple[Any, Any] | None:
        """``(exported, out_tree)`` saved at ``path``; None when absent or unusable (then removed)."""
        if not os.path.exists(path):
            return None
        try:
            with open(path, "rb") as f:
                blob, out_tree = pickle.load(f)
            exported = _deserialize(blob)
            os.utime(path)  # recently used
            return exported, out_tree
        except Exception as e:  # damaged, or written by a build this key did not tell apart: build again
            self._warn(f"kept program {os.path.basename(path)} unusable ({type(e).__name__}); building it again")
            with contextlib.suppress(OSError):
                os.remove(path)
            return None

    def _save(self, path: str, blob: bytes, out_tree: Any) -> bool:
        try:
            blob = pickle.dumps((blob, out_tree))
            os.makedirs(self.folder, exist_ok=True)
            tmp = f"{path}.{os.getpid()}.{threading.get_ident()}.tmp"
            with open(tmp, "wb") as f:
                f.write(blob)
            os.replace(tmp, path)
        except (OSError, ValueError, TypeError, AttributeError, pickle.PicklingError) as e:
            self._warn(f"program {os.path.basename(path)} not kept ({type(e).__name__}: {e})"[:300])
            return False
        self._trim()
        return True

    def _trim(self) -> None:
        """Remove the least recently used programs beyond :attr:`max_bytes`."""
        with self._lock, contextlib.suppress(OSError):
            entries = []
            for name in os.listdir(self.folder):
                if name.endswith(self.SUFFIX):
                    st = os.stat(os.path.join(self.folder, name))
                    entries.append((st.st_mtime, st.st_size, name))
            total = sum(e[1] for e in entries)
            for _, size, name in sorted(entries):
                if total <= self.max_bytes:
                    break
                os.remove(os.path.join(self.folder, name))
                total -= size

    def _warn(self, message: str) -> None:
        if not self._warned:
            self._warned = True
            print(f"note: {message}", file=sys.stderr, flush=True)


def _named(fn: Callable, name: str) -> Callable:
    """``fn`` under the name ``name`` (how JAX names its program: ``jit(<name>)`` in :class:`CompileLog`)."""

    def program(*args: Any) -> Any:
        return fn(*args)

    program.__name__ = program.__qualname__ = name
    return program


def _export(fn: Callable, in_tree: Any, leaves: list) -> tuple[bytes, Any]:
    """``(jax.export's serialisation of fn over the flat leaves, fn's output tree)`` for arguments ``in_tree``
    / ``leaves`` of those shapes, dtypes and shardings. Weak types are left out (the serialisation has none):
    arguments are traced as, and results come back as, plain arrays of their dtypes, in every run alike."""
    out_trees = []

    def flat(*xs: Any) -> list:
        out, tree = jax.tree.flatten(fn(*jax.tree.unflatten(in_tree, xs)))
        out_trees.append(tree)
        return out

    def spec(x: Any) -> jax.ShapeDtypeStruct:
        return jax.ShapeDtypeStruct(tuple(getattr(x, "shape", ())), x.dtype, sharding=getattr(x, "sharding", None))

    exported = jax.export.export(jax.jit(flat))(*[spec(x) for x in leaves])
    return bytes(exported.serialize()), out_trees[-1]


def _deserialize(blob: bytes) -> Any:
    """The ``jax.export.Exported`` of an :func:`_export` serialisation."""
    return jax.export.deserialize(bytearray(blob))
