"""Environment for the JAX subprocesses that tests start.

A GPU machine pre-allocates most of each GPU's memory to the first JAX process (the test
session), so a second process on the same GPU fails to start; subprocesses therefore run on the
CPU (``JAX_PLATFORMS=cpu``), with ``devices`` fake CPU devices when asked.
"""

from __future__ import annotations

import contextlib
import os
from collections.abc import Iterator

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def cpu_env(devices: int | None = None, **extra: str) -> dict[str, str]:
    """``os.environ`` for a CPU-pinned JAX subprocess that can import this repository.

    Args:
      devices: if given, ``--xla_force_host_platform_device_count=devices`` is added to ``XLA_FLAGS``.
      extra: further variables (override the inherited ones; ``JAXRL_ROBOT_WARP="on"`` for a process that
        needs MuJoCo Warp, which is otherwise left out).
    """
    env = dict(os.environ)
    env["JAX_PLATFORMS"] = "cpu"
    env.setdefault("JAXRL_ROBOT_WARP", "off")  # MJX without MuJoCo Warp: seconds less per start (envs_mjx.xla)
    env["PYTHONPATH"] = ROOT + os.pathsep + env.get("PYTHONPATH", "")
    if devices is not None:
        flags = [f for f in env.get("XLA_FLAGS", "").split() if "xla_force_host_platform_device_count" not in f]
        env["XLA_FLAGS"] = " ".join(flags + [f"--xla_force_host_platform_device_count={devices}"])
    env.update(extra)
    return env


MIN_COMPILE_TIME = "JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS"


@contextlib.contextmanager
def cache_every_program() -> Iterator[None]:
    """Inside: every program this process compiles goes to the session's persistent compilation cache
    (``tests/conftest.py`` keeps only those that took a second), and so does every program of the
    subprocesses started here (they inherit the variable); a subprocess that compiles a program this
    process (or an earlier subprocess) compiled loads the same executable instead of compiling it again.
    """
    import jax

    before_env, before = os.environ.get(MIN_COMPILE_TIME), jax.config.jax_persistent_cache_min_compile_time_secs
    os.environ[MIN_COMPILE_TIME] = "0"
    jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.0)
    try:
        yield
    finally:
        jax.config.update("jax_persistent_cache_min_compile_time_secs", before)
        if before_env is None:
            os.environ.pop(MIN_COMPILE_TIME, None)
        else:
            os.environ[MIN_COMPILE_TIME] = before_env
