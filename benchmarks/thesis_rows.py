"""The thesis's tables as rows of :mod:`benchmarks.thesis`: each row's command line, goal and the thesis's figure,
with the precise and faithful variants of a row."""

from __future__ import annotations

import dataclasses
from typing import Any

from benchmarks.tracking_report import THESIS

ARM_GOAL = 95.0
PRECISE_GOAL = (95.0, 90.0)
"""``--variant precise``: success within 2 cm and within 1 cm, % (every arm row)."""
VARIANTS = ("standard", "precise", "faithful")
"""``faithful``: every row in the thesis's setting (:func:`faithful_row`, the ``thesis`` preset)."""
ROADS = ("train", "test1", "test2", "test3")
RACING_THESIS = {  # per road: (success, collision, out of track, overtakes) of 20 laps, Tables 6.2 and 6.3
    "ddpg": ((18, 2, 0, 2.65), (16, 2, 2, 2.55), (17, 2, 1, 2.6), (18, 1, 1, 2.85)),
    "td3": ((18, 2, 0, 2.6), (17, 2, 1, 2.65), (18, 1, 1, 2.9), (17, 2, 1, 2.7)),
}
"""Arm rows: success over 100 test episodes, % (every row)."""


@dataclasses.dataclass(frozen=True)
class Row:
    """One row of a thesis table.

    ``algo``: the ``train.<algo>`` command (None: missing); ``argv``: its flags beyond preset,
    seed and output; ``thesis``: the thesis's figure (success % for the arm, ``(x, y, θ or z)``
    sums for tracking); ``reference``: the tracking goal's key (``scara``, ``sine``, ``ellipse``).
    """

    table: str
    name: str
    label: str
    algo: str | None
    argv: tuple[str, ...]
    thesis: Any
    kind: str
    reference: str = ""
    missing: str = ""

    @property
    def id(self) -> str:
        return f"{self.table}/{self.name}"


ARM = ("--env", "arm7", "--env-config", "mode=kinematic")  # the thesis's arm runs in joint-position mode
UNICYCLE = {"sine": ("--env", "unicycle", "--env-config", "trajectory=sine"),
            "ellipse": ("--env", "unicycle", "--env-config", "trajectory=ellipse")}  # fmt: skip


def _tracking_rows() -> list[Row]:
    """Tables 4.3-4.5 (DDPG, distributed DDPG) and 5.4-5.7 (PPO, two-stage, PPO + LSTM)."""
    rows = []
    table = {"scara": "4.3", "sine": "4.4", "ellipse": "4.5"}
    for ref in ("scara", "sine", "ellipse"):
        env = ("--env", "scara") if ref == "scara" else UNICYCLE[ref]
        rows.append(Row(table[ref], f"{ref}-ddpg", f"DDPG + PER, {ref}", "ddpg", env, THESIS[(ref, "ddpg")],
                        "tracking", ref))  # fmt: skip
        rows.append(Row(table[ref], f"{ref}-distributed", f"Distributed DDPG, {ref}", "ddpg",
                        (*env, "--distributed"), THESIS[(ref, "distributed")], "tracking", ref))  # fmt: skip
    for ref in ("sine", "ellipse"):
        env = UNICYCLE[ref]
        rows += [
            Row("5.4-5.7", f"{ref}-ppo", f"Distributed PPO, {ref}", "ppo", env, THESIS[(ref, "mlp")], "tracking", ref),
            Row("5.4-5.7", f"{ref}-two-stage", f"Two-stage (action-search pre-training + PPO), {ref}", "ppo",
                (*env, "--pretrain", "action-search"), THESIS[(ref, "two-stage")], "tracking", ref),
            Row("5.4-5.7", f"{ref}-lstm", f"Distributed PPO + LSTM, {ref}", "ppo", (*env, "--policy", "lstm"),
                THESIS[(ref, "lstm")], "tracking", ref),
        ]  # fmt: skip
    return rows


ROWS: tuple[Row, ...] = (
    Row("3.1", "sparse-final", "DDPG, sparse reward, HER final", "ddpg",
        (*ARM, "--reward", "sparse", "--her", "final"), 79, "arm"),
    Row("3.1", "sparse-future2", "DDPG, sparse reward, HER future k=2", "ddpg",
        (*ARM, "--reward", "sparse", "--her", "future", "--her-k", "2"), 78, "arm"),
    Row("3.1", "sparse-future4", "DDPG, sparse reward, HER future k=4", "ddpg",
        (*ARM, "--reward", "sparse", "--her", "future", "--her-k", "4"), 81, "arm"),
    Row("3.1", "shaped-random2", "DDPG, shaped reward, HER random k=2", "ddpg",
        (*ARM, "--reward", "shaped", "--her", "random", "--her-k", "2"), 87, "arm"),
    Row("3.1", "shaped-future2", "DDPG, shaped reward, HER future k=2", "ddpg",
        (*ARM, "--reward", "shaped", "--her", "future", "--her-k", "2"), 56, "arm"),
    Row("3.1", "shaped-per", "DDPG, shaped reward, no relabelling, PER (no goal in the observation)", "ddpg",
        ("--env", "arm7", "--env-config", "mode=kinematic", "obs=no_goal", "--reward", "shaped", "--her", "none",
         "--per"), 9, "arm"),
    Row("4.1", "a3c-ordinary", "A3C, ordinary reward", "a3c", (*ARM, "--reward", "ordinary"), 76, "arm"),
    Row("4.1", "a3c-path", "A3C, path reward", "a3c", (*ARM, "--reward", "path"), 84, "arm"),
    Row("4.1", "a2c-ordinary", "A2C, ordinary reward", "a2c", (*ARM, "--reward", "ordinary"), 79, "arm"),
    Row("4.1", "a2c-path", "A2C, path reward", "a2c", (*ARM, "--reward", "path"), 88, "arm"),
    *[r for r in _tracking_rows() if r.table in ("4.3", "4.4", "4.5")],
    Row("5.1", "ppo-ordinary", "Distributed PPO, ordinary reward", "ppo", (*ARM, "--reward", "ordinary"), 82, "arm"),
    Row("5.1", "ppo-path", "Distributed PPO, path reward", "ppo", (*ARM, "--reward", "path"), 91, "arm"),
    *[r for r in _tracking_rows() if r.table == "5.4-5.7"],
    *[Row("6.2-6.3", algo, f"{algo.upper()} after imitation of the expert, 20 laps per road", algo,
          ("--env", "racecar", "--eval-episodes", "20"), RACING_THESIS[algo], "driving")
      for algo in ("ddpg", "td3")],
)  # fmt: skip
"""Every row of the thesis's result tables (chapters 3-6)."""

