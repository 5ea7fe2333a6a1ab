"""Environment configuration: frozen dataclasses with validated overrides.

Every environment has a ``Config`` dataclass whose defaults are the thesis's values.
``apply_overrides`` builds a new config from keyword overrides, rejecting unknown
fields with the list of valid ones; ``check_choice`` / ``check_range`` give errors
that name the field and what is allowed.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Iterable, Mapping
from typing import Any, TypeVar

C = TypeVar("C")


class ConfigError(ValueError):
    """An invalid configuration value; the message names the field and the allowed values."""


def check_choice(field: str, value: Any, choices: Iterable[Any]) -> None:
    """Raise ``ConfigError`` unless ``value`` is one of ``choices``."""
    choices = tuple(choices)
    if value not in choices:
        raise ConfigError(f"{field}={value!r} is not valid; choose one of {', '.join(map(repr, choices))}")


def check_range(
    field: str,
    value: float,
    lo: float | None = None,
    hi: float | None = None,
    *,
    lo_open: bool = False,
    hi_open: bool = False,
) -> None:
    """Raise ``ConfigError`` unless ``lo <= value <= hi`` (bounds optional, openness selectable)."""
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise ConfigError(f"{field}={value!r} must be a number") from None
    bad = v != v  # NaN
    if lo is not None:
        bad |= v <= lo if lo_open else v < lo
    if hi is not None:
        bad |= v >= hi if hi_open else v > hi
    if bad:
        left = "(" if lo_open else "["
        right = ")" if hi_open else "]"
        lo_s = "-inf" if lo is None else f"{lo:g}"
        hi_s = "inf" if hi is None else f"{hi:g}"
        raise ConfigError(f"{field}={value!r} is out of range; allowed {left}{lo_s}, {hi_s}{right}")


def check_vector(field: str, value: Any, length: int, lo: float | None = None, hi: float | None = None) -> None:
    """Check a fixed-length numeric tuple, element-wise within ``[lo, hi]``."""
    try:
        n = len(value)
    except TypeError:
        raise ConfigError(f"{field}={value!r} must be a sequence of {length} numbers") from None
    if n != length:
        raise ConfigError(f"{field}={value!r} must have {length} elements, got {n}")
    for i, v in enumerate(value):
        check_range(f"{field}[{i}]", v, lo, hi)


def apply_overrides(config: C, overrides: Mapping[str, Any], owner: str = "config") -> C:
    """Return ``config`` with ``overrides`` applied (the original is not modified).

    Raises ``ConfigError`` naming the unknown field and listing the valid fields.
    Lists given for tuple fields are converted to tuples so configs stay hashable.
    """
    fields = {f.name: f for f in dataclasses.fields(config)}
    clean = {}
    for name, value in overrides.items():
        if name not in fields:
            raise ConfigError(
                f"{owner}: unknown setting {name!r}; valid settings: {', '.join(sorted(fields))}"
            )
        if isinstance(value, list):
            value = tuple(value)
        clean[name] = value
    return dataclasses.replace(config, **clean)
