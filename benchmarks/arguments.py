"""Argument types of the benchmarks' command lines: counts checked as they are parsed.

    p.add_argument("--repeats", type=positive, default=3)

A value out of range stops the command before anything runs, with argparse's usage line and
``error: argument --repeats: 0 is out of range; allowed >= 1`` (exit code 2).
"""

from __future__ import annotations

import argparse
from collections.abc import Callable

__all__ = ["at_least", "nonnegative", "positive"]


def at_least(minimum: int) -> Callable[[str], int]:
    """An argparse ``type``: an integer ``>= minimum`` (anything else is an argparse error naming the range)."""

    def count(text: str) -> int:
        try:
            value = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"{text!r} is not an integer") from None
        if value < minimum:
            raise argparse.ArgumentTypeError(f"{value} is out of range; allowed >= {minimum}")
        return value

    count.__name__ = f"integer >= {minimum}"
    return count


positive = at_least(1)
"""An integer ``>= 1``: a count where 0 would mean nothing (seeds, repeats, lanes, steps)."""
nonnegative = at_least(0)
"""An integer ``>= 0``: a seed or key, or a count whose 0 means a default."""
