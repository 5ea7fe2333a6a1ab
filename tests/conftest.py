"""Shared test set-up.

The suite runs in two pytest-xdist workers (``addopts`` in ``pyproject.toml``). On a GPU machine
each worker allocates device memory as it needs it instead of taking most of it up front, so
the two share the GPU.

``envs_mjx`` is imported before any test module so that its XLA:CPU setting (see
``envs_mjx/xla.py``) is in place before the first JAX computation of the session, whatever
order the test modules are collected in.
"""

import os

os.environ.setdefault("XLA_PYTHON_CLIENT_PREALLOCATE", "false")

import envs_mjx  # noqa: E402, F401
