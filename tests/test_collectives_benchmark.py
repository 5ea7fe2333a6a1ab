"""``benchmarks.collectives``: the device counts it visits and the loop it times, checked against values by hand."""

import jax
import pytest

from benchmarks import collectives


def test_device_counts_are_the_powers_of_two_then_every_device():
    assert collectives.device_counts(1) == [1]
    assert collectives.device_counts(4) == [1, 2, 4]
    assert collectives.device_counts(6) == [1, 2, 4, 6]


@pytest.mark.parametrize("steps, repeats", [(3, 1), (10, 2)])
def test_the_timed_loop_approaches_the_fixed_point_as_worked_by_hand(steps, repeats):
    """From 0, ``v <- 0.5 v + 1`` n times gives ``2 - 2 * 0.5 ** n``; the warm-up and timed calls chain."""
    row = collectives.time_loop(jax.device_count(), 4, steps, repeats)
    n = steps * (repeats + 1)
    assert row["value"] == pytest.approx(2 - 2 * 0.5**n, rel=1e-6)
    assert row["steps"] == steps and row["us_per_step"] > 0


def test_the_table_gives_what_the_all_reduce_adds_over_one_device():
    rows = [
        {"devices": 1, "size": 256, "impl": "shard_map", "us_per_step": 10.0, "compile_s": 0.1},
        {"devices": 2, "size": 256, "impl": "vmap", "us_per_step": 35.5, "compile_s": 0.2},
    ]
    lines = collectives.table(rows).splitlines()
    assert lines[2].split("|")[5].strip() == "—"
    assert lines[3].split("|")[5].strip() == "25.5"
