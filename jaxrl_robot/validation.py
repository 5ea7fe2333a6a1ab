"""Validation of configurations: :class:`ConfigError` and the checks every ``validate()`` is written with.

Each check raises :class:`ConfigError` with a one-line message that names the field and what is allowed
(``num_envs=0 is out of range; allowed [1, inf)``), so the command line can print it as it is.

>>> check_choice("her", "best", ("none", "final"))   # her='best' is not valid; choose one of 'none', 'final'
>>> check_range("tau", 0.0, 0.0, 1.0, lo_open=True)  # tau=0.0 is out of range; allowed (0, 1]
>>> check_counts(config, "num_envs", "batch_size")   # integers >= 1

The class and the range and choice checks are defined by the environments' configurations
(:mod:`envs_mjx.config`), which are validated the same way and cannot import this library; agents take
them from here.
"""

from __future__ import annotations

from collections.abc import Iterable
from typing import Any

from envs_mjx.config import ConfigError, check_choice, check_range, check_vector

__all__ = ["ConfigError", "check_choice", "check_counts", "check_each", "check_integer", "check_range", "check_vector"]


def check_integer(field: str, value: Any, lo: float | None = None) -> None:
    """Raise ``ConfigError`` unless ``value`` is an integer ``>= lo`` (a float with an integer value passes)."""
    check_range(field, value, lo)
    if int(value) != value:
        raise ConfigError(f"{field}={value!r} must be an integer")


def check_counts(config: Any, *names: str) -> None:
    """Raise ``ConfigError`` unless each field of ``config`` in ``names`` is an integer ``>= 1``."""
    for name in names:
        check_integer(name, getattr(config, name), 1)


def check_each(field: str, values: Iterable[Any], lo: float | None = None, hi: float | None = None, *,
               lo_open: bool = False, hi_open: bool = False) -> None:  # fmt: skip
    """:func:`check_range` of every element of a sequence field, named ``field[i]``."""
    for i, v in enumerate(values):
        check_range(f"{field}[{i}]", v, lo, hi, lo_open=lo_open, hi_open=hi_open)
