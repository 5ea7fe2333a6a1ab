"""``benchmarks.scaling``: the device counts and cases it plans, by hand, and a sweep's file written row by row."""

import argparse
import json
import os

import jax
import numpy as np
import pytest

from benchmarks import scaling
from jaxrl_robot import parallel


def test_device_counts_default_to_every_device_and_stop_beyond_them():
    assert scaling.device_counts([], 4) == [4]
    assert scaling.device_counts([4, 2, 2, 1], 4) == [2, 4]
    assert scaling.device_counts([], 1) == []
    with pytest.raises(SystemExit, match="--device-counts 8: only 4 device"):
        scaling.device_counts([2, 8], 4)


def test_the_plan_pairs_every_several_device_case_with_its_one_device_case():
    args = argparse.Namespace(one=[64], weak=[32], strong=[128], lane_group=48)
    assert scaling.plan_cases(args, [2, 4]) == [
        ("one", 1, 64), ("weak", 1, 32), ("weak", 2, 64), ("weak", 4, 128),
        ("strong", 1, 128), ("strong", 2, 128), ("strong", 4, 128),
        ("one, lane group 48", 1, 64, 48), ("strong, lane group 48", 1, 128, 48),
        ("strong, lane group 48", 2, 128, 48),
    ]  # fmt: skip


def test_the_results_file_is_rewritten_after_each_row(tmp_path, monkeypatch):
    """Each case is measured once (``bench_ours`` stands in here), and the file holds every row measured so far
    at each write: a sweep stopped half-way keeps its rows."""
    seen = []

    def fake_bench(env, lanes, *args, mesh=None, lane_group=0):
        path = os.path.join(tmp_path, os.listdir(tmp_path)[0]) if seen else None
        on_disk = len(json.load(open(path.replace(".md", ".json")))["runs"]) if path else 0
        seen.append((lanes, on_disk))
        return {"impl": "jaxrl_robot", "lanes": lanes, "steps_per_s": 1000.0 * lanes, "compile_s": 0.0}

    monkeypatch.setattr(scaling, "bench_ours", fake_bench)
    result = scaling.main(["--envs", "arm7", "--one", "8", "16", "--weak", "--strong", "--brax", "--out",
                           str(tmp_path), "--allow-dirty"])  # fmt: skip
    assert seen == [(8, 0), (16, 1)]
    assert [r["lanes"] for r in result["runs"]] == [8, 16] and result["runs"][0]["lane_map"] == "shard_map"
    saved = json.load(open(os.path.join(tmp_path, os.listdir(tmp_path)[0]).rsplit(".", 1)[0] + ".json"))
    assert [r["steps_per_s"] for r in saved["runs"]] == [8000.0, 16000.0]


def test_several_device_rows_run_under_each_lane_map_asked_for_and_one_device_rows_under_their_own(
    tmp_path, monkeypatch
):
    """``--lane-maps vmap shard_map``: each several-device case is measured under both (the variable set while it
    is built and timed), each one-device case once under the run's own; ``--env-config`` reaches the env."""
    seen = []

    def fake_bench(env, lanes, *args, mesh=None, lane_group=0):
        seen.append((lanes, os.environ.get(parallel.IMPL_ENV), env.config.jacobian))
        return {"impl": "jaxrl_robot", "lanes": lanes, "steps_per_s": 1.0, "compile_s": 0.0}

    monkeypatch.delenv(parallel.IMPL_ENV, raising=False)
    monkeypatch.setattr(scaling, "bench_ours", fake_bench)
    monkeypatch.setattr(scaling, "device_counts", lambda requested, available: [2])
    monkeypatch.setattr(parallel, "lane_mesh", lambda n=None, devices=None: parallel.Mesh(np.array(jax.devices()[:1]),
                                                                                          (parallel.LANES,)))
    result = scaling.main(["--envs", "arm7", "--one", "--weak", "8", "--strong", "--brax", "--lane-maps", "vmap",
                           "shard_map", "--env-config", "jacobian=sparse", "--out", str(tmp_path), "--allow-dirty"])
    assert seen == [(8, None, "sparse"), (16, "vmap", "sparse"), (16, "shard_map", "sparse")]
    assert [(r["devices"], r["lane_map"]) for r in result["runs"]] == [(1, "shard_map"), (2, "vmap"), (2, "shard_map")]
    assert result["env_configs"]["arm7"] == {"mode": "pd", "jacobian": "sparse"}
    assert parallel.IMPL_ENV not in os.environ
