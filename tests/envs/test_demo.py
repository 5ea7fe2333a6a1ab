"""``python -m envs_mjx.demo --results DIR``: the greedy controller's table with its provenance."""

from __future__ import annotations

import glob
import json

from envs_mjx import demo


def test_greedy_demo_writes_its_results_with_provenance(tmp_path):
    demo.main(["--modes", "kinematic", "--lanes", "16", "--results", str(tmp_path)])
    (path,) = glob.glob(str(tmp_path / "*-arm7_greedy.json"))
    got = json.load(open(path))
    assert got["command"] == f"python -m envs_mjx.demo --modes kinematic --lanes 16 --results {tmp_path}"
    assert got["lanes"] == 16 and got["seed"] == 0 and got["commit"] and got["device"]
    (row,) = got["rows"]
    assert row["mode"] == "kinematic" and row["success"] == 1.0  # straight to the goal always arrives
    assert 1.0 < row["length"] < 50.0 and row["steps_per_s"] > 0
    md = open(path[:-5] + ".md").read()
    assert "| kinematic | 100.0% |" in md and got["command"] in md


def test_roads_figure_writes_a_png(tmp_path):
    path = demo.roads_figure(str(tmp_path), generated=2)
    with open(path, "rb") as f:
        assert f.read(8) == b"\x89PNG\r\n\x1a\n"
