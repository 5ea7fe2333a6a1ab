"""``python -m benchmarks.playground_suite``: each env's ``train.ppo`` command, the verdict per env and the
table, with a stand-in for the processes (the real ``train.ppo --env playground:<Name>`` path is trained by
``tests/cli/test_playground_cli.py``); unknown names are a one-line error naming the valid ones."""

from __future__ import annotations

import json
import math

import pytest

from benchmarks import playground_suite


def test_each_env_runs_train_ppo_tiny_and_a_failure_is_reported_not_hidden(tmp_path):
    seen = []

    def runner(cmd, out):
        seen.append(cmd)
        name = cmd[cmd.index("--env") + 1].split(":", 1)[1]
        if name == "PointMass":
            return {"rc": 1, "wall_s": 2.0, "error": "ValueError: boom"}
        ret = float("nan") if name == "CheetahRun" else 1.5
        return {"rc": 0, "wall_s": 3.0, "eval": {"mean_return": ret, "env_steps": 256}}

    argv = ["--names", "CartpoleBalance", "PointMass", "CheetahRun", "--jobs", "2", "--out", str(tmp_path),
            "--allow-dirty", "--", "--actor-lr", "1e-3"]  # fmt: skip
    assert playground_suite.main(argv, runner=runner) == 1  # not every env passed
    cmd = seen[0]
    assert cmd[1:4] == ["-m", "train.ppo", "--env"] and "--total-steps" in cmd and cmd[-2:] == ["--actor-lr", "1e-3"]
    assert cmd[cmd.index("--seed") + 1] == "1000000"  # the report range
    (stem,) = [p for p in tmp_path.iterdir() if p.suffix == ".json"]
    got = json.loads(stem.read_text())
    assert got["passed"] == 1 and [r["name"] for r in got["rows"]] == ["CartpoleBalance", "PointMass", "CheetahRun"]
    md = stem.with_suffix(".md").read_text()
    assert "**1 of 3 envs trained and evaluated.**" in md
    assert "| CartpoleBalance | yes | 256 | 1.500 | 3.0 |  |" in md
    assert "| PointMass | **no** | — | — | 2.0 | ValueError: boom |" in md
    assert "| CheetahRun | **no** |" in md  # exit 0 but a NaN return is not a pass
    assert not playground_suite.passed({"rc": 0, "eval": {"mean_return": math.inf}})


def test_unknown_names_are_one_line_errors(capsys):
    with pytest.raises(SystemExit):
        playground_suite.main(["--names", "Nope"])
    err = capsys.readouterr().err.strip().splitlines()[-1]
    assert "--names 'Nope': not in dm_control_suite; valid:" in err and "CheetahRun" in err
