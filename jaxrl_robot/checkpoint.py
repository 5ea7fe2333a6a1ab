"""Orbax checkpoints of a whole train state plus a small JSON record per step.

A checkpoint holds the complete state pytree (parameters, optimiser states, normalisers,
environment states, RNG key, counters), so restoring it continues a run exactly. Saves are
synchronous (the file is complete when ``save`` returns) and the newest ``max_to_keep``
are kept.
"""

from __future__ import annotations

import os
from typing import Any

import jax
import numpy as np
import orbax.checkpoint as ocp

__all__ = ["Checkpointer"]


class Checkpointer:
    """Save and restore ``(state, record)`` pairs under ``directory/<step>/``.

    ``record`` is a JSON-able dict (counters, wall time) saved beside the state.
    """

    def __init__(self, directory: str, max_to_keep: int = 3):
        self.directory = os.path.abspath(directory)
        options = ocp.CheckpointManagerOptions(
            max_to_keep=max_to_keep, create=True, enable_async_checkpointing=False
        )
        self._manager = ocp.CheckpointManager(self.directory, options=options, item_names=("state", "record"))

    def save(self, step: int, state: Any, record: dict[str, Any]) -> None:
        """Write the checkpoint of ``step`` (overwrites nothing: a step is saved once).

        Zero-size arrays (e.g. empty fields of MJX's ``Data``) are stored as ``None``: orbax
        cannot write them, and :meth:`restore` takes them back from ``target``.
        """
        state = jax.tree.map(lambda x: x if np.size(x) else None, state)
        args = ocp.args.Composite(state=ocp.args.StandardSave(state), record=ocp.args.JsonSave(record))
        self._manager.save(int(step), args=args, force=True)
        self._manager.wait_until_finished()

    def latest_step(self) -> int | None:
        """The newest saved step, or None."""
        return self._manager.latest_step()

    def all_steps(self) -> list[int]:
        return list(self._manager.all_steps())

    def restore(self, step: int, target: Any = None) -> tuple[Any, dict[str, Any]]:
        """Restore ``step`` into the structure, shapes and shardings of ``target`` (a state).

        Without ``target`` the state comes back as saved: nested dicts of arrays.
        """
        abstract = None
        if target is not None:
            abstract = jax.tree.map(lambda x: ocp.utils.to_shape_dtype_struct(x) if np.size(x) else None, target)
        args = ocp.args.Composite(state=ocp.args.StandardRestore(abstract), record=ocp.args.JsonRestore())
        out = self._manager.restore(int(step), args=args)
        state = out["state"]
        if target is not None:
            saved = {_names(p): v for p, v in jax.tree_util.tree_flatten_with_path(state)[0]}
            paths, treedef = jax.tree_util.tree_flatten_with_path(target)
            state = jax.tree.unflatten(treedef, [saved[_names(p)] if np.size(t) else t for p, t in paths])
        return state, dict(out["record"])

    def close(self) -> None:
        self._manager.close()


def _names(path: tuple) -> tuple:
    """A key path as plain names, so a dataclass field and the dict key it was saved under match."""
    return tuple(str(getattr(k, "name", getattr(k, "key", getattr(k, "idx", k)))) for k in path)
