"""The processes of a run over several hosts, as the command line sees them: which one speaks and writes
(process 0), the text it shares with the others, and a state's arrays as one process holds them.

With one process every function here is the plain single-process operation (no collective is called).
"""

from __future__ import annotations

from typing import Any

import jax
import numpy as np

__all__ = ["broadcast_text", "is_main_process", "local_view", "say", "to_host"]


def is_main_process() -> bool:
    """Whether this is process 0 of the run (the only process of a one-process run)."""
    return jax.process_index() == 0


def say(message: str) -> None:
    """Print on process 0 only."""
    if is_main_process():
        print(message, flush=True)


def broadcast_text(text: str) -> str:
    """Process 0's ``text`` on every process (a collective: every process calls it)."""
    from jax.experimental import multihost_utils

    data = np.frombuffer(text.encode(), np.uint8) if is_main_process() else np.zeros(0, np.uint8)
    size = int(multihost_utils.broadcast_one_to_all(np.int32(data.size)))
    buf = data if is_main_process() else np.zeros(size, np.uint8)
    return bytes(np.asarray(multihost_utils.broadcast_one_to_all(buf), np.uint8)).decode()


def local_view(tree: Any) -> Any:
    """``tree`` as arrays of this process: leaves every device holds whole → a copy on a local device,
    leaves split over several processes → None. With one process ``tree`` is returned as it is."""

    def local(x: Any) -> Any:
        if not isinstance(x, jax.Array) or x.is_fully_addressable:
            return x
        return x.addressable_data(0) if x.is_fully_replicated else None

    return jax.tree.map(local, tree)


def to_host(tree: Any) -> Any:
    """Every leaf as a NumPy array of its global value, also for arrays that span several processes
    (split ones are gathered: a collective, so every process calls it)."""
    from jax.experimental import multihost_utils

    def fetch(x: Any) -> np.ndarray:
        if isinstance(x, jax.Array) and not x.is_fully_addressable and not x.is_fully_replicated:
            return np.asarray(multihost_utils.process_allgather(x, tiled=True))
        return np.asarray(x)

    return jax.tree.map(fetch, tree)
