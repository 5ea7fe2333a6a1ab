"""benchmarks.ddpg_throughput's tables: rows paired by work per device and by lane map, ratios by hand; the lane map
set per case."""

import json
import os

import pytest

from benchmarks.ddpg_throughput import lane_map, load_baseline, scaling_lines, scaling_rows, to_markdown
from jaxrl_robot import parallel


def _row(kind, lanes, workers, updates_per_s, steps_per_s, updates=32, batch=32):
    return {"kind": kind, "lanes": lanes, "sync_workers": workers, "batch": batch, "updates_per_iteration": updates,
            "transitions_per_update": workers * batch, "updates_per_s": updates_per_s,
            "env_steps_per_s": steps_per_s}  # fmt: skip


def test_scaling_pairs_rows_of_the_same_work_per_device_by_hand():
    one = {"devices": 1, "command": "c1", "commit": "abc", "device": "gpu",
           "runs": [_row("distributed", 4096, 4, 2000.0, 1.0e6), _row("single", 4096, 1, 2500.0, 1.2e6),
                    _row("distributed", 8192, 4, 1500.0, 1.5e6)]}  # fmt: skip
    two = {"devices": 2, "runs": [_row("distributed", 8192, 8, 1900.0, 1.9e6), _row("distributed", 8192, 4, 9.0, 9.0),
                                  _row("single", 8192, 1, 2400.0, 2.0e6)]}  # fmt: skip
    rows = scaling_rows(two, one)
    assert len(rows) == 1  # 8192 lanes with 4 workers is 2 workers per device: no baseline row of that work
    (r,) = rows
    assert (r["lanes"], r["base_lanes"], r["sync_workers"], r["base_sync_workers"]) == (8192, 4096, 8, 4)
    assert r["updates_ratio"] == pytest.approx(1900 / 2000)
    assert r["transitions_per_s"] == pytest.approx(1900 * 256) and r["base_transitions_per_s"] == 2000 * 128
    assert r["transitions_ratio"] == pytest.approx(1.9)
    assert r["steps_ratio"] == pytest.approx(1.9)
    text = "\n".join(scaling_lines(two, one))
    assert "| 8192 / 4096 | 8 / 4 | 1,900 / 2,000 | 0.95 | 486,400 / 256,000 | 1.90 | 1.90 |" in text


def test_baseline_must_be_a_ddpg_throughput_result(tmp_path):
    path = tmp_path / "other.json"
    path.write_text(json.dumps({"benchmark": "train_throughput"}))
    with pytest.raises(SystemExit, match=r"--baseline .*other.json: not a ddpg_throughput result"):
        load_baseline(str(path))
    with pytest.raises(SystemExit, match="--baseline .*missing.json"):
        load_baseline(str(tmp_path / "missing.json"))


def test_each_lane_map_is_set_for_the_case_and_the_variable_restored_after(monkeypatch):
    monkeypatch.setenv(parallel.IMPL_ENV, "vmap")
    with lane_map("shard_map"):
        assert os.environ[parallel.IMPL_ENV] == "shard_map"
    with lane_map("auto"):
        assert parallel.IMPL_ENV not in os.environ
    assert os.environ[parallel.IMPL_ENV] == "vmap"
    monkeypatch.delenv(parallel.IMPL_ENV)
    with lane_map("vmap"):
        assert parallel.lane_map_impl(parallel.lane_mesh(1)) == "vmap"
    assert parallel.IMPL_ENV not in os.environ


def test_the_table_compares_a_row_with_the_single_learner_of_its_own_lane_map():
    rows = [{**_row("single", 1024, 1, 2000.0, 1.0e6), "lane_map": "shard_map"},
            {**_row("single", 1024, 1, 50.0, 2.5e4), "lane_map": "vmap"},
            {**_row("distributed", 1024, 4, 1000.0, 5.0e5), "lane_map": "vmap"}]  # fmt: skip
    for r in rows:
        r.update(unroll=4, compile_s=1.0)
    result = {"env": "arm7", "device": "gpu", "devices": 2, "command": "c", "commit": "abc", "jax": "0", "date": "d",
              "repeats": 1, "iterations": 1, "runs": rows}  # fmt: skip
    lines = [line for line in to_markdown(result).splitlines() if line.startswith("| distributed")]
    assert lines == ["| distributed | vmap | 1024 | 4 | 32 | 128 | 500,000 | 1,000 | 20.00 | 20.00 | 1.0 |"]
