"""What a run shows and answers to while it trains: its progress bar, the signals that stop it after a chunk,
the errors that end it, and how its process exits (:mod:`train.run` drives the run)."""

from __future__ import annotations

import contextlib
import math
import os
import signal
import sys
import threading
from typing import Any

__all__ = ["STOP_SIGNALS", "NonFiniteLossError", "PeerLostError", "Progress", "exit_process", "process_age_s",
           "progress_info", "stop_on_signals", "use_progress_bar"]  # fmt: skip


class NonFiniteLossError(RuntimeError):
    """A loss became NaN or inf; the message names the metric, the env step and the last good checkpoint."""


class PeerLostError(RuntimeError):
    """Another process of a run over several processes stopped responding; the message names it and
    the run directory to resume (:func:`jaxrl_robot.parallel.lost_peer`)."""


def use_progress_bar() -> bool:
    """A bar only on an interactive terminal and not under CI."""
    return sys.stdout.isatty() and not os.environ.get("CI")


def process_age_s() -> float | None:
    """Seconds since this process started (Linux ``/proc``; None elsewhere): imports, device start and
    building the env and trainer, when called as a run begins."""
    try:
        with open("/proc/self/stat") as f:
            start_ticks = int(f.read().rsplit(")", 1)[1].split()[19])
        with open("/proc/uptime") as f:
            uptime = float(f.read().split()[0])
        return round(uptime - start_ticks / os.sysconf("SC_CLK_TCK"), 2)
    except (OSError, ValueError, IndexError):
        return None


class Progress:
    """A rich progress bar, or nothing."""

    def __init__(self, enabled: bool, total: int, done: int):
        self.enabled = enabled
        if not enabled:
            return
        from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeRemainingColumn

        self._bar = Progress(
            TextColumn("[bold]train"),
            BarColumn(),
            MofNCompleteColumn(),
            TextColumn("steps"),
            TimeRemainingColumn(),
            TextColumn("{task.fields[info]}"),
        )
        self._bar.start()
        self._task = self._bar.add_task("train", total=total, completed=done, info="compiling…")

    def update(self, done: int, info: str) -> None:
        if self.enabled:
            self._bar.update(self._task, completed=done, info=info)

    def close(self) -> None:
        if self.enabled:
            self._bar.stop()


def progress_info(metrics: dict[str, float], sps: float) -> str:
    parts = [f"{sps:,.0f} steps/s"]
    for key, label in (("episode_return", "return"), ("success", "success"), ("pos_error", "tracking error")):
        v = metrics.get(key)
        if v is not None and math.isfinite(v):
            parts.append(f"{label} {v:.3g}")
    return "  ".join(parts)


STOP_SIGNALS = (signal.SIGINT, signal.SIGTERM)
"""Signals that stop a run after its current chunk, checkpointed (:func:`stop_on_signals`)."""


@contextlib.contextmanager
def stop_on_signals(enabled: bool = True):
    """While the block runs, SIGINT (Ctrl-C) and SIGTERM ask the run to stop after its current chunk;
    yields a dict whose ``"signal"`` holds the first such signal's number (0 while none came).  A second
    SIGINT interrupts at once.  Only in the main thread (where Python runs signal handlers) and when
    ``enabled`` (not across several processes, which must stop together); the previous handlers come back
    at the end of the block."""
    got = {"signal": 0}
    if not enabled or threading.current_thread() is not threading.main_thread():
        yield got
        return

    def handler(signum: int, frame: Any) -> None:
        got["signal"] = got["signal"] or signum
        signal.signal(signal.SIGINT, signal.default_int_handler)  # a second Ctrl-C: at once

    previous = {s: signal.getsignal(s) for s in STOP_SIGNALS}
    for s in STOP_SIGNALS:
        signal.signal(s, handler)
    try:
        yield got
    finally:
        for s, h in previous.items():
            signal.signal(s, h)


def exit_process(code: int) -> None:
    """End a ``python -m train.<algo>`` process with ``code`` once its output is flushed. A run of one process
    leaves at once (``os._exit``): its files are closed by then, and the interpreter's teardown of XLA's
    clients and compiled programs would add seconds (4–5 s on a CPU) to every command. A process of a run
    over several exits normally, through ``jax.distributed``'s shutdown."""
    import logging

    import jax

    sys.stdout.flush()
    sys.stderr.flush()
    if jax.process_count() == 1:
        logging.shutdown()
        os._exit(code)
    sys.exit(code)
