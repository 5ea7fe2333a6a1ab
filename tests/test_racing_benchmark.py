"""``python -m benchmarks.racing``: the methods' configurations and the per-road aggregate by hand (no training)."""

from __future__ import annotations

import envs_mjx
from benchmarks import racing


def test_imitation_method_imitates_for_the_whole_run_after_overrides():
    env = envs_mjx.make("racecar")
    cfg = racing.config_for("imitation", "cpu", env, {"total_steps": 1024, "num_envs": 4})
    assert cfg.pretrain_steps == cfg.total_steps == 1024
    td3 = racing.config_for("td3", "cpu", env, {})
    assert td3.twin_critics and 0 < td3.pretrain_steps < td3.total_steps


def test_aggregate_counts_outcomes_and_contacts_over_seeds_by_hand():
    def seed(success, car, wall):
        row = {"laps": 20, "success": success, "collision": 20 - success, "out_of_track": 0, "stalled": 0,
               "car_contact": car, "wall_contact": wall, "overtakes": 7.0, "speed_kmh": 100.0}  # fmt: skip
        return {road: dict(row) for road in racing.ROADS}

    agg = racing.aggregate([seed(19, 1, 0), seed(17, 2, 2), seed(20, 0, 0)])["test2"]
    assert agg["success"]["mean"] == 56 / 3 and agg["success"]["median"] == 19.0
    assert agg["car_contact"]["seeds"] == [1, 2, 0] and agg["wall_contact"]["mean"] == 2 / 3
    assert agg["met"] is False  # the second seed: 17 < 19 successes and 3 collisions
    assert racing.aggregate([seed(19, 1, 0), seed(20, 0, 0)])["train"]["met"] is True
