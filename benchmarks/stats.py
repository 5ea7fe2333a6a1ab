"""Whether one side is ahead of another beyond the seeds' noise: Welch's t interval and Mann–Whitney's U.

    c = compare(ours, brax)       # per-seed results of each side, higher better
    c["verdict"]                  # "ahead", "behind", "level" or "not tested"
    words(c)                      # "ahead: +154 (95 % CI −386 … +694; Welch), Mann–Whitney p 0.70, 3 vs 3 seeds"

The verdict is Welch's: ``ahead`` where the 95 % confidence interval of the difference of the means lies
above 0, ``behind`` where it lies below, ``level`` where it holds 0 (the seeds cannot tell the sides apart).
Mann–Whitney's two-sided p (exact without ties, else the normal approximation with the tie correction and a
continuity correction, as ``scipy.stats.mannwhitneyu`` computes it) is given beside, a check that does not
assume normal seeds. A side of fewer than 2 seeds, or one whose results all lie within floating-point noise
of one number while the other's do too, is not tested (identical sides are ``level``).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import numpy as np

LEVEL = 0.95


def welch(a: Sequence[float], b: Sequence[float], level: float = LEVEL) -> dict[str, float]:
    """Welch's t for ``mean(a) − mean(b)``: ``diff``, ``se`` (its standard error, sample variances),
    ``df`` (Welch–Satterthwaite), ``t``, ``p`` (two-sided) and the ``level`` interval ``lo`` … ``hi``.
    Each side needs at least 2 values; ``se`` 0 (both sides constant) gives ``lo = hi = diff``, ``p`` 1 or 0."""
    from scipy.special import stdtr, stdtrit

    x, y = np.asarray(a, float), np.asarray(b, float)
    if x.size < 2 or y.size < 2:
        raise ValueError(f"welch: each side needs at least 2 values; got {x.size} and {y.size}")
    va, vb = x.var(ddof=1) / x.size, y.var(ddof=1) / y.size
    diff, se = float(x.mean() - y.mean()), math.sqrt(va + vb)
    if se == 0.0:
        return {"diff": diff, "se": 0.0, "df": math.inf, "t": math.copysign(math.inf, diff) if diff else 0.0,
                "p": 1.0 if diff == 0.0 else 0.0, "lo": diff, "hi": diff}  # fmt: skip
    df = (va + vb) ** 2 / (va**2 / (x.size - 1) + vb**2 / (y.size - 1))
    t = diff / se
    q = float(stdtrit(df, 0.5 + level / 2))
    return {"diff": diff, "se": se, "df": float(df), "t": t, "p": float(2 * stdtr(df, -abs(t))),
            "lo": diff - q * se, "hi": diff + q * se}  # fmt: skip


def _ranks(values: np.ndarray) -> np.ndarray:
    """Ranks 1 … n, ties given their mean rank."""
    order = np.argsort(values, kind="mergesort")
    ranks = np.empty(values.size)
    ranks[order] = np.arange(1, values.size + 1)
    for v in np.unique(values):
        tied = values == v
        ranks[tied] = ranks[tied].mean()
    return ranks


def u_counts(m: int, n: int) -> np.ndarray:
    """How many of the C(m + n, m) orderings of two samples of sizes ``m`` and ``n`` (no ties) give each
    U = 0 … m·n: ``f(u; m, n) = f(u − n; m − 1, n) + f(u; m, n − 1)``."""
    table = {(0, j): np.ones(1) for j in range(n + 1)} | {(i, 0): np.ones(1) for i in range(m + 1)}
    for i in range(1, m + 1):
        for j in range(1, n + 1):
            out = np.zeros(i * j + 1)
            left, down = table[(i - 1, j)], table[(i, j - 1)]
            out[j : j + left.size] += left
            out[: down.size] += down
            table[(i, j)] = out
    return table[(m, n)]


def mann_whitney(a: Sequence[float], b: Sequence[float]) -> dict[str, Any]:
    """Mann–Whitney's U of ``a`` against ``b`` (pairs with a above b, ties counting ½) and its two-sided p:
    ``exact`` where no value is tied, else ``asymptotic`` (normal, tie-corrected, continuity-corrected)."""
    x, y = np.asarray(a, float), np.asarray(b, float)
    m, n = x.size, y.size
    if m < 1 or n < 1:
        raise ValueError(f"mann_whitney: each side needs at least 1 value; got {m} and {n}")
    both = np.concatenate([x, y])
    ranks = _ranks(both)
    u = float(ranks[:m].sum() - m * (m + 1) / 2)
    if np.unique(both).size == both.size:
        counts = u_counts(m, n)
        k = int(round(u))
        p = 2 * min(counts[: k + 1].sum(), counts[k:].sum()) / counts.sum()
        return {"u": u, "p": float(min(1.0, p)), "method": "exact"}
    _, tied = np.unique(both, return_counts=True)
    total = m + n
    var = m * n / 12 * ((total + 1) - float((tied**3 - tied).sum()) / (total * (total - 1)))
    z = (abs(u - m * n / 2) - 0.5) / math.sqrt(var) if var > 0 else 0.0
    return {"u": u, "p": float(min(1.0, math.erfc(max(z, 0.0) / math.sqrt(2)))), "method": "asymptotic"}


def compare(ours: Sequence[float], theirs: Sequence[float], level: float = LEVEL) -> dict[str, Any]:
    """``ours`` against ``theirs`` (per-seed results, higher better; NaN entries dropped): the seeds per side,
    :func:`welch` and :func:`mann_whitney` where each side has 2 or more, and the ``verdict`` (module docstring)."""
    x = [float(v) for v in ours if not math.isnan(float(v))]
    y = [float(v) for v in theirs if not math.isnan(float(v))]
    out: dict[str, Any] = {"n_ours": len(x), "n_theirs": len(y), "level": level}
    if len(x) < 2 or len(y) < 2:
        return {**out, "verdict": "not tested"}
    w = welch(x, y, level)
    out.update(welch=w, mann_whitney=mann_whitney(x, y))
    out["verdict"] = "ahead" if w["lo"] > 0 else "behind" if w["hi"] < 0 else "level"
    return out


def _signed(v: float, digits: int) -> str:
    return f"{v:+.{digits}f}".replace("-", "−")


def digits_for(values: Sequence[float]) -> int:
    """Decimals that show ``values`` at about 3 significant digits of their largest (0 at 100 and above)."""
    top = max((abs(float(v)) for v in values if not math.isnan(float(v))), default=0.0)
    return 0 if top >= 100 else 1 if top >= 10 else 2


def words(c: dict[str, Any], digits: int | None = None) -> str:
    """:func:`compare`'s result in words: ``level: +154 (95 % CI −386 … +694; Welch), Mann–Whitney p 0.70, 3 vs
    3 seeds``; ``digits``: decimals of the difference (default :func:`digits_for` its interval)."""
    seeds = f"{c['n_ours']} vs {c['n_theirs']} seeds"
    if not (c["n_ours"] and c["n_theirs"]):
        return "not compared (a side has no results)"
    if c["verdict"] == "not tested":
        return f"not tested ({seeds}; 2 a side needed)"
    w, mw = c["welch"], c["mann_whitney"]
    d = digits_for((w["diff"], w["lo"], w["hi"])) if digits is None else digits
    ci = f"{_signed(w['lo'], d)} … {_signed(w['hi'], d)}"
    return (f"{c['verdict']}: {_signed(w['diff'], d)} ({c['level']:.0%} CI {ci}; Welch), Mann–Whitney p "
            f"{mw['p']:.2g}, {seeds}").replace("95%", "95 %")
