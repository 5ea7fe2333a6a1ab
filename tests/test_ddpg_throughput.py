"""benchmarks.ddpg_throughput's scaling table: rows paired by work per device, ratios by hand."""

import json

import pytest

from benchmarks.ddpg_throughput import load_baseline, scaling_lines, scaling_rows


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
