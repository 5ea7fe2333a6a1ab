"""Keeping MJX fast on XLA:CPU.

On the CPU, XLA's algebraic simplifier (the HLO pass ``algsimp``) rewrites MJX's many small
quaternion and matrix products into element-wise arithmetic, which the CPU fusion emitters then
fuse into loop nests that recompute each link's transform for every element that uses it: the
cost of ``mjx.kinematics`` grows about tenfold per link of a serial chain.  For this package's
7-link arm ``mjx.kinematics`` ran ~160 calls/s at 256 lanes with XLA's defaults and ~1.1 M/s with
the pass disabled; stepping the arm with MJX (10 substeps per control step, 64 lanes) ran 6 control
steps/s and ~9,800 (``benchmarks/results/cpu-2core-env_throughput.md``), while a 2 x 256 MLP Adam
update ran at 159 and 201 updates/s.  GPUs are not affected.  The pass cannot be disabled more
narrowly, and the one other option that helped, ``xla_cpu_use_fusion_emitters=false``, fixes
kinematics but compiles ``mjx.step`` 2-3x slower and runs it at half the speed.

What this package does about it:

1. Kinematics and inverse kinematics are written in plain JAX (``envs_mjx/ik.py``), which XLA
   compiles well with any flags, so ``arm7``'s ``kinematic`` mode is fast everywhere.
2. MJX physics (``arm7``'s ``pd`` mode) needs the pass disabled on the CPU:

   * :func:`configure` runs when ``envs_mjx`` is imported.  On a host with no accelerator plugin
     (or with ``JAX_PLATFORMS=cpu``) whose JAX backend has not started yet, it appends
     ``--xla_disable_hlo_passes=algsimp`` to ``XLA_FLAGS`` (read once, when the first JAX
     computation initialises the backend).  Set ``ENVS_MJX_XLA_CPU_FIX=0`` to leave XLA alone.
   * :func:`compiler_options` / :func:`jit` apply the same setting to one computation
     (``jax.jit(f, compiler_options=...)``), which works after the backend has started and only
     on the CPU backend; use them when ``envs_mjx`` could not be imported first.
"""

from __future__ import annotations

import contextlib
import importlib.util
import io
import os
import pkgutil
import sys
from collections.abc import Callable
from typing import Any

import jax

__all__ = ["CPU_FLAG", "OPT_OUT_ENV", "compiler_options", "configure", "flag_active", "import_mjx_quietly", "jit"]

CPU_FLAG = "--xla_disable_hlo_passes=algsimp"
OPT_OUT_ENV = "ENVS_MJX_XLA_CPU_FIX"
_OPTIONS = {"xla_disable_hlo_passes": "algsimp"}


def _backends_started() -> bool:
    try:
        from jax._src import xla_bridge

        return bool(xla_bridge.backends_are_initialized())
    except Exception:  # an unknown JAX layout: assume started, never touch XLA_FLAGS late
        return True


def _accelerator_possible() -> bool:
    """Whether JAX may pick a GPU/TPU: a platform other than cpu requested, or a plugin installed."""
    platforms = os.environ.get("JAX_PLATFORMS", "") or str(jax.config.jax_platforms or "")
    if platforms:
        return platforms.split(",")[0].strip().lower() != "cpu"
    try:
        import jax_plugins

        if any(True for _ in pkgutil.iter_modules(jax_plugins.__path__)):
            return True
    except ImportError:
        pass
    return importlib.util.find_spec("libtpu") is not None


def configure() -> bool:
    """Disable ``algsimp`` for the CPU backend if it is safe and not too late; True if this call set it."""
    if os.environ.get(OPT_OUT_ENV, "1").strip() == "0":
        return False
    flags = os.environ.get("XLA_FLAGS", "")
    if "xla_disable_hlo_passes" in flags or _backends_started() or _accelerator_possible():
        return False
    os.environ["XLA_FLAGS"] = f"{flags} {CPU_FLAG}".strip()
    return True


def flag_active() -> bool:
    """Whether ``XLA_FLAGS`` disables ``algsimp`` (meaningful once the backend has started)."""
    flags = os.environ.get("XLA_FLAGS", "")
    return "xla_disable_hlo_passes" in flags and "algsimp" in flags


def compiler_options(backend: str | None = None) -> dict[str, Any]:
    """Per-computation XLA options that keep MJX fast: ``{"xla_disable_hlo_passes": "algsimp"}`` on
    the CPU backend (``backend`` or JAX's default), ``{}`` elsewhere."""
    backend = backend or jax.default_backend()
    return dict(_OPTIONS) if backend == "cpu" else {}


def jit(fun: Callable, **kwargs: Any) -> Callable:
    """``jax.jit(fun, **kwargs)`` with :func:`compiler_options` merged in (CPU only)."""
    options = {**compiler_options(), **kwargs.pop("compiler_options", {})}
    return jax.jit(fun, compiler_options=options or None, **kwargs)


_WARP_PROBE_LINES = ("Failed to import warp:", "Failed to import mujoco_warp:")


WARP_ENV = "JAXRL_ROBOT_WARP"
"""Environment variable: ``off`` imports MJX without MuJoCo Warp (its import costs 3–8 s of start-up), so that
``impl=warp`` is unavailable in the process; anything else (the default) imports Warp when it is installed.
``python -m train.<algo>`` sets it to ``off`` for a command that does not ask for Warp (``train/__init__.py``)."""


def warp_skipped() -> bool:
    """Whether this process imports MJX without MuJoCo Warp (:data:`WARP_ENV`)."""
    return os.environ.get(WARP_ENV, "").strip().lower() in ("off", "0", "no", "false")


def import_mjx_quietly() -> None:
    """Import ``mujoco.mjx`` without the lines its optional Warp backend prints when Warp is absent.

    ``mujoco.mjx.warp`` probes for the ``warp`` package at import and *prints* (not logs)
    ``Failed to import warp: ...`` and ``Failed to import mujoco_warp: ...`` when it is not
    installed; MJX's JAX backend, the default, does not need it. Only those two lines are dropped;
    anything else printed during the import is passed on, and an import error is raised as usual.
    With :func:`warp_skipped`, Warp is left out as if it were not installed. Does nothing if
    ``mujoco.mjx`` is already imported.
    """
    if "mujoco.mjx" in sys.modules:
        return
    buf = io.StringIO()
    blocked = warp_skipped() and "warp" not in sys.modules
    try:
        if blocked:
            sys.modules["warp"] = None  # type: ignore[assignment]  # an import of it fails as if absent
        with contextlib.redirect_stdout(buf):
            import mujoco.mjx  # noqa: F401
    finally:
        if blocked:
            del sys.modules["warp"]
        kept = [line for line in buf.getvalue().splitlines(True) if not line.startswith(_WARP_PROBE_LINES)]
        sys.stdout.write("".join(kept))
