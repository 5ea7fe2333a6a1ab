"""Metrics to CSV (one row per report) and TensorBoard (tensorboardX)."""

from __future__ import annotations

import csv
import math
import os
from collections.abc import Mapping
from typing import Any

__all__ = ["MetricsLogger", "read_csv"]


class MetricsLogger:
    """Append rows of scalars to ``run_dir/metrics.csv`` and TensorBoard events in ``run_dir/tb``.

    The CSV columns are fixed by the first row written (or by an existing file when
    resuming, whose rows past ``keep_until_step`` are dropped so a resumed run does not
    repeat them).
    """

    def __init__(self, run_dir: str, tensorboard: bool = True, keep_until_step: int | None = None):
        self.path = os.path.join(run_dir, "metrics.csv")
        self._fields: list[str] | None = None
        existing: list[dict[str, str]] = []
        if os.path.exists(self.path) and keep_until_step is not None:
            existing = [r for r in read_csv(self.path) if float(r["env_steps"]) <= keep_until_step]
            with open(self.path, newline="") as f:
                self._fields = next(csv.reader(f), None)
        self._file = open(self.path, "w", newline="")
        self._writer = None
        if self._fields:
            self._writer = csv.DictWriter(self._file, fieldnames=self._fields, extrasaction="ignore")
            self._writer.writeheader()
            self._writer.writerows(existing)
            self._file.flush()
        self._tb = None
        if tensorboard:
            from tensorboardX import SummaryWriter

            self._tb = SummaryWriter(os.path.join(run_dir, "tb"))

    def write(self, env_steps: int, metrics: Mapping[str, Any]) -> None:
        """Log one row at ``env_steps``; values are converted to floats."""
        row = {"env_steps": int(env_steps)}
        row.update({k: float(v) for k, v in metrics.items()})
        if self._writer is None:
            self._fields = list(row)
            self._writer = csv.DictWriter(self._file, fieldnames=self._fields, extrasaction="ignore")
            self._writer.writeheader()
        self._writer.writerow(row)
        self._file.flush()
        if self._tb is not None:
            for k, v in row.items():
                if k != "env_steps" and not math.isnan(v):
                    self._tb.add_scalar(k, v, int(env_steps))
            self._tb.flush()

    def close(self) -> None:
        self._file.close()
        if self._tb is not None:
            self._tb.close()


def read_csv(path: str) -> list[dict[str, str]]:
    """Rows of a metrics CSV as dicts of strings."""
    with open(path, newline="") as f:
        return list(csv.DictReader(f))
