"""``python -m benchmarks.arm7_greedy``: the greedy controller's table with the run's provenance."""

from __future__ import annotations

import glob
import json

from benchmarks import arm7_greedy


def test_greedy_controller_writes_its_results_with_provenance(tmp_path):
    argv = ["--modes", "kinematic", "--lanes", "16", "--purpose", "report", "--allow-dirty", "--out", str(tmp_path)]
    arm7_greedy.main(argv)
    (path,) = glob.glob(str(tmp_path / "*-arm7_greedy.json"))
    got = json.load(open(path))
    assert got["command"] == "python -m benchmarks.arm7_greedy " + " ".join(argv)
    prov = got["provenance"]
    assert len(prov["commit"]) == 40 and prov["dirty"] in (True, False) and prov["tree_sha1"]
    assert got["seed"] == 1_000_000 and prov["seeds"]["purpose"] == "report"
    (row,) = got["rows"]
    assert row["mode"] == "kinematic" and (row["successes"], row["episodes"]) == (16, 16)  # straight there always
    assert 1.0 < row["length"] < 50.0 and row["steps_per_s"] > 0
    md = open(path[:-5] + ".md").read()
    assert "| kinematic | 16 of 16 | 100.0% |" in md and got["command"] in md and "## Provenance" in md