TABLES = tuple(dict.fromkeys(r.table for r in ROWS))
TITLES = {
    "3.1": "Table 3.1 — DDPG with HER / PER on the arm (success over 100 test goals, %)",
    "4.1": "Table 4.1 — A3C and A2C on the arm (success, %)",
    "4.3": "Table 4.3 — SCARA tracking, DDPG and distributed DDPG (sum of |error|: x, y, z in m)",
    "4.4": "Table 4.4 — unicycle sine, DDPG and distributed DDPG (sum of |error|: x, y m; θ rad)",
    "4.5": "Table 4.5 — unicycle ellipse, DDPG and distributed DDPG (sum of |error|)",
    "5.1": "Table 5.1 — distributed PPO on the arm (success, %)",
    "5.4-5.7": "Tables 5.4–5.7 — unicycle, PPO, two-stage and PPO + LSTM (sum of |error|)",
    "6.2-6.3": "Tables 6.2–6.3 — racing with opponents, 20 laps per road (success / collision / out / overtakes)",
}

SMOKE = {  # budgets of seconds: the plumbing, not the numbers
    ("ddpg", "arm"): ("--epochs", "1", "--cycles-per-epoch", "2", "--num-envs", "4", "--updates-per-cycle", "2",
                      "--batch-size", "16", "--actor-hidden", "16", "--critic-hidden", "16", "--eval-episodes", "4"),
    ("ddpg", "tracking"): ("--total-steps", "256", "--learning-starts", "64", "--batch-size", "16",
                           "--actor-hidden", "16", "--critic-hidden", "16", "--chunks", "2"),
    ("a2c", "arm"): ("--total-steps", "256", "--chunks", "2", "--eval-episodes", "4"),
    ("ppo", "arm"): ("--total-steps", "1024", "--chunks", "2", "--eval-episodes", "4"),
    ("ppo", "tracking"): ("--total-steps", "1024", "--chunks", "2"),
    ("ddpg", "driving"): ("--total-steps", "256", "--pretrain-steps", "128", "--num-envs", "4", "--unroll-length",
                          "4", "--learning-starts", "32", "--batch-size", "16", "--actor-hidden", "16",
                          "--critic-hidden", "16", "--imitation-batch", "16", "--imitation-updates", "1",
                          "--chunks", "2", "--eval-episodes", "1", "--env-config", "n_opponents=2", "max_steps=100"),
}  # fmt: skip


def precise_row(row: Row) -> Row:
    """``row`` on ``arm7_precise`` (arm rows; any other row unchanged)."""
    if row.kind != "arm":
        return row
    argv = tuple("arm7_precise" if a == "arm7" and i and row.argv[i - 1] == "--env" else a
                 for i, a in enumerate(row.argv))  # fmt: skip
    return dataclasses.replace(row, argv=argv)


def faithful_row(row: Row) -> Row:
    """``row`` in the thesis's plant: the unicycle rows in ``kinematic`` mode (the thesis's Euler update of
    Eq. 3.18; the arm rows already run ``kinematic``); with the ``thesis`` preset (Tables 3.2, 3.3, 4.2,
    5.2, 5.3 and Eq. 3.21–3.23) the thesis's setting."""
    if "unicycle" not in row.argv:
        return row
    argv = tuple(x for a in row.argv for x in ((a, "mode=kinematic") if a.startswith("trajectory=") else (a,)))
    return dataclasses.replace(row, argv=argv)


def is_precise(row: Row | dict) -> bool:
    argv = row.argv if isinstance(row, Row) else row["argv"]
    return "arm7_precise" in argv


def smoke_args(row: Row) -> tuple[str, ...]:
    algo = {"a3c": "a2c", "td3": "ddpg"}.get(row.algo, row.algo)
    return SMOKE[(algo, row.kind)]


def command(row: Row, preset: str, seed: int, smoke: bool) -> list[str]:
    """The row's ``train.<algo>`` arguments for one seed (output directory apart)."""
    return [*row.argv, "--preset", preset, "--seed", str(seed), *(smoke_args(row) if smoke else ())]
