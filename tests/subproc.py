"""Environment for the JAX subprocesses that tests start.

A GPU machine pre-allocates most of each GPU's memory to the first JAX process (the test
session), so a second process on the same GPU fails to start; subprocesses therefore run on the
CPU (``JAX_PLATFORMS=cpu``), with ``devices`` fake CPU devices when asked.
"""

from __future__ import annotations

import os

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


def cpu_env(devices: int | None = None, **extra: str) -> dict[str, str]:
    """``os.environ`` for a CPU-pinned JAX subprocess that can import this repository.

    Args:
      devices: if given, ``--xla_force_host_platform_device_count=devices`` is added to ``XLA_FLAGS``.
      extra: further variables (override the inherited ones).
    """
    env = dict(os.environ)
    env["JAX_PLATFORMS"] = "cpu"
    env["PYTHONPATH"] = ROOT + os.pathsep + env.get("PYTHONPATH", "")
    if devices is not None:
        flags = [f for f in env.get("XLA_FLAGS", "").split() if "xla_force_host_platform_device_count" not in f]
        env["XLA_FLAGS"] = " ".join(flags + [f"--xla_force_host_platform_device_count={devices}"])
    env.update(extra)
    return env
