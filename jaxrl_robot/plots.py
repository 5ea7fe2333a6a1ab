"""The thesis's figure types, drawn with matplotlib (Agg): training curves and tracking plots."""

from __future__ import annotations

import os
import threading
import warnings
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

__all__ = [
    "import_in_background", "plot_seed_bands", "plot_staleness", "plot_training_curves", "plot_tracking",
    "plot_worker_curves",
]  # fmt: skip

_CURVES = (
    ("episode_return", "Episode reward", "episode_reward.png"),
    ("success", "Success rate", "success_rate.png"),
    ("extra_distance", "Extra distance", "extra_distance.png"),
)


def _plt() -> Any:
    """matplotlib's ``pyplot`` on the Agg backend, imported on first use (importing it takes about a
    second, which a run that draws at its end need not spend before it starts)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def import_in_background() -> threading.Thread:
    """Start importing :func:`_plt`'s ``pyplot`` in a daemon thread and return it.

    A run that draws its figures after training calls this when training starts: the import (about a
    second of Python) then overlaps the compiled chunks, which hold no Python lock while they run, instead
    of delaying the end of the run. A later :func:`_plt` waits for the import if it has not finished (the
    import system's module lock); an import error surfaces there, where the figures are drawn.
    """

    def target() -> None:
        try:
            _plt()
        except Exception:  # reported by the drawing's own import
            pass

    thread = threading.Thread(target=target, name="import-pyplot", daemon=True)
    thread.start()
    return thread


def _save(fig: Any, out_dir: str, name: str) -> str:
    """Write ``fig`` to ``out_dir/name`` (100 dpi, tight layout), close it and return the path."""
    path = os.path.join(out_dir, name)
    fig.tight_layout()
    fig.savefig(path, dpi=100)
    _plt().close(fig)
    return path


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
        fig, ax = _plt().subplots(figsize=(6, 3.5))
        ax.plot(steps, y)
        ax.set_xlabel("environment steps")
        ax.set_ylabel(title.lower())
        ax.set_title(title)
        ax.grid(alpha=0.3)
        written.append(_save(fig, out_dir, name))
    return written


def plot_seed_bands(
    curves: Mapping[str, Sequence[Sequence[Mapping[str, Any]]]], key: str, out_dir: str, name: str, title: str
) -> str | None:
    """One curve per label: the mean over seeds of column ``key`` against env steps, with the band
    between the seeds' lowest and highest values.

    Args:
      curves: ``label -> [metrics rows of one seed, ...]`` (``env_steps`` and ``key`` columns); the
        seeds' rows are cut to the shortest seed's length.
      key: the metric to draw (e.g. ``success``, ``episode_return``).
    Returns:
      the written path, or None when no label has the column.
    """
    fig, ax = _plt().subplots(figsize=(7, 4))
    drawn = 0
    for label, seeds in curves.items():
        seeds = [rows for rows in seeds if rows and key in rows[0]]
        if not seeds:
            continue
        n = min(len(rows) for rows in seeds)
        steps = np.array([float(r["env_steps"]) for r in seeds[0][:n]])
        y = np.array([[float(r[key]) if r[key] not in ("", None) else np.nan for r in rows[:n]] for rows in seeds])
        with warnings.catch_warnings():  # chunks without a finished episode are NaN in every seed
            warnings.simplefilter("ignore", RuntimeWarning)
            mean, lo, hi = np.nanmean(y, axis=0), np.nanmin(y, axis=0), np.nanmax(y, axis=0)
        ok = np.isfinite(mean)  # chunks where no episode ended are left out, the points around them joined
        marker = "o" if ok.sum() <= 20 else None
        (line,) = ax.plot(steps[ok], mean[ok], marker=marker, ms=3, label=f"{label} ({len(seeds)} seeds)")
        ax.fill_between(steps[ok], lo[ok], hi[ok], color=line.get_color(), alpha=0.2)
        drawn += 1
    if not drawn:
        _plt().close(fig)
        return None
    ax.set_xlabel("environment steps")
    ax.set_ylabel(key)
    ax.set_title(title)
    ax.grid(alpha=0.3)
    ax.legend(fontsize=7)
    return _save(fig, out_dir, name)


def plot_tracking(
    reference: Any, actual: Any, errors: Any, out_dir: str, axes: Sequence[str] = ("x", "y", "orientation")
) -> list[str]:
    """Reference vs real path (x-y) and per-axis tracking errors over time (thesis Fig. 5.27-5.31).

    Args:
      reference, actual: ``[T, >=2]`` states whose first two columns are x and y.
      errors: ``[T, len(axes)]`` tracking errors.
    """
    ref, act, err = (np.asarray(a, np.float64) for a in (reference, actual, errors))
    fig, ax = _plt().subplots(figsize=(5, 5))
    ax.plot(ref[:, 0], ref[:, 1], "--", label="reference")
    ax.plot(act[:, 0], act[:, 1], label="real")
    ax.set_xlabel("x")
    ax.set_ylabel("y")
    ax.set_aspect("equal", adjustable="datalim")
    ax.legend()
    ax.set_title("Referenced path and real path")
    path1 = _save(fig, out_dir, "tracking_path.png")
    fig, ax = _plt().subplots(figsize=(6, 3.5))
    for i, name in enumerate(axes):
        ax.plot(err[:, i], label=f"{name} error")
    ax.set_xlabel("time step")
    ax.set_ylabel("error")
    ax.legend()
    ax.grid(alpha=0.3)
    ax.set_title("Tracking errors")
    return [path1, _save(fig, out_dir, "tracking_errors.png")]


def _column(rows: Sequence[Mapping[str, Any]], key: str) -> np.ndarray:
    return np.array([float(r[key]) if r.get(key) not in ("", None) else np.nan for r in rows])


def plot_worker_curves(
    rows: Sequence[Mapping[str, Any]], out_dir: str, prefix: str = "worker_return_", name: str = "worker_rewards.png"
) -> list[str]:
    """Episode rewards of the individual workers against env steps (thesis Fig. 4.5, 4.7, 4.11, 4.13).

    Args:
      rows: metrics rows with ``env_steps`` and columns ``<prefix><worker>``.
      out_dir: where the PNG goes.
    Returns:
      the written path, or nothing when no such column has a value.
    """
    if not rows:
        return []
    keys = sorted((k for k in rows[0] if k.startswith(prefix)), key=lambda k: int(k[len(prefix) :]))
    steps = _column(rows, "env_steps")
    curves = [(k[len(prefix) :], _column(rows, k)) for k in keys]
    curves = [(w, y) for w, y in curves if not np.all(np.isnan(y))]
    if not curves:
        return []
    fig, ax = _plt().subplots(figsize=(6, 3.5))
    for w, y in curves:
        ok = ~np.isnan(y)
        ax.plot(steps[ok], y[ok], label=f"worker {w}", lw=1)
    ax.set_xlabel("environment steps")
    ax.set_ylabel("episode reward")
    ax.set_title("Episode rewards of different workers")
    ax.legend(fontsize=7, ncol=2)
    ax.grid(alpha=0.3)
    return [_save(fig, out_dir, name)]


def plot_staleness(rows: Sequence[Mapping[str, Any]], out_dir: str, name: str = "staleness.png") -> list[str]:
    """Gradient staleness of asynchronous training: histogram over the run and mean per report.

    Args:
      rows: metrics rows with ``staleness_hist_<lower edge>`` shares, ``applied_gradients`` and
        ``staleness_mean`` per report (A3C).
      out_dir: where the PNG goes.
    Returns:
      the written path, or nothing without staleness histogram columns.
    """
    prefix = "staleness_hist_"
    if not rows or not any(k.startswith(prefix) for k in rows[0]):
        return []
    keys = sorted((k for k in rows[0] if k.startswith(prefix)), key=lambda k: int(k[len(prefix) :]))
    weights = _column(rows, "applied_gradients")
    shares = np.stack([_column(rows, k) for k in keys], axis=1)
    total = np.nansum(shares * weights[:, None], axis=0) / max(np.nansum(weights), 1.0)
    fig, (ax1, ax2) = _plt().subplots(1, 2, figsize=(9, 3.5))
    ax1.bar([k[len(prefix) :] for k in keys], total)
    ax1.set_xlabel("staleness (global updates since the worker's sync; bin lower edge)")
    ax1.set_ylabel("share of applied gradients")
    ax1.set_title("Gradient delay")
    ax2.plot(_column(rows, "env_steps"), _column(rows, "staleness_mean"))
    ax2.set_xlabel("environment steps")
    ax2.set_ylabel("mean staleness")
    ax2.grid(alpha=0.3)
    return [_save(fig, out_dir, name)]
