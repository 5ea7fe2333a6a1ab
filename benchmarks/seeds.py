"""Where every benchmark's seeds come from: tuning and reporting draw from two ranges that never meet.

A seed is an integer ``s``; its training key is ``jax.random.PRNGKey(s)``, exactly the key of
``python -m train.<algo> --seed s`` (and its evaluation key ``fold_in(PRNGKey(s), EVAL_KEY_OFFSET)``, as
``jaxrl_robot.evaluation`` derives it). A benchmark's ``--purpose`` picks the range:

* ``tune`` (the default): seeds ``first, first + 1, …`` below :data:`REPORT_BASE` — sweeps, variants,
  ablations, anything a setting is chosen on;
* ``report``: seeds ``REPORT_BASE + first, …`` — the figures a README or a report states. No tuning
  command can draw them (:func:`seed_ids` refuses a tuning seed at or above :data:`REPORT_BASE`), so a
  reported figure is never measured on the seeds its setting was chosen on.

Every results file records its purpose and its seeds (:func:`record`), a sweep's file included, so the
keys behind any figure can be read back and told apart.
"""

from __future__ import annotations

import argparse
from collections.abc import Sequence
from typing import Any

from benchmarks.arguments import nonnegative, positive

PURPOSES = ("tune", "report")
REPORT_BASE = 1_000_000
"""The first seed of the ``report`` range; ``tune`` seeds are below it. (JAX's keys take seeds up to 2**32 − 1.)"""
MAX_SEED = 2**32 - 1


def add_args(p: argparse.ArgumentParser, seeds: int = 3) -> None:
    """``--purpose tune|report``, ``--seeds N`` (default ``seeds``) and ``--first-seed K`` (the offset in the
    purpose's range)."""
    p.add_argument("--purpose", default="tune", choices=PURPOSES,
                   help=f"tune: seeds from --first-seed up (below {REPORT_BASE:,}), for choosing settings; report: "
                   f"seeds {REPORT_BASE:,} + --first-seed up, which no tuning run can draw, for the figures stated")
    p.add_argument("--seeds", type=positive, default=seeds, help="how many seeds")
    p.add_argument("--first-seed", type=nonnegative, default=0,
                   help="the first seed's offset within the purpose's range (default 0)")  # fmt: skip


def seed_ids(purpose: str, n: int, first: int = 0) -> list[int]:
    """The ``n`` seeds of ``purpose`` from offset ``first``: ``tune`` ``[first, first + n)``, ``report``
    ``[REPORT_BASE + first, REPORT_BASE + first + n)``.

    Raises:
      ValueError: an unknown purpose, ``n < 1``, ``first < 0``, or seeds outside the purpose's range (a
        ``tune`` seed reaching :data:`REPORT_BASE`, a ``report`` seed past :data:`MAX_SEED`).
    """
    if purpose not in PURPOSES:
        raise ValueError(f"purpose {purpose!r} is not one of {', '.join(PURPOSES)}")
    if n < 1 or first < 0:
        raise ValueError(f"seeds {n} from {first}: allowed at least 1 seed from an offset >= 0")
    base, end = (0, REPORT_BASE) if purpose == "tune" else (REPORT_BASE, MAX_SEED + 1)
    if base + first + n > end:
        raise ValueError(f"{purpose} seeds {base + first}..{base + first + n - 1} leave the {purpose} range "
                         f"[{base}, {end - 1}]")  # fmt: skip
    return [base + first + i for i in range(n)]


def purpose_of(seed: int) -> str:
    """The purpose whose range holds ``seed``."""
    return "report" if seed >= REPORT_BASE else "tune"


def keys(ids: Sequence[int]) -> Any:
    """The training keys of seeds ``ids``: ``[len(ids), 2]``, row ``i`` ``PRNGKey(ids[i])``."""
    import jax
    import jax.numpy as jnp

    return jnp.stack([jax.random.PRNGKey(s) for s in ids])


def eval_keys(ids: Sequence[int]) -> Any:
    """The evaluation keys of seeds ``ids`` (``[len(ids), 2]``), those of ``python -m train.<algo>``'s runs."""
    import jax
    import jax.numpy as jnp

    from jaxrl_robot.evaluation import EVAL_KEY_OFFSET

    return jnp.stack([jax.random.fold_in(jax.random.PRNGKey(s), EVAL_KEY_OFFSET) for s in ids])


def record(purpose: str, ids: Sequence[int], how: str = "training key PRNGKey(seed)") -> dict[str, Any]:
    """The seeds' entry of a results file's provenance: ``{"purpose", "ids", "keys"}``."""
    return {"purpose": purpose, "ids": list(ids), "keys": how}


def words(entry: Any) -> str:
    """A provenance ``seeds`` entry in words (entries written before :func:`record` are shown as they are)."""
    if not isinstance(entry, dict) or "purpose" not in entry:
        return str(entry)
    ids = entry["ids"]
    run = len(ids) > 3 and ids == list(range(ids[0], ids[-1] + 1))
    span = f"{ids[0]}..{ids[-1]}" if run else ", ".join(map(str, ids))
    kind = ("the report range: never used to choose a setting" if entry["purpose"] == "report"
            else "the tuning range")  # fmt: skip
    return f"{len(ids)} seed(s) {span} ({kind}); {entry['keys']}"
