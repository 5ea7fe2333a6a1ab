"""``python -m envs_mjx.demo``: the racecar pictures (the greedy controller's results file:
``tests/test_arm7_greedy.py``)."""

from __future__ import annotations

from envs_mjx import demo


def test_roads_figure_writes_a_png(tmp_path):
    path = demo.roads_figure(str(tmp_path), generated=2)
    with open(path, "rb") as f:
        assert f.read(8) == b"\x89PNG\r\n\x1a\n"
