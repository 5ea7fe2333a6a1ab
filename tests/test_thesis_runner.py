"""``python -m benchmarks.thesis``: every row of a table through its command line, the report's
structure, skipping finished seeds, continuing an unfinished one, and missing rows listed as such.
Smoke budgets: the numbers are not checked, the plumbing is."""

from __future__ import annotations

import glob
import json
import os

from benchmarks import thesis


def test_table_3_1_smoke_report_resume_and_missing_rows(tmp_path):
    runs, out = str(tmp_path / "runs"), str(tmp_path / "out")
    argv = ["--tables", "3.1", "--seeds", "1", "--smoke", "--preset", "cpu", "--quiet", "--runs", runs, "--out", out]
    result = thesis.main(argv)
    rows = result["rows"]
    assert [r["row"]["name"] for r in rows] == [r.name for r in thesis.ROWS if r.table == "3.1"]
    assert [r["row"]["thesis"] for r in rows] == [79, 78, 81, 87, 56, 9]
    for r in rows:
        (seed,) = r["seeds"]
        assert "error" not in seed and seed["finished"] is True, seed
        assert r["figure"]["seeds_done"] == 1 and 0.0 <= r["figure"]["mean"][0] <= 100.0
        assert r["figure"]["met"] == [r["figure"]["mean"][0] >= 95.0]
        assert len(r["figure"]["precision"]) == 2 and 0.0 <= min(r["figure"]["precision"])  # at 2 and 1 cm
        assert seed["success_5cm"] == seed["success_rate"]  # the precision run agrees with the evaluation
    stem = result["stem"]
    md = open(stem + ".md").read()
    assert md.count("| DDPG, ") == 6 and "## Table 3.1" in md and "## Tables 7.1–7.3" in md
    assert "--her future --her-k 4 --preset cpu --seed 0" in md  # the exact command of a row
    assert os.path.exists(os.path.join(stem + "-figures", "table-3.1-curves.png"))
    assert json.load(open(stem + ".json"))["meta"]["smoke"] is True

    # a finished seed is skipped; one without eval.json (a killed run) continues in its own run directory
    dirs = {r["row"]["name"]: r["seeds"][0]["run_dir"] for r in rows}
    os.remove(os.path.join(dirs["sparse-final"], "eval.json"))
    before = os.path.getmtime(os.path.join(dirs["sparse-future2"], "eval.json"))
    again = thesis.main(argv)
    seeds = {r["row"]["name"]: r["seeds"][0] for r in again["rows"]}
    assert seeds["sparse-future2"].get("skipped") and not seeds["sparse-final"].get("skipped")
    assert seeds["sparse-final"]["run_dir"] == dirs["sparse-final"]
    assert os.path.exists(os.path.join(dirs["sparse-final"], "eval.json"))
    assert os.path.getmtime(os.path.join(dirs["sparse-future2"], "eval.json")) == before
    assert len(glob.glob(os.path.join(runs, "3.1", "sparse-final", "seed0", "*"))) == 1

    # rows whose algorithm does not exist yet are reported as missing, never run
    missing = thesis.main(["--tables", "6.2-6.3", "--seeds", "1", "--runs", runs, "--out", out])
    md = open(missing["stem"] + ".md").read()
    assert md.count("**missing**") == 8 and not os.path.exists(os.path.join(runs, "6.2-6.3"))
