"""Whole programs kept between processes: :class:`ProgramCache` keeps a traced and lowered program as a
``jax.export`` module under a key of the run's settings, this project's files (:func:`code_fingerprint`), the
installed versions, JAX's settings, the devices and the arguments' :func:`signature`, so that a later process
compiles it without tracing or lowering it again."""

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
from concurrent.futures import Future, ThreadPoolExecutor
from importlib import metadata
from typing import Any

import jax

from jaxrl_robot import parallel
from jaxrl_robot.compilation.log import compile_log

__all__ = [
    "FINGERPRINTED", "PROGRAMS", "VERSIONED", "CachedJit", "ProgramCache", "code_fingerprint", "in_thread", "signature",
]  # fmt: skip

PROGRAMS = "programs"
"""Subfolder of the cache folder holding :class:`ProgramCache`'s executables."""

PROGRAMS_MAX_BYTES = 4 << 30
"""Size limit of the programs folder: the least recently used executables go first beyond it."""

FINGERPRINTED = ("jaxrl_robot", "envs_mjx", "train")
"""Packages whose files (code, models, assets) are part of every :class:`ProgramCache` key."""

VERSIONED = ("jax", "jaxlib", "mujoco", "mujoco-mjx", "brax", "flax", "optax", "numpy", "playground", "warp-lang")
"""Installed distributions whose versions are part of every :class:`ProgramCache` key."""


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
    """What besides the run decides a compiled program: versions, JAX's settings, XLA's flags, the lane map's
    variable (``JAXRL_LANE_MAP``: the same run builds another program under another lane map), the devices."""
    settings = ("jax_enable_x64", "jax_default_matmul_precision", "jax_default_prng_impl", "jax_threefry_partitionable")
    return json.dumps({
        "code": code_fingerprint(),
        "versions": {n: _version(n) for n in VERSIONED},
        "python": sys.version.split()[0],
        "jax_config": {k: str(getattr(jax.config, k, None)) for k in settings},
        "env": {k: os.environ.get(k) for k in ("XLA_FLAGS", "LIBTPU_INIT_ARGS", parallel.IMPL_ENV)},
        "devices": parallel.device_summary(),
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
        place = _placer(exported.nr_devices)
        compiled = jax.jit(_named(exported.call, name)).lower(*place(leaves)).compile()
        return lambda *a: jax.tree.unflatten(out_tree, compiled(*place(jax.tree.leaves(a))))

    def jit(self, name: str, fn: Callable) -> CachedJit:
        """A function like ``jax.jit(fn)`` whose program for each argument signature comes from
        :meth:`compile` (looked up once per signature in this process; :meth:`CachedJit.compile_ahead`
        starts one in a thread before the arguments exist)."""
        return CachedJit(self, name, fn)

    def has(self, name: str, *args: Any) -> bool:
        """Whether program ``name`` for ``args`` is kept in the folder (a later :meth:`compile` loads it)."""
        return os.path.exists(self.path(name, args))

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


class CachedJit:
    """``ProgramCache.jit(name, fn)``: called like ``jax.jit(fn)``, its program per argument signature from
    :meth:`ProgramCache.compile`; :meth:`compile_ahead` builds one in a thread for arguments described by
    ``jax.ShapeDtypeStruct`` leaves (their shardings included), so that its tracing, lowering and XLA
    compilation overlap other work, e.g. another program's compilation (XLA compiles one program on one
    core). A call whose arguments match waits for that build; a build that failed is retried in line."""

    def __init__(self, cache: ProgramCache, name: str, fn: Callable):
        self.cache, self.name, self.fn = cache, name, fn
        self._programs: dict[tuple, Callable | Future] = {}

    def compile_ahead(self, *abstract_args: Any) -> Future:
        """Start building the program for arguments like ``abstract_args`` in a thread (:func:`in_thread`)."""
        future = in_thread(f"compile-{self.name}", self.cache.compile, self.name, self.fn, *abstract_args)
        self._programs[_call_key(abstract_args)] = future
        return future

    def __call__(self, *args: Any) -> Any:
        key = _call_key(args)
        program = self._programs.get(key)
        if isinstance(program, Future):
            try:
                program = program.result()
            except Exception as e:  # built again below, in line
                print(f"note: compiling {self.name!r} ahead failed ({type(e).__name__}: {e}); compiling it now"[:300],
                      file=sys.stderr, flush=True)  # fmt: skip
                program = None
        if program is None:
            program = self.cache.compile(self.name, self.fn, *args)
        self._programs[key] = program
        return program(*args)


def in_thread(name: str, fn: Callable, *args: Any) -> Future:
    """``fn(*args)`` started in a thread of its own named ``name`` (XLA compiles while the caller goes on); the
    future of its result. The thread is not waited for here; the interpreter joins it at exit."""
    executor = ThreadPoolExecutor(max_workers=1, thread_name_prefix=name)
    future = executor.submit(fn, *args)
    executor.shutdown(wait=False)
    return future


def _named(fn: Callable, name: str) -> Callable:
    """``fn`` under the name ``name`` (how JAX names its program: ``jit(<name>)`` in :class:`CompileLog`)."""

    def program(*args: Any) -> Any:
        return fn(*args)

    program.__name__ = program.__qualname__ = name
    return program


def _export(fn: Callable, in_tree: Any, leaves: list) -> tuple[bytes, Any]:
    """``(jax.export's serialisation of fn over the flat leaves, fn's output tree)`` for arguments ``in_tree``
    / ``leaves`` of those shapes, dtypes and shardings (an uncommitted array's placement left open:
    :func:`_placer`). Weak types are left out (the serialisation has none): arguments are traced as, and results
    come back as, plain arrays of their dtypes, in every run alike."""
    out_trees = []

    def flat(*xs: Any) -> list:
        out, tree = jax.tree.flatten(fn(*jax.tree.unflatten(in_tree, xs)))
        out_trees.append(tree)
        return out

    def spec(x: Any) -> jax.ShapeDtypeStruct:
        sharding = getattr(x, "sharding", None) if _committed(x) else None  # see _placer
        return jax.ShapeDtypeStruct(tuple(getattr(x, "shape", ())), x.dtype, sharding=sharding)

    exported = jax.export.export(jax.jit(flat))(*[spec(x) for x in leaves])
    return bytes(exported.serialize()), out_trees[-1]


def _committed(x: Any) -> bool:
    return bool(getattr(x, "committed", True))


def _placer(devices: int) -> Callable[[list], list]:
    """``leaves -> leaves`` with each uncommitted array (a key made by ``jax.random.PRNGKey``, say) replicated over
    the lane mesh of a program over ``devices`` devices: ``jax.jit`` would put it there, while its default device
    alone would not match such a program (exported with that argument's placement open, :func:`_export`). One
    device: the leaves as they are."""
    if devices <= 1:
        return lambda leaves: leaves
    replicated = parallel.lane_sharding(parallel.lane_mesh(devices), split=False)
    return lambda leaves: [x if _committed(x) else jax.device_put(x, replicated) for x in leaves]


def _deserialize(blob: bytes) -> Any:
    """The ``jax.export.Exported`` of an :func:`_export` serialisation."""
    return jax.export.deserialize(bytearray(blob))
