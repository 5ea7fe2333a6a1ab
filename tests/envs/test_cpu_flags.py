"""envs_mjx's XLA:CPU settings: set only where they are safe, and on import on a CPU-only host."""

import os
import subprocess
import sys

from envs_mjx import xla


def test_cpu_fix_sets_xla_flags_only_when_it_is_safe(monkeypatch):
    for var in ("XLA_FLAGS", xla.OPT_OUT_ENV, "JAX_PLATFORMS"):
        monkeypatch.delenv(var, raising=False)
    monkeypatch.setattr(xla, "_backends_started", lambda: False)
    monkeypatch.setattr(xla, "_accelerator_possible", lambda: False)
    assert xla.configure() and os.environ["XLA_FLAGS"] == xla.CPU_FLAG
    assert not xla.configure() and os.environ["XLA_FLAGS"] == xla.CPU_FLAG  # not added twice
    monkeypatch.setenv("XLA_FLAGS", "--xla_cpu_enable_fast_math=false")
    assert xla.configure() and os.environ["XLA_FLAGS"] == "--xla_cpu_enable_fast_math=false " + xla.CPU_FLAG
    monkeypatch.setenv("XLA_FLAGS", "")
    monkeypatch.setenv(xla.OPT_OUT_ENV, "0")  # the user opted out
    assert not xla.configure() and os.environ["XLA_FLAGS"] == ""
    monkeypatch.delenv(xla.OPT_OUT_ENV)
    monkeypatch.setattr(xla, "_accelerator_possible", lambda: True)  # a GPU may be used: leave XLA alone
    assert not xla.configure() and os.environ["XLA_FLAGS"] == ""
    monkeypatch.setattr(xla, "_accelerator_possible", lambda: False)
    monkeypatch.setattr(xla, "_backends_started", lambda: True)  # too late to take effect
    assert not xla.configure() and os.environ["XLA_FLAGS"] == ""
    assert xla.compiler_options("cpu") == {"xla_disable_hlo_passes": "algsimp"}
    assert xla.compiler_options("gpu") == {}


def test_importing_envs_mjx_disables_algsimp_on_a_cpu_only_host():
    env = {k: v for k, v in os.environ.items() if k not in ("XLA_FLAGS", xla.OPT_OUT_ENV, "JAX_PLATFORMS")}
    env["XLA_PYTHON_CLIENT_PREALLOCATE"] = "false"  # on a GPU machine this process shares the GPU
    code = "import os, envs_mjx, jax; jax.numpy.ones(1); print(os.environ.get('XLA_FLAGS'))"
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, check=True)
    expected = "None" if xla._accelerator_possible() else xla.CPU_FLAG
    assert out.stdout.strip().splitlines()[-1] == expected
