"""Shared test set-up.

The suite runs in two pytest-xdist workers (``addopts`` in ``pyproject.toml``; ``--dist worksteal``:
each starts on its half of the tests, in file order, and one that runs out takes tests the other has
not started, so a file's module fixtures are mostly built once and neither waits long). On a GPU machine
each worker allocates device memory as it needs it instead of taking most of it up front, so
the two share the GPU.

Compiled programs go to a persistent compilation cache shared by the workers and by the
processes the tests start (``JAX_COMPILATION_CACHE_DIR``, a fresh folder per session unless set):
many tests compile the same training programs, in-process and in subprocesses, and XLA:CPU
compilation is most of their time.  A cached program is the same executable, so no result changes;
the cache's size limit makes JAX lock the folder (``filelock``) while workers write it.

On a host without a GPU (no ``nvidia-smi``), or with ``JAX_PLATFORMS=cpu``, XLA:CPU compiles at LLVM
optimisation level 0 (``--xla_backend_optimization_level=0`` in ``XLA_FLAGS``, inherited by the
processes the tests start): the tests' programs are small and run briefly, so compiling them is
most of their time (the whole suite, 345 tests on 2 cores: 840 s against 1 072 s).  The level can change the last
bits of a float result (arm7 stepped 50 times from 100 starts: observations summing to 188.325256 at the default
level, 188.325287 at level 0): the tests' oracles are worked by hand or computed under the same flags (in the test's
process, or in a subprocess, which inherits ``XLA_FLAGS``).  A level already in
``XLA_FLAGS`` is kept.  For the same reason the CPU's older fusion code generator is used
(``--xla_cpu_use_fusion_emitters=false``, unless ``XLA_FLAGS`` names that option): at level 0 it
compiles the tests' programs in about half the time (a DDPG update on the toy env: 3.9 s of CPU
against 9.0 s; ``arm7``'s MJX step: 11 s against 21 s) and they run as fast; it too changes only
how the code is compiled (the note in ``envs_mjx/xla.py`` on this option is about the default level).
Each program's machine code is generated in one piece (``--xla_cpu_parallel_codegen_split_count=1``): the
workers already keep both cores busy, and splitting it for threads cost ``tests/agents/test_ppo.py`` 76-78 s
of CPU against 70-72 s.  MuJoCo Warp's CPU kernels, which the Warp tests compile on a fresh machine, are
built at ``-O0`` for the same reason (``warp.config.optimization_level``; the Warp tests' CPU 124 s -> 98 s on
a fresh kernel cache).

``envs_mjx`` is imported before any test module so that its XLA:CPU setting (see
``envs_mjx/xla.py``) is in place before the first JAX computation of the session, whatever
order the test modules are collected in.
"""

import os
import shutil
import sys
import tempfile

os.environ.setdefault("XLA_PYTHON_CLIENT_PREALLOCATE", "false")
if "JAX_COMPILATION_CACHE_DIR" not in os.environ:  # set once by the session's first process, inherited after
    os.environ["JAX_COMPILATION_CACHE_DIR"] = tempfile.mkdtemp(prefix="jaxrl-robot-test-xla-cache-")
    os.environ.setdefault("JAX_COMPILATION_CACHE_MAX_SIZE", str(4 << 30))
    # JAX's own threshold (the CLI's is lower): only programs that took a second to compile are cached, so
    # the folder stays small and the size limit's scan of it on every write stays cheap
    os.environ.setdefault("JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS", "1")
_flags = os.environ.get("XLA_FLAGS", "")
_cpu_only = os.environ.get("JAX_PLATFORMS") == "cpu" or shutil.which("nvidia-smi") is None
if _cpu_only and "xla_backend_optimization_level" not in _flags:
    os.environ["XLA_FLAGS"] = (_flags + " --xla_backend_optimization_level=0").strip()
    if "xla_cpu_use_fusion_emitters" not in _flags:
        os.environ["XLA_FLAGS"] += " --xla_cpu_use_fusion_emitters=false"
    if "xla_cpu_parallel_codegen_split_count" not in _flags:
        os.environ["XLA_FLAGS"] += " --xla_cpu_parallel_codegen_split_count=1"

import envs_mjx  # noqa: E402, F401

if _cpu_only and "warp" in sys.modules:  # MuJoCo Warp's CPU kernels at -O0: 98 s of the Warp tests' CPU against 124 s
    sys.modules["warp"].config.optimization_level = 0
