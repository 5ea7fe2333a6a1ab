"""``benchmarks.seeds``: tuning and reporting seeds come from ranges that never meet, and a seed's key is the
key of ``train.<algo> --seed s``."""

from __future__ import annotations

import argparse

import jax
import numpy as np
import pytest

from benchmarks import seeds
from jaxrl_robot.evaluation import EVAL_KEY_OFFSET


def test_the_ranges_never_meet():
    assert seeds.seed_ids("tune", 3) == [0, 1, 2] and seeds.seed_ids("tune", 2, 5) == [5, 6]
    assert seeds.seed_ids("report", 3) == [1_000_000, 1_000_001, 1_000_002]
    assert seeds.seed_ids("report", 16)[:8] == seeds.seed_ids("report", 8)  # more seeds: the same first ones
    top = seeds.REPORT_BASE - 1
    assert seeds.seed_ids("tune", 1, top) == [top]  # the last tuning seed
    with pytest.raises(ValueError, match=r"tune seeds 999999..1000000 leave the tune range \[0, 999999\]"):
        seeds.seed_ids("tune", 2, top)  # a tuning run cannot reach the report range
    with pytest.raises(ValueError, match="leave the report range"):
        seeds.seed_ids("report", 2, seeds.MAX_SEED - seeds.REPORT_BASE)
    with pytest.raises(ValueError, match="purpose 'final' is not one of tune, report"):
        seeds.seed_ids("final", 3)
    assert [seeds.purpose_of(s) for s in (0, top, seeds.REPORT_BASE)] == ["tune", "tune", "report"]


def test_keys_are_those_of_the_train_command_lines():
    ids = seeds.seed_ids("report", 2)
    got, evals = np.asarray(seeds.keys(ids)), np.asarray(seeds.eval_keys(ids))
    assert got.shape == (2, 2)
    for i, s in enumerate(ids):
        assert (got[i] == np.asarray(jax.random.PRNGKey(s))).all()
        assert (evals[i] == np.asarray(jax.random.fold_in(jax.random.PRNGKey(s), EVAL_KEY_OFFSET))).all()
    assert not (np.asarray(seeds.keys([0])) == got[0]).all()


def test_the_purpose_is_a_flag_and_the_record_says_it():
    p = argparse.ArgumentParser()
    seeds.add_args(p)
    args = p.parse_args(["--purpose", "report", "--seeds", "4"])
    assert (args.purpose, args.seeds, args.first_seed) == ("report", 4, 0)
    entry = seeds.record("report", seeds.seed_ids("report", 4))
    assert entry == {"purpose": "report", "ids": [1_000_000, 1_000_001, 1_000_002, 1_000_003],
                     "keys": "training key PRNGKey(seed)"}  # fmt: skip
    assert seeds.words(entry) == ("4 seed(s) 1000000..1000003 (the report range: never used to choose a setting); "
                                  "training key PRNGKey(seed)")  # fmt: skip
    assert seeds.words("3 keys split from PRNGKey(0)") == "3 keys split from PRNGKey(0)"  # an older file's words
