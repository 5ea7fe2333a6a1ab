"""The thesis's figure types, drawn with matplotlib (Agg): training curves and tracking plots."""

from __future__ import annotations

import os
from collections.abc import Mapping, Sequence
from typing import Any

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402

__all__ = ["plot_training_curves", "plot_tracking"]

_CURVES = (
    ("episode_return", "Episode reward", "episode_reward.png"),
    ("success", "Success rate", "success_rate.png"),
    ("extra_distance", "Extra distance", "extra_distance.png"),
)


def plot_training_curves(rows: Sequence[Mapping[str, Any]], out_dir: str) -> list[str]:
    """Episode reward, success rate and extra distance against environment steps.

    Args:
      rows: metrics rows (``env_steps`` and any of ``episode_return``, ``success``,
        ``extra_distance``), e.g. ``logging.read_csv(...)``.
      out_dir: where the PNG files go.
    Returns:
      the written paths (a curve whose column is missing or all NaN is skipped).
    """
    written = []
    if not rows:
        return written
    steps = np.array([float(r["env_steps"]) for r in rows])
    for key, title, name in _CURVES:
        if key not in rows[0]:
            continue
        y = np.array([float(r[key]) if r[key] not in ("", None) else np.nan for r in rows])
        if np.all(np.isnan(y)):
            continue
        fig, ax = plt.subplots(figsize=(6, 3.5))
        ax.plot(steps, y)
        ax.set_xlabel("environment steps")
        ax.set_ylabel(title.lower())
        ax.set_title(title)
        ax.grid(alpha=0.3)
        path = os.path.join(out_dir, name)
        fig.tight_layout()
        fig.savefig(path, dpi=100)
        plt.close(fig)
        written.append(path)
    return written


def plot_tracking(
    reference: Any, actual: Any, errors: Any, out_dir: str, axes: Sequence[str] = ("x", "y", "orientation")
) -> list[str]:
    """Reference vs real path (x-y) and per-axis tracking errors over time (thesis Fig. 5.27-5.31).

    Args:
      reference, actual: ``[T, >=2]`` states whose first two columns are x and y.
      errors: ``[T, len(axes)]`` tracking errors.
    """
    ref, act, err = (np.asarray(a, np.float64) for a in (reference, actual, errors))
    fig, ax = plt.subplots(figsize=(5, 5))
    ax.plot(ref[:, 0], ref[:, 1], "--", label="reference")
    ax.plot(act[:, 0], act[:, 1], label="real")
    ax.set_xlabel("x")
    ax.set_ylabel("y")
    ax.set_aspect("equal", adjustable="datalim")
    ax.legend()
    ax.set_title("Referenced path and real path")
    path1 = os.path.join(out_dir, "tracking_path.png")
    fig.tight_layout()
    fig.savefig(path1, dpi=100)
    plt.close(fig)
    fig, ax = plt.subplots(figsize=(6, 3.5))
    for i, name in enumerate(axes):
        ax.plot(err[:, i], label=f"{name} error")
    ax.set_xlabel("time step")
    ax.set_ylabel("error")
    ax.legend()
    ax.grid(alpha=0.3)
    ax.set_title("Tracking errors")
    path2 = os.path.join(out_dir, "tracking_errors.png")
    fig.tight_layout()
    fig.savefig(path2, dpi=100)
    plt.close(fig)
    return [path1, path2]
