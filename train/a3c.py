"""Train A3C, reproduced deterministically: ``python -m train.a3c --env arm7 --reward ordinary|path``.

Workers are groups of lanes with their own parameter snapshots; their gradients are pushed to
the global network one after another and each worker re-syncs after its own push, so the
gradient delay of real asynchronous training is reproduced exactly and measured (staleness).
Flags, presets, run directory and figures as ``python -m train.a2c`` (see ``train/a2c.py``).
"""

from __future__ import annotations

from train.a2c import CLIS
from train.a2c import main as _main

__all__ = ["CLI", "main"]

CLI = CLIS["a3c"]
"""``python -m train.a3c``: A3C's :class:`~train.cli.AlgorithmCLI` (``train/a2c.py``)."""


def main(argv: list[str] | None = None) -> int:
    """Entry point; returns the process exit code."""
    return _main(argv, algo="a3c")


if __name__ == "__main__":
    from train.cli import exit_process

    exit_process(main())
