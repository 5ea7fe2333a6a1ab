"""The brax-tasks report by hand (benchmarks.brax_tasks_report): walls with compilation apart, return ratios,
evaluation points."""

from __future__ import annotations

import numpy as np

from benchmarks.brax_tasks_merge import join_seeds
from benchmarks.brax_tasks_report import apart_cell, return_ratio, timed_seeds, training_wall_per_seed
from benchmarks.brax_tasks_sides import eval_points


def test_training_wall_per_seed_leaves_compilation_out_by_hand(tmp_path):
    """From the second evaluation to the last, scaled to all env steps, per seed of a program: ours (two seeds
    vmapped) 10 s at seconds 30 -> 40 over the second half of 100 steps = 20 s for all steps, 10 s a seed; brax's
    two seeds 6 and 8 s over that half = 12 and 16 s, 14 s a seed. A merge keeps each brax seed's times with
    it (None for a seed run before times were kept), and the wall apart is over the timed seeds."""
    ours = {"curve_steps": [0, 50, 100], "env_steps": 100, "curve_wall_s": [[10.0, 30.0, 40.0]], "seeds_per_program": 2}
    brax = {"curve_steps": [0, 50, 100], "env_steps": 100, "curve_wall_s": [[5.0, 20.0, 26.0], [5.0, 22.0, 30.0]]}
    assert training_wall_per_seed(ours) == 10.0 and training_wall_per_seed(brax) == 14.0
    assert training_wall_per_seed({**ours, "cut": True}) is None  # a run cut short
    assert training_wall_per_seed({k: v for k, v in ours.items() if k != "curve_wall_s"}) is None
    two = {"curve_steps": [0, 100], "env_steps": 100, "curve_wall_s": [[10.0, 40.0]]}
    assert training_wall_per_seed(two) is None  # the one interval holds the compilation
    record = {"returns": [1.0], "wall_s": 30.0, "env_steps": 100, "curve_steps": [0, 50, 100], "curves": [[0, 1, 1]],
              "eval_mode": "stochastic"}  # fmt: skip
    a = {**record, "seed_ids": [0], "curve_wall_s": [[5.0, 20.0, 26.0]]}
    b = {**record, "seed_ids": [1], "curve_wall_s": [[5.0, 22.0, 30.0]]}
    assert join_seeds(a, b)["curve_wall_s"] == brax["curve_wall_s"]
    assert join_seeds({**a, "seeds_asked": 1}, {**b, "seeds_asked": 2})["seeds_asked"] == 3  # a short run stays so
    # a seed run before times were kept: the wall apart speaks for the timed seed alone (8 s over 50 steps -> 16 s)
    untimed = join_seeds({k: v for k, v in a.items() if k != "curve_wall_s"}, b)
    assert untimed["curve_wall_s"] == [None, [5.0, 22.0, 30.0]] and untimed["seed_ids"] == [0, 1]
    assert training_wall_per_seed(untimed) == 16.0 and timed_seeds(untimed) == (1, 2)
    assert apart_cell(untimed) == "16 (1 of 2 seeds)" and apart_cell(brax | {"returns": [1.0, 1.0]}) == "14"
    assert apart_cell({**untimed, "curve_wall_s": [None, None]}) == "—"
    assert timed_seeds(ours | {"returns": [1.0, 2.0]}) == (2, 2)


def test_the_return_ratio_is_above_one_where_ours_is_ahead_for_rewards_and_costs():
    assert return_ratio(1800.0, 1200.0) == 1.5 and return_ratio(600.0, 1200.0) == 0.5
    assert return_ratio(-20.0, -25.0) == 1.25 and return_ratio(-25.0, -20.0) == 0.8
    assert np.isnan(return_ratio(5.0, 0.0))


def test_eval_points_spread_brax_s_ten_evaluations_over_the_updates():
    assert eval_points(18) == [0, 2, 4, 6, 8, 10, 12, 14, 16, 18]
    assert eval_points(4) == [0, 1, 2, 3, 4]  # fewer updates than evaluations: each update once
    assert eval_points(27) == [0, 3, 6, 9, 12, 15, 18, 21, 24, 27]
    assert eval_points(18, 3) == [0, 9, 18] and eval_points(18, 2) == [0, 18]  # --evals
