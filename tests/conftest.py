"""Shared test set-up.

``envs_mjx`` is imported before any test module so that its XLA:CPU setting (see
``envs_mjx/xla.py``) is in place before the first JAX computation of the session, whatever
order the test modules are collected in.
"""

import envs_mjx  # noqa: F401
